"""The oracle's pilot: sticks from the TRUE state, the flight's cascade on truth.

:mod:`mkflight.sim.oracle` flies an airframe with this controller, which knows everything
the flight has to estimate:

* it reads the true position, velocity, yaw, height and battery every DebugOut period
  (:data:`PERIOD_S`, 52 FC ticks of 1.024 ms), as the flight's control step runs;
* horizontal: the flight's cascade (SPEC §4, :mod:`mkflight.control.position`) on truth:
  position P + I -> velocity set-point (norm <= :data:`MAX_SPEED_MPS`) -> velocity PID
  (derivative on the measurement) -> world acceleration -> heading frame -> tilt
  (pitch ``-a_x / g``, roll ``a_y / g``, norm <= :data:`MAX_TILT_RAD`) -> counts in the
  airframe's TRUE counts per radian and signs, rounded to the integer counts an
  ExternControl frame carries;
* yaw and height held by true-state loops (the height is not judged): a P loop on the yaw
  error with the airframe's true yaw rate per count, and a PD + I loop on the height error
  around the airframe's true hover gas at the true battery voltage, divided by the tilt.

The limits and the height and yaw loops' gains are the oracle's own copies of the
flight's defaults: the simulator never reads the flight code's constants.
"""

from __future__ import annotations

import math
from typing import Final

from mkflight.frames import wrap_pi
from mkflight.sim.vehicle import Sticks, Vec3, VehicleParams, VehicleState

PERIOD_S: Final = 52 * 1.024e-3  # the FC's DebugOut period (mk-serial.md §7.2)
MAX_SPEED_MPS: Final = 0.5  # velocity set-point norm (the flight's control.max_speed_mps)
MAX_TILT_RAD: Final = 0.30  # tilt norm (the flight's control.max_tilt_rad)
MAX_COUNTS: Final = 127  # an ExternControl stick is a signed byte
YAW_MAX_COUNTS: Final = 40
YAW_GAIN_PER_S: Final = 2.0  # yaw rate set-point per rad of yaw error
HEIGHT_KP_PER_S2: Final = 16.0  # height loop: acceleration per m of error (1/s^2)
HEIGHT_KD_PER_S: Final = 8.0  # ... per m/s of vertical speed
HEIGHT_KI_PER_S3: Final = 8.0  # ... per m s of integrated error
HEIGHT_I_LIMIT_MPS2: Final = 2.0
GAS_MAX_COUNTS: Final = 255.0

#: The horizontal cascade's gains ``(kp_xy, ki_xy, kp_vxy, ki_vxy, kd_vxy)``.
Gains = tuple[float, float, float, float, float]


def _stick(value: float, limit: int) -> float:
    """A command rounded to whole counts within ±limit (a signed byte on the wire)."""
    return float(min(max(round(value), -limit), limit))


