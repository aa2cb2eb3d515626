"""The simulated MikroKopter: an FRD rigid body flown by the FC's own attitude loop (SPEC §8).

Pure and synchronous: :func:`step` takes a :class:`VehicleState`, the sticks the FC applies
(:class:`Sticks`, after its own rules: extern + pilot sticks, gas capped by the stick gas),
a time step and a seeded ``numpy.random.Generator``, and returns the next state. Nothing
reads a clock; time is ``state.t_s``.

Model (world frame W: x forward, y right, z down; body B FRD; SPEC §1):

* **Attitude** (seed §F, ~200 ms response): the MK's attitude loop tracks the commanded
  angles after a pure delay (``attitude_delay_s`` ≈ 0.1 s) through a first-order lag
  (``attitude_tau_s`` ≈ 0.1 s). Commanded angle = ``sign * counts / counts_per_rad`` with
  ``sign = -1`` (SPEC §1: + nick tilts the nose down, our pitch is + nose up; + roll lowers
  the left side, our roll is + right side down). The yaw stick commands a yaw *rate*
  ``sign_yaw * yaw * yaw_rate_radps_per_count`` (+ yaw turns the nose left, our ψ is
  clockwise) through the same delay and lag. The true angle also carries the flight's
  attitude trim: the FC levels its own (slightly wrong) horizon.
* **Thrust** (seed §K, §M): ``T = m g (gas / hover_gas) (V / V_hover)^2`` with the battery's
  terminal voltage V, through a motor lag ``thrust_tau_s``; at ``hover_gas_counts`` and
  ``hover_voltage_v`` it equals the weight (``control.hover_gas``/``hover_voltage_v``).
* **Battery** (seed §L, §M): open-circuit voltage from a LiPo curve of the state of charge
  (:mod:`mkflight.sim.battery`, per cell) minus ``I R``; ``I`` = avionics current + the motors'
  current, which scales as ``(T / W)^1.5`` (momentum theory: power ∝ T^1.5) at the seed's
  6.8 A hover current, divided by ``V / V_hover`` (same power, other voltage).
* **Translation** (SPEC §8): ``a_W = R(ψ) R_y(θ) R_x(φ) (0, 0, -T/m) + (0, 0, g) - drag``,
  drag = ``k1 v_rel + k2 |v_rel| v_rel`` per unit mass on the air-relative velocity.
* **Gusts**: an Ornstein-Uhlenbeck wind velocity (std ``wind_std_mps``, correlation time
  ``wind_tau_s``), felt through the drag: ≈ ``k1 * 0.1 m/s`` = a few cm/s².
* **Ground** at z = 0 (height 0): the vehicle cannot go below it; on it with net force
  down, it sits still and level (velocity, rates and acceleration zero).

The sensors (what the FC and the laser would measure of this state) live in
:mod:`mkflight.sim.vehicle_sensors`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from mkflight.config import Config
from mkflight.frames import wrap_pi
from mkflight.sim.battery import current_a, open_circuit_v

MAX_SUBSTEP_S = 0.005  # integration step: well below every time constant


@dataclass(frozen=True, slots=True)
class VehicleParams:
    """The vehicle's physical constants (defaults: the seed's airframe, SPEC §8).

    Counts and signs follow ``config.mk``; hover gas and voltage ``config.control``, so the
    default controller gains hover this vehicle.
    """

    mass_kg: float = 1.04  # seed §L: 1,040 g all up
    g_mps2: float = 9.81
    counts_per_rad: float = 120.0  # mk.counts_per_rad
    nick_sign: int = -1  # mk.signs: our angle = sign * counts / counts_per_rad
    roll_sign: int = -1
    yaw_sign: int = -1
    max_tilt_rad: float = 1.0  # the FC's attitude loop never commands more
    attitude_delay_s: float = 0.1  # seed §F
    attitude_tau_s: float = 0.1  # seed §F
    yaw_rate_radps_per_count: float = 0.02  # 40 counts -> 0.8 rad/s
    hover_gas_counts: float = 100.0  # control.hover_gas
    hover_voltage_v: float = 11.8  # control.hover_voltage_v
    gas_max_counts: float = 255.0  # the FC's gas is an unsigned char
    thrust_tau_s: float = 0.05  # motor + ESC spin-up
    battery_cells: int = 3  # seed §M: 3 cells, 2200 mAh
    battery_capacity_ah: float = 2.2
    battery_resistance_ohm: float = 0.05  # pack + wiring
    hover_current_a: float = 6.8  # seed §L: 4 x 1.7 A
    avionics_current_a: float = 0.5  # seed §L: Gumstix, laser, hub
    drag_linear_per_s: float = 0.3  # k1
    drag_quadratic_per_m: float = 0.1  # k2
    wind_std_mps: float = 0.1  # OU gust velocity, horizontal
    wind_std_z_mps: float = 0.05  # OU gust velocity, vertical
    wind_tau_s: float = 2.0
    gusts: bool = True
    pitch_trim_std_rad: float = 0.005  # per flight, seeded
    acc_bias_std_mps2: float = 0.05  # per flight and axis, seeded
    vibration_std_mps2: float = 0.2  # left in the FC-averaged accelerations at hover thrust
    angle_noise_std_rad: float = 0.002
    battery_noise_std_v: float = 0.02

    @classmethod
    def from_config(cls, cfg: Config) -> VehicleParams:
        """Counts, signs and g from ``mk``; the airframe from ``sim.vehicle``; rest default."""
        v = cfg.sim.vehicle
        return cls(
            g_mps2=cfg.mk.g_mps2,
            counts_per_rad=cfg.mk.counts_per_rad,
            nick_sign=cfg.mk.signs.nick,
            roll_sign=cfg.mk.signs.roll,
            yaw_sign=cfg.mk.signs.yaw,
            mass_kg=v.mass_kg,
            hover_gas_counts=v.hover_gas,
            hover_voltage_v=cfg.control.hover_voltage_v,
            attitude_delay_s=v.attitude_delay_s,
            attitude_tau_s=v.attitude_tau_s,
            gusts=v.gusts,
            wind_std_mps=v.wind_std_mps,
            wind_tau_s=v.wind_tau_s,
            pitch_trim_std_rad=v.trim_std_rad,
            acc_bias_std_mps2=v.acc_bias_std_mps2,
            vibration_std_mps2=v.vibration_std_mps2,
            battery_capacity_ah=v.battery_capacity_ah,
        )


@dataclass(frozen=True, slots=True)
class Sticks:
    """What the FC flies (``mkflight.sim.fc_control.FcCommand``), in MK counts.

    + nick = nose down, + roll = left side down, + yaw = nose turns left; gas 0..255.
    """

    nick_counts: float = 0.0
    roll_counts: float = 0.0
    yaw_counts: float = 0.0
    gas_counts: float = 0.0


@dataclass(frozen=True, slots=True)
class FlightErrors:
    """Per-flight constant errors (seeded): attitude trim and accelerometer biases."""

    pitch_trim_rad: float = 0.0
    roll_trim_rad: float = 0.0
    acc_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)


Vec3 = tuple[float, float, float]
_ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Everything :func:`step` needs (SI, world frame W, z down; the floor is z = 0).

    ``targets`` is the delay line: ``(t_s, pitch*, roll*, yaw_rate*)`` per step, newest
    last. ``acc_w_mps2`` is the last acceleration (for the specific force).
    """

    t_s: float = 0.0
    pos_w_m: Vec3 = _ZERO
    vel_w_mps: Vec3 = _ZERO
    acc_w_mps2: Vec3 = _ZERO
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    thrust_n: float = 0.0
    used_ah: float = 0.0
    battery_v: float = 0.0
    current_a: float = 0.0
    wind_w_mps: Vec3 = _ZERO
    on_ground: bool = True
    errors: FlightErrors = field(default_factory=FlightErrors)
    targets: tuple[tuple[float, float, float, float], ...] = ()

    @property
    def height_m(self) -> float:
        """Height above the floor, positive up."""
        return -self.pos_w_m[2]


