"""Altitude control (SPEC §4; §K eq 25 outer, §H eq 23 inner).

§ and eq are those of the 2011 QUT CyPhy MikroKopter documentation.

1. Height PID (eq 25) on ``h* - h`` (D on the measurement: ``-kd_z * vz_up``) -> climb-rate
   set-point, limited to ``+-control.max_climb_mps`` (integral within the same bound), plus
   an optional climb feed-forward from a ramping set-point.
2. Vertical velocity PID (eq 23) on ``vz* - vz_up`` -> gas correction, integral clamped to
   ``+-control.integral_limit_gas``, anti-windup against the gas saturation. Its D term
   differentiates the speed estimate over at least :data:`MIN_DERIVATIVE_DT_S`: the FC
   samples every ~53 ms, and a shorter gap between steps is a starved host catching up (a
   sample that came late, then the next on time), not a shorter time for the speed to
   change; over the arrival gap (13 ms after a 201 ms one) the estimate's correction
   became a 53-count gas drop, gas 10 held by the FC through the next stall (a 1.5 m/s
   fall, a 0.94 m/s touchdown under CPU starvation).
3. Gas = feed-forward + PID, saturated to ``[0, control.gas_max]`` (§K: 0..130) and
   rounded: an unsigned byte that can never wrap.

Feed-forward (§M: the thrust offset drifts as the pack discharges)::

    gas_ff = hover_gas * (hover_voltage_v / battery_v) / max(cos(theta) cos(phi), min_tilt_factor)

Thrust grows roughly with voltage at a given gas, so a lower voltage needs
proportionally more gas; the ratio is clamped to ``battery_ratio_limits`` so a bad reading
cannot command a jump, and the tilt factor is floored at ``min_tilt_factor`` (0.5, i.e.
60 deg) so a large attitude cannot ask for unbounded gas. The integral takes up the rest.
"""

from __future__ import annotations

import math

import msgspec

from mkflight.config import ControlConfig
from mkflight.control.limits import all_finite, gas_to_counts
from mkflight.control.pid import PidGains, PidState, clamp, gains_of_config, pid_update

MIN_TILT_FACTOR = 0.5
"""Floor of cos(theta) cos(phi) in the feed-forward (60 deg of combined tilt)."""

BATTERY_RATIO_LIMITS = (0.8, 1.25)
"""Bounds of hover_voltage_v / battery_v in the feed-forward."""

MIN_DERIVATIVE_DT_S = 0.05
"""The shortest span the inner loop's D term divides by (module docstring): about the
FC's DebugOut period (~53 ms), so that only steps that came closer than the FC sends are
affected (and the FC's early answer to a re-subscription: one step with a little less
damping). The integral and everything else still take the step's own ``dt_s``."""


class AltitudeState(msgspec.Struct, frozen=True, gc=False):
    """The height (outer) and vertical-velocity (inner) PIDs' states."""

    height: PidState = msgspec.field(default_factory=PidState)
    climb: PidState = msgspec.field(default_factory=PidState)


class AltitudeResult(msgspec.Struct, frozen=True, gc=False):
    """One altitude step: the climb set-point, the gas parts and the gas byte."""

    climb_sp_mps: float
    gas_ff: float
    gas_pid: float
    gas_total: float
    gas_counts: int
    gas_saturation: int
    state: AltitudeState


@gains_of_config
def height_gains(control: ControlConfig) -> PidGains:
    """Eq 25's gains: climb-rate output and integral within +-max_climb_mps."""
    lim = control.max_climb_mps
    return PidGains(
        kp=control.kp_z,
        ki=control.ki_z,
        kd=control.kd_z,
        integral_limit=lim,
        output_min=-lim,
        output_max=lim,
    )


@gains_of_config
def climb_gains(control: ControlConfig) -> PidGains:
    """Eq 23's gains: output = the whole gas in [0, gas_max], integral +-integral_limit_gas."""
    return PidGains(
        kp=control.kp_vz,
        ki=control.ki_vz,
        kd=control.kd_vz,
        integral_limit=control.integral_limit_gas,
        output_min=0.0,
        output_max=float(control.gas_max),
    )