class TruthPilot:
    """The oracle's controller: sticks from the TRUE state, one call per DebugOut period.

    Horizontal: the flight's cascade (module docstring) with the gains; yaw held at 0 by a
    rate stick; height by PD + I around the airframe's true hover gas. Keeps the
    integrators and the last velocity (the derivative is on the measurement).
    """

    def __init__(
        self, params: VehicleParams, gains: Gains, height_m: float, vel_w_mps: Vec3
    ) -> None:
        """A pilot holding (0, 0, ``height_m``), integrators at 0, last velocity ``vel_w_mps``.

        ``gains``: ``(kp_xy, ki_xy, kp_vxy, ki_vxy, kd_vxy)``, as ``control``'s.
        """
        self.params = params
        self.gains = gains
        self.height_m = height_m
        self.a_max_mps2 = params.g_mps2 * MAX_TILT_RAD
        self.ix = self.iy = self.ivx = self.ivy = self.iz = 0.0
        self.prev_vx, self.prev_vy = vel_w_mps[0], vel_w_mps[1]

    def sticks(self, state: VehicleState) -> Sticks:
        """The sticks for the next period, in the airframe's TRUE counts and signs."""
        p = self.params
        axw, ayw = self._world_acceleration(state)
        pitch, roll = _tilt_rad(axw, ayw, state.yaw_rad, p.g_mps2)
        yaw_counts_per_radps = 1.0 / (p.yaw_sign * p.yaw_rate_radps_per_count)
        yaw_counts = _stick(
            YAW_GAIN_PER_S * wrap_pi(-state.yaw_rad) * yaw_counts_per_radps, YAW_MAX_COUNTS
        )
        return Sticks(
            nick_counts=_stick(pitch * (p.counts_per_rad * p.nick_sign), MAX_COUNTS),
            roll_counts=_stick(roll * (p.counts_per_rad * p.roll_sign), MAX_COUNTS),
            yaw_counts=yaw_counts,
            gas_counts=float(self._gas_counts(state)),
        )

    def _world_acceleration(self, state: VehicleState) -> tuple[float, float]:
        """Position P + I -> velocity set-point -> velocity PID: the world acceleration."""
        kp, ki, kpv, kiv, kdv = self.gains
        x, y, _ = state.pos_w_m
        vx, vy, _ = state.vel_w_mps
        dt = PERIOD_S
        # position P + I -> velocity set-point (norm-limited, integral clamped to it)
        i_max = MAX_SPEED_MPS / max(ki, 1e-9)
        self.ix = min(max(self.ix - x * dt, -i_max), i_max)
        self.iy = min(max(self.iy - y * dt, -i_max), i_max)
        vsx, vsy = -kp * x + ki * self.ix, -kp * y + ki * self.iy
        speed = math.hypot(vsx, vsy)
        if speed > MAX_SPEED_MPS:
            vsx, vsy = vsx * MAX_SPEED_MPS / speed, vsy * MAX_SPEED_MPS / speed
        # velocity PID (derivative on the measurement) -> world acceleration
        a_max = self.a_max_mps2
        ilim = a_max / max(kiv, 1e-9)
        self.ivx = min(max(self.ivx + (vsx - vx) * dt, -ilim), ilim)
        self.ivy = min(max(self.ivy + (vsy - vy) * dt, -ilim), ilim)
        axw = kpv * (vsx - vx) + kiv * self.ivx - kdv * (vx - self.prev_vx) / dt
        ayw = kpv * (vsy - vy) + kiv * self.ivy - kdv * (vy - self.prev_vy) / dt
        self.prev_vx, self.prev_vy = vx, vy
        return min(max(axw, -a_max), a_max), min(max(ayw, -a_max), a_max)

    def _gas_counts(self, state: VehicleState) -> float:
        """Height by PD + I around the true hover gas at the true battery, over the tilt."""
        p = self.params
        z, vz = state.pos_w_m[2], state.vel_w_mps[2]
        err_z = self.height_m + z  # z is down: height = -z
        iz_limit = HEIGHT_I_LIMIT_MPS2 / HEIGHT_KI_PER_S3  # the integral term within ±2 m/s²
        self.iz = min(max(self.iz + err_z * PERIOD_S, -iz_limit), iz_limit)
        acc_up = HEIGHT_KP_PER_S2 * err_z + HEIGHT_KI_PER_S3 * self.iz + HEIGHT_KD_PER_S * vz
        volts = max(state.battery_v, 0.5 * p.hover_voltage_v)
        hover = p.hover_gas_counts * (p.hover_voltage_v / volts) ** 2
        tilt_cos = max(math.cos(state.pitch_rad) * math.cos(state.roll_rad), 0.5)
        return min(max(round(hover * (1.0 + acc_up / p.g_mps2) / tilt_cos), 0.0), GAS_MAX_COUNTS)


def _tilt_rad(axw: float, ayw: float, yaw_rad: float, g_mps2: float) -> tuple[float, float]:
    """``(pitch, roll)`` for a world acceleration: heading frame (SPEC §1), norm clamp."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    abx, aby = cy * axw + sy * ayw, -sy * axw + cy * ayw
    pitch, roll = -abx / g_mps2, aby / g_mps2
    tilt = math.hypot(pitch, roll)
    if tilt > MAX_TILT_RAD:
        return pitch * MAX_TILT_RAD / tilt, roll * MAX_TILT_RAD / tilt
    return pitch, roll
