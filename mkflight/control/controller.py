"""The controller: position, yaw and altitude loops -> one MK ``Command`` (SPEC §4).

Like PX4's ``PositionControl``: set-points and state in, ``update(dt_s)`` out, no I/O and
no clock. The flight step owns time, the phases and the failsafe.

Contract for invalid outputs (SPEC §5 row 1)
--------------------------------------------
``update`` returns ``ControlOutput(valid=False, command=None, diagnostics=None,
invalid_inputs=(...names...))`` when an input it needs is NaN/inf (or ``battery_v <= 0``):

* needed in ``ControlMode.POSITION``: every float of the estimate (x, y, yaw, height,
  vx, vy, vz_up), of the set-point, the attitude and ``battery_v``;
* needed in ``ControlMode.LEVEL`` (failsafe level hold: no position, tilt 0): the
  estimate's yaw, height and vz_up, the set-point's yaw, height and climb feed-forward,
  the attitude and ``battery_v``; x/y/vx/vy and the x/y set-point may then be anything.

An invalid step leaves the controller's state exactly as it was (no integral, no
derivative memory advanced). The caller must then send its LAST SAFE command (the last
valid one) and tell the failsafe (``FailsafeInputs.values_finite=False``), which lands
after ``safety.nonfinite_land_steps`` consecutive invalid steps. A valid output's command
always satisfies :func:`mkflight.control.limits.command_within_limits` and its
diagnostics are all finite. ``dt_s`` is NOT an input that invalidates: ``dt_s <= 0`` or
non-finite only skips integration and derivatives (P still acts); pass the time since the
last VALID update (``est.t_ns - controller.last_valid_t_ns``).
"""

from __future__ import annotations

import enum
import math

import msgspec

from mkflight.config import ControlConfig, MkConfig
from mkflight.control.altitude import AltitudeResult, AltitudeState, altitude_step
from mkflight.control.limits import all_finite
from mkflight.control.pid import PidState
from mkflight.control.position import PositionResult, PositionState, position_step
from mkflight.control.yaw import YawResult, yaw_step
from mkflight.msgs import Command, Estimate


class ControlMode(enum.Enum):
    """What the horizontal loops do (the failsafe's LEVEL_HOLD selects LEVEL)."""

    POSITION = "position"
    LEVEL = "level"


class Setpoint(msgspec.Struct, frozen=True, gc=False):
    """Where to be, in W (SPEC §1): position, heading (clockwise) and height (up).

    ``climb_ff_mps`` is the height set-point's own rate (a ramp's climb/descent), used as
    feed-forward of the climb-rate set-point; 0 when holding.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    height_m: float
    climb_ff_mps: float = 0.0


class ControlDiagnostics(msgspec.Struct, frozen=True, gc=False):
    """Every intermediate of a valid step (all finite), for the logs."""

    pitch_sp_rad: float
    roll_sp_rad: float
    tilt_clamped: bool
    vel_sp_x_mps: float
    vel_sp_y_mps: float
    acc_sp_x_w_mps2: float
    acc_sp_y_w_mps2: float
    yaw_error_rad: float
    yaw_rate_cmd_counts: float
    climb_sp_mps: float
    gas_ff: float
    gas_pid: float
    gas_total: float


class ControlOutput(msgspec.Struct, frozen=True, gc=False):
    """One step's result: a command and its diagnostics, or ``valid=False`` (see module)."""

    valid: bool
    command: Command | None
    diagnostics: ControlDiagnostics | None
    invalid_inputs: tuple[str, ...] = ()


class ControllerState(msgspec.Struct, frozen=True, gc=False):
    """All loop states and the timestamp of the last valid update (None before any)."""

    position: PositionState = msgspec.field(default_factory=PositionState)
    yaw: PidState = msgspec.field(default_factory=PidState)
    altitude: AltitudeState = msgspec.field(default_factory=AltitudeState)
    last_valid_t_ns: int | None = None


def _invalid(names: tuple[str, ...]) -> ControlOutput:
    return ControlOutput(valid=False, command=None, diagnostics=None, invalid_inputs=names)