def hover_feedforward(
    control: ControlConfig,
    *,
    pitch_rad: float,
    roll_rad: float,
    battery_v: float,
    min_tilt_factor: float = MIN_TILT_FACTOR,
    battery_ratio_limits: tuple[float, float] = BATTERY_RATIO_LIMITS,
) -> float:
    """Hover gas for this attitude and battery (see the module docstring); finite inputs."""
    ratio = clamp(control.hover_voltage_v / battery_v, *battery_ratio_limits)
    tilt = math.cos(pitch_rad) * math.cos(roll_rad)
    tilt = min_tilt_factor if tilt < min_tilt_factor else tilt  # max(tilt, min_tilt_factor)
    return control.hover_gas * ratio / tilt


def _climb_rate(kd: float, prev_mps: float | None, vz_up_mps: float, dt_s: float) -> float | None:
    """The D term's rate of the speed, over at least ``MIN_DERIVATIVE_DT_S``.

    None: the PID's own derivative over ``dt_s`` (a step that long, or the first one).
    """
    if kd != 0.0 and prev_mps is not None and 0.0 < dt_s < MIN_DERIVATIVE_DT_S:
        return (vz_up_mps - prev_mps) / MIN_DERIVATIVE_DT_S
    return None


def altitude_step(
    control: ControlConfig,
    state: AltitudeState,
    *,
    height_sp_m: float,
    height_m: float,
    vz_up_mps: float,
    pitch_rad: float,
    roll_rad: float,
    battery_v: float,
    dt_s: float,
    climb_ff_mps: float = 0.0,
    min_tilt_factor: float = MIN_TILT_FACTOR,
    battery_ratio_limits: tuple[float, float] = BATTERY_RATIO_LIMITS,
) -> AltitudeResult | None:
    """One altitude step (eq 25 -> eq 23 -> gas).

    Args:
        control: gains and limits.
        state: the previous state (``AltitudeState()`` to start).
        height_sp_m: height set-point (m, up).
        height_m: estimated height (m, up).
        vz_up_mps: estimated vertical velocity (m/s, up).
        pitch_rad: measured pitch (rad).
        roll_rad: measured roll (rad).
        battery_v: battery voltage (V), must be > 0.
        dt_s: seconds since the previous step (from timestamps).
        climb_ff_mps: climb-rate feed-forward (the set-point's own rate, m/s up).
        min_tilt_factor: floor of cos(theta) cos(phi).
        battery_ratio_limits: bounds of hover_voltage_v / battery_v.

    Returns:
        The result, or None if an input is non-finite or ``battery_v <= 0`` (state
        unchanged).
    """
    values = (height_sp_m, height_m, vz_up_mps, pitch_rad, roll_rad, battery_v, climb_ff_mps)
    if not all_finite(*values) or battery_v <= 0.0:
        return None
    outer = pid_update(
        height_gains(control),
        state.height,
        error=height_sp_m - height_m,
        measurement=height_m,
        dt_s=dt_s,
        rate=vz_up_mps,
    )
    if not outer.valid:
        return None
    climb_sp = clamp(outer.output + climb_ff_mps, -control.max_climb_mps, control.max_climb_mps)
    gas_ff = hover_feedforward(
        control,
        pitch_rad=pitch_rad,
        roll_rad=roll_rad,
        battery_v=battery_v,
        min_tilt_factor=min_tilt_factor,
        battery_ratio_limits=battery_ratio_limits,
    )
    gains = climb_gains(control)
    inner = pid_update(
        gains,
        state.climb,
        error=climb_sp - vz_up_mps,
        measurement=vz_up_mps,
        dt_s=dt_s,
        rate=_climb_rate(gains.kd, state.climb.prev_measurement, vz_up_mps, dt_s),
        feedforward=gas_ff,
    )
    if not inner.valid:
        return None
    return AltitudeResult(
        climb_sp_mps=climb_sp,
        gas_ff=gas_ff,
        gas_pid=inner.output - gas_ff,
        gas_total=inner.output,
        gas_counts=gas_to_counts(inner.output, control.gas_max),
        gas_saturation=inner.saturation,
        state=AltitudeState(outer.state, inner.state),
    )