def thrust_n(gas_counts: float, battery_v: float, params: VehicleParams) -> float:
    """Steady thrust for a gas at a terminal voltage: ∝ gas and ∝ V² (seed §K, §M)."""
    gas = min(max(gas_counts, 0.0), params.gas_max_counts)
    weight = params.mass_kg * params.g_mps2
    return weight * gas / params.hover_gas_counts * (battery_v / params.hover_voltage_v) ** 2


def hover_gas_counts(state: VehicleState, params: VehicleParams) -> float:
    """The (fractional) gas that holds altitude level at the state's battery (a test aid)."""
    volts = state.battery_v
    weight = params.mass_kg * params.g_mps2
    for _ in range(20):  # fixed point: gas -> current -> sag -> gas
        gas = params.hover_gas_counts * (params.hover_voltage_v / volts) ** 2
        amps = current_a(weight, volts, params)
        volts = open_circuit_v(state.used_ah, params) - amps * params.battery_resistance_ohm
    return gas


def initial_state(
    params: VehicleParams,
    rng: np.random.Generator,
    *,
    pos_w_m: Vec3 = _ZERO,
    yaw_rad: float = 0.0,
    used_ah: float = 0.0,
) -> VehicleState:
    """A vehicle at rest (on the floor if ``pos_w_m[2] == 0``) with this flight's errors.

    The trims and biases are drawn from ``rng`` (constant for the flight, seeded); the
    initial wind from the OU stationary distribution when gusts are on.
    """
    trims = rng.normal(0.0, params.pitch_trim_std_rad, 2)
    biases = rng.normal(0.0, params.acc_bias_std_mps2, 3)
    errors = FlightErrors(
        pitch_trim_rad=float(trims[0]),
        roll_trim_rad=float(trims[1]),
        acc_bias_mps2=(float(biases[0]), float(biases[1]), float(biases[2])),
    )
    wind = _ZERO
    if params.gusts:
        std = np.array([params.wind_std_mps, params.wind_std_mps, params.wind_std_z_mps])
        w = rng.normal(0.0, 1.0, 3) * std
        wind = (float(w[0]), float(w[1]), float(w[2]))
    on_ground = pos_w_m[2] >= 0.0
    return VehicleState(
        pos_w_m=(pos_w_m[0], pos_w_m[1], min(pos_w_m[2], 0.0)),
        yaw_rad=wrap_pi(yaw_rad),
        pitch_rad=0.0 if on_ground else errors.pitch_trim_rad,
        roll_rad=0.0 if on_ground else errors.roll_trim_rad,
        used_ah=used_ah,
        battery_v=open_circuit_v(used_ah, params)
        - params.avionics_current_a * params.battery_resistance_ohm,
        current_a=params.avionics_current_a,
        wind_w_mps=wind,
        on_ground=on_ground,
        errors=errors,
    )