class Controller:
    """Position + yaw + altitude control around a frozen :class:`ControllerState`.

    Deterministic and I/O-free; ``state`` can be read, saved and restored
    (``Controller(..., state=s)``) for replay and tests.
    """

    def __init__(
        self,
        control: ControlConfig,
        mk: MkConfig,
        *,
        state: ControllerState | None = None,
    ) -> None:
        self.control = control
        self.mk = mk
        self.state = state if state is not None else ControllerState()

    @property
    def last_valid_t_ns(self) -> int | None:
        """``t_ns`` of the estimate of the last valid update (for the caller's ``dt_s``)."""
        return self.state.last_valid_t_ns

    def reset(self) -> None:
        """Forget all integrals and derivative memories (e.g. before take-off)."""
        self.state = ControllerState()

    def update(
        self,
        est: Estimate,
        setpoint: Setpoint,
        attitude: tuple[float, float],
        battery_v: float,
        dt_s: float,
        *,
        mode: ControlMode = ControlMode.POSITION,
        take_control: bool = True,
    ) -> ControlOutput:
        """Run all loops once; see the module docstring for the invalid-output contract.

        Args:
            est: the estimate (W frame, SPEC §1/§3).
            setpoint: the set-point (from the flight phases).
            attitude: measured ``(pitch_rad, roll_rad)`` (SPEC §1 signs).
            battery_v: battery voltage for the gas feed-forward (V).
            dt_s: seconds since the last valid update, from timestamps.
            mode: POSITION, or LEVEL (tilt 0, yaw and height held; failsafe level hold).
            take_control: copied into the command (Config bit 0).

        Returns:
            A valid output with a within-limits :class:`Command` stamped ``est.t_ns``, or
            ``valid=False`` with ``command=None`` and the names of the bad inputs.
        """
        bad = _invalid_inputs(est, setpoint, attitude, battery_v, mode)
        if bad:
            return _invalid(bad)
        pitch_rad, roll_rad = attitude
        st = self.state
        c, mk = self.control, self.mk
        pos = None
        if mode is ControlMode.POSITION:
            pos = position_step(
                c,
                mk,
                st.position,
                x_sp_m=setpoint.x_m,
                y_sp_m=setpoint.y_m,
                x_m=est.x_m,
                y_m=est.y_m,
                vx_mps=est.vx_mps,
                vy_mps=est.vy_mps,
                yaw_rad=est.yaw_rad,
                dt_s=dt_s,
                ff_ax_w_mps2=-c.disturbance_ff * est.ax_ext_mps2,
                ff_ay_w_mps2=-c.disturbance_ff * est.ay_ext_mps2,
            )
        yaw = yaw_step(c, mk, st.yaw, yaw_sp_rad=setpoint.yaw_rad, yaw_rad=est.yaw_rad, dt_s=dt_s)
        alt = altitude_step(
            c,
            st.altitude,
            height_sp_m=setpoint.height_m,
            height_m=est.height_m,
            vz_up_mps=est.vz_up_mps,
            pitch_rad=pitch_rad,
            roll_rad=roll_rad,
            battery_v=battery_v,
            dt_s=dt_s,
            climb_ff_mps=setpoint.climb_ff_mps,
        )
        if yaw is None or alt is None or (mode is ControlMode.POSITION and pos is None):
            # Finite inputs whose arithmetic overflowed (absurd magnitudes): same contract.
            return _invalid(("overflow",))
        command = Command(
            t_ns=est.t_ns,
            nick_counts=0 if pos is None else pos.nick_counts,
            roll_counts=0 if pos is None else pos.roll_counts,
            yaw_counts=yaw.yaw_counts,
            gas_counts=alt.gas_counts,
            take_control=take_control,
        )
        # LEVEL (no position result): tilt 0, and the horizontal loops forget their state.
        new_pos = PositionState() if pos is None else pos.state
        self.state = ControllerState(new_pos, yaw.state, alt.state, est.t_ns)
        return ControlOutput(valid=True, command=command, diagnostics=_diagnostics(pos, yaw, alt))


def _invalid_inputs(
    est: Estimate,
    setpoint: Setpoint,
    attitude: tuple[float, float],
    battery_v: float,
    mode: ControlMode,
) -> tuple[str, ...]:
    """The names of the inputs ``mode`` needs that are NaN/inf (see the module docstring).

    A battery voltage at or below 0 is invalid too.
    """
    pitch_rad, roll_rad = attitude
    ok_battery = math.isfinite(battery_v) and battery_v > 0.0
    if ok_battery and _all_inputs_finite(est, setpoint, pitch_rad, roll_rad, mode):
        return ()  # the usual case, without naming each input
    needed = {
        "est.yaw_rad": est.yaw_rad,
        "est.height_m": est.height_m,
        "est.vz_up_mps": est.vz_up_mps,
        "setpoint.yaw_rad": setpoint.yaw_rad,
        "setpoint.height_m": setpoint.height_m,
        "setpoint.climb_ff_mps": setpoint.climb_ff_mps,
        "pitch_rad": pitch_rad,
        "roll_rad": roll_rad,
    }
    if mode is ControlMode.POSITION:
        needed |= {
            "est.x_m": est.x_m,
            "est.y_m": est.y_m,
            "est.vx_mps": est.vx_mps,
            "est.vy_mps": est.vy_mps,
            "setpoint.x_m": setpoint.x_m,
            "setpoint.y_m": setpoint.y_m,
        }
    bad = [name for name, v in needed.items() if not math.isfinite(v)]
    if not (math.isfinite(battery_v) and battery_v > 0.0):
        bad.append("battery_v")
    return tuple(bad)


def _all_inputs_finite(
    est: Estimate, setpoint: Setpoint, pitch_rad: float, roll_rad: float, mode: ControlMode
) -> bool:
    """Every input :func:`_invalid_inputs` checks for ``mode`` finite, but the battery's."""
    if not all_finite(
        est.yaw_rad,
        est.height_m,
        est.vz_up_mps,
        setpoint.yaw_rad,
        setpoint.height_m,
        setpoint.climb_ff_mps,
        pitch_rad,
        roll_rad,
    ):
        return False
    return mode is not ControlMode.POSITION or all_finite(
        est.x_m, est.y_m, est.vx_mps, est.vy_mps, setpoint.x_m, setpoint.y_m
    )


def _diagnostics(
    pos: PositionResult | None, yaw: YawResult, alt: AltitudeResult
) -> ControlDiagnostics:
    """A valid step's intermediates (LEVEL, no position result: the horizontal ones 0)."""
    if pos is None:
        diag_pos: tuple[float, float, bool, float, float, float, float] = (
            0.0, 0.0, False, 0.0, 0.0, 0.0, 0.0,
        )  # fmt: skip
    else:
        diag_pos = (
            pos.pitch_sp_rad,
            pos.roll_sp_rad,
            pos.tilt_clamped,
            pos.vel_sp_x_mps,
            pos.vel_sp_y_mps,
            pos.acc_x_w_mps2,
            pos.acc_y_w_mps2,
        )
    return ControlDiagnostics(
        *diag_pos,
        yaw_error_rad=yaw.error_rad,
        yaw_rate_cmd_counts=yaw.rate_cmd_counts,
        climb_sp_mps=alt.climb_sp_mps,
        gas_ff=alt.gas_ff,
        gas_pid=alt.gas_pid,
        gas_total=alt.gas_total,
    )