def body_to_world(pitch_rad: float, roll_rad: float, yaw_rad: float) -> np.ndarray:
    """R(ψ) R_y(θ) R_x(φ): FRD body -> world W (SPEC §1, §8)."""
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _delayed_target(
    targets: tuple[tuple[float, float, float, float], ...], t_s: float
) -> tuple[float, float, float]:
    """The command in force at ``t_s`` (zero-order hold; before any command: zero)."""
    chosen = (0.0, 0.0, 0.0)
    for entry in targets:
        if entry[0] <= t_s + 1e-12:
            chosen = (entry[1], entry[2], entry[3])
        else:
            break
    return chosen


def _check(sticks: Sticks, dt_s: float) -> None:
    """Reject what no FC can send: a non-finite stick or time step."""
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        msg = f"vehicle step: dt_s must be finite and > 0, got {dt_s}"
        raise ValueError(msg)
    for name in ("nick_counts", "roll_counts", "yaw_counts", "gas_counts"):
        value = getattr(sticks, name)
        if not math.isfinite(value):
            msg = f"vehicle step: sticks.{name} must be finite, got {value}"
            raise ValueError(msg)


def step(
    state: VehicleState,
    sticks: Sticks,
    dt_s: float,
    params: VehicleParams,
    rng: np.random.Generator,
) -> VehicleState:
    """Advance the vehicle by ``dt_s`` with constant sticks (sub-stepped at ≤ 5 ms).

    Raises:
        ValueError: ``dt_s`` not finite and positive, or a non-finite stick.
    """
    _check(sticks, dt_s)
    lim = params.max_tilt_rad
    pitch_cmd = min(max(params.nick_sign * sticks.nick_counts / params.counts_per_rad, -lim), lim)
    roll_cmd = min(max(params.roll_sign * sticks.roll_counts / params.counts_per_rad, -lim), lim)
    rate_cmd = params.yaw_sign * sticks.yaw_counts * params.yaw_rate_radps_per_count
    horizon = state.t_s - params.attitude_delay_s
    kept = tuple(e for e in state.targets if e[0] > horizon - 1e-12)
    older = [e for e in state.targets if e[0] <= horizon - 1e-12]
    if older:  # keep the last command at or before the horizon: it is still in force
        kept = (older[-1], *kept)
    targets = (*kept, (state.t_s, pitch_cmd, roll_cmd, rate_cmd))
    n = max(1, math.ceil(dt_s / MAX_SUBSTEP_S - 1e-9))
    return _integrate(replace(state, targets=targets), sticks.gas_counts, dt_s / n, n, params, rng)


def _integrate(
    s: VehicleState,
    gas: float,
    h: float,
    n: int,
    params: VehicleParams,
    rng: np.random.Generator,
) -> VehicleState:
    """``n`` integration steps of ``h`` (exact lags and OU, semi-implicit Euler).

    Plain floats, not numpy, and one random draw for all sub-steps: this loop is most of
    the simulator's run time.
    """
    g, m = params.g_mps2, params.mass_kg
    lag = 1.0 - math.exp(-h / params.attitude_tau_s)
    thrust_lag = 1.0 - math.exp(-h / params.thrust_tau_s)
    decay = math.exp(-h / params.wind_tau_s)
    kick = math.sqrt(1.0 - decay * decay)
    if params.gusts:
        std = (params.wind_std_mps, params.wind_std_mps, params.wind_std_z_mps)
        draws = rng.normal(0.0, 1.0, (n, 3)).tolist()
    e = s.errors
    t, pitch, roll, yaw, rate = s.t_s, s.pitch_rad, s.roll_rad, s.yaw_rad, s.yaw_rate_radps
    x, y, z = s.pos_w_m
    vx, vy, vz = s.vel_w_mps
    ax, ay, az = s.acc_w_mps2
    wx, wy, wz = s.wind_w_mps
    thrust, used, volts, amps, on_ground = (
        s.thrust_n,
        s.used_ah,
        s.battery_v,
        s.current_a,
        s.on_ground,
    )
    for i in range(n):
        p_cmd, r_cmd, rate_cmd = _delayed_target(s.targets, t - params.attitude_delay_s)
        pitch += (p_cmd + e.pitch_trim_rad - pitch) * lag
        roll += (r_cmd + e.roll_trim_rad - roll) * lag
        rate += (rate_cmd - rate) * lag
        thrust += (thrust_n(gas, volts, params) - thrust) * thrust_lag
        if params.gusts:
            d = draws[i]
            wx = wx * decay + std[0] * kick * d[0]
            wy = wy * decay + std[1] * kick * d[1]
            wz = wz * decay + std[2] * kick * d[2]
        rx, ry, rz = vx - wx, vy - wy, vz - wz
        k = params.drag_linear_per_s + params.drag_quadratic_per_m * math.sqrt(
            rx * rx + ry * ry + rz * rz
        )
        # third column of R(ψ) R_y(θ) R_x(φ): the body z axis in W
        cp, sp = math.cos(pitch), math.sin(pitch)
        cr, sr = math.cos(roll), math.sin(roll)
        cy, sy = math.cos(yaw), math.sin(yaw)
        a_t = -thrust / m
        ax = (cy * sp * cr + sy * sr) * a_t - k * rx
        ay = (sy * sp * cr - cy * sr) * a_t - k * ry
        az = cp * cr * a_t + g - k * rz
        on_ground = on_ground and az >= 0.0
        if on_ground:  # resting on the floor: level, still, no yaw
            pitch = roll = rate = 0.0
            vx = vy = vz = ax = ay = az = z = 0.0
        else:
            vx, vy, vz = vx + ax * h, vy + ay * h, vz + az * h
            x, y, z = x + vx * h, y + vy * h, z + vz * h
            yaw = wrap_pi(yaw + rate * h)
            if z >= 0.0:  # touched the floor: an inelastic stop
                vx = vy = vz = ax = ay = az = z = 0.0
                on_ground = True
        amps = current_a(thrust, volts, params)
        used += amps * h / 3600.0
        volts = open_circuit_v(used, params) - amps * params.battery_resistance_ohm
        t += h
    return replace(
        s,
        t_s=t,
        pos_w_m=(x, y, z),
        vel_w_mps=(vx, vy, vz),
        acc_w_mps2=(ax, ay, az),
        pitch_rad=pitch,
        roll_rad=roll,
        yaw_rad=yaw,
        yaw_rate_radps=rate,
        thrust_n=thrust,
        used_ah=used,
        battery_v=volts,
        current_a=amps,
        wind_w_mps=(wx, wy, wz),
        on_ground=on_ground,
    )
