"""The simulated MikroKopter: an FRD rigid body flown by the FC's own attitude loop (SPEC §8).

Pure and synchronous: :func:`step` takes a :class:`VehicleState`, the sticks the FC applies
(:class:`Sticks`, after its own rules: extern + pilot sticks, gas capped by the stick gas),
a time step and a ``numpy.random.Generator`` (kept for the signature: the vehicle itself
draws nothing, its randomness is fixed at :func:`initial_state`), and returns the next
state. Nothing reads a clock; time is ``state.t_s``.

Model (world frame W: x forward, y right, z down; body B FRD; SPEC §1; § alone: a section
of the 2011 QUT CyPhy MikroKopter documentation):

* **Attitude** (§F, ~200 ms response): the MK's attitude loop tracks the commanded
  angles after a pure delay (``attitude_delay_s`` ≈ 0.1 s) through a first-order lag
  (``attitude_tau_s`` ≈ 0.1 s). Commanded angle = ``sign * counts / counts_per_rad`` with
  ``sign = -1`` (SPEC §1: + nick tilts the nose down, our pitch is + nose up; + roll lowers
  the left side, our roll is + right side down). The yaw stick commands a yaw *rate*
  ``sign_yaw * yaw * yaw_rate_radps_per_count + yaw_drift_radps`` (+ yaw turns the nose
  left, our ψ is clockwise; the drift is the rate at a neutral stick) through the same
  delay and lag. The true angle also carries the flight's attitude trim: the FC levels its
  own (slightly wrong) horizon.
* **Thrust** (§K, §M): ``T = m g (gas / hover_gas_counts) (V / hover_voltage_v)^2`` with the
  battery's terminal voltage V, through a motor lag ``thrust_tau_s``; at ``hover_gas_counts``
  and ``hover_voltage_v`` it equals the weight. ``hover_gas_counts`` is the airframe's own
  (``sim.vehicle.hover_gas``, or drawn), never the controller's ``control.hover_gas``.
  Near the floor the rotors push harder (ground effect): the force is ``T (1 + ground_effect
  (r / (r + h))^2)``, ``r = ground_effect_height_m``, ``h`` the height above the landed
  position (+``ground_effect`` on the floor, 2 % of it at 0.6 m). ``thrust_n`` is the rotors'
  own thrust, without it.
* **Battery** (§L, §M): open-circuit voltage from a LiPo curve of the state of charge
  (:mod:`mkflight.sim.battery`, per cell) minus ``I R``; ``I`` = avionics current + the motors'
  current, which scales as ``(T / W)^1.5`` (momentum theory: power ∝ T^1.5) at §L's
  6.8 A hover current, divided by ``V / V_hover`` (same power, other voltage).
* **Translation** (SPEC §8): ``a_W = R(ψ) R_y(θ) R_x(φ) (0, 0, -T/m) + (0, 0, g) - drag +
  gust``, drag = ``k1 v_rel + k2 |v_rel| v_rel`` per unit mass on the air-relative velocity.
  Integration: 5 ms sub-steps (:mod:`mkflight.sim.vehicle_substep`), velocity by Euler,
  position by the trapezoid (exact under a constant acceleration, so a touchdown's speed is
  exact).
* **Gusts** (:mod:`mkflight.sim.gusts`): an Ornstein-Uhlenbeck wind velocity (std
  ``wind_std_mps``, ``wind_std_z_mps``, correlation time ``wind_tau_s``), felt through the
  drag (≈ ``k1 * 0.1 m/s`` = a few cm/s²), and an OU disturbance acceleration (std
  ``gust_accel_std_mps2`` in x and y, ``gust_accel_z_ratio`` of that in z, correlation time
  ``gust_tau_s``). Both are a function of ``(gust_seed, t)`` only, read at each sub-step's
  midpoint: the same gusts whatever the step pattern. ``gusts = False``: still air.
* **Floor and landing gear** (:mod:`mkflight.sim.landing_gear`): z = 0 is where the vehicle
  rests with the motors off. The gear touches the floor at ``z = -gear_sag_m`` and is a
  spring-damper pushing up (compression softly damped, rebound heavily: a touchdown is
  stopped over ≈ 40 ms and does not bounce) with Coulomb friction (``gear_friction``) on the
  floor; while in contact the gear levels the vehicle and stops its yaw (time constant
  :data:`~mkflight.sim.landing_gear.GEAR_LEVEL_TAU_S`). ``on_ground`` = the gear touches.
  Every touchdown from the air (first contact at >= 0.05 m/s) is recorded in
  ``touchdowns`` with its downward speed at first contact.

The sensors (what the FC and the laser would measure of this state) live in
:mod:`mkflight.sim.vehicle_sensors`.
"""

from __future__ import annotations

import math

import numpy as np

from mkflight.frames import wrap_pi
from mkflight.sim.battery import current_a, open_circuit_v
from mkflight.sim.gusts import GustSeries, gust_series, gusts_at
from mkflight.sim.landing_gear import MIN_TOUCHDOWN_MPS
from mkflight.sim.vehicle_substep import (
    NO_COMMAND,
    Target,
    air_at,
    air_constants,
    attitude_constants,
    attitude_tracked,
    battery_step,
    delayed_command,
    floor_friction,
    free_acceleration,
    gear_constants,
    gear_levelled,
    gear_push_mps2,
    gear_vertical,
    motor_thrust_n,
    pack_constants,
    rotor_constants,
    segment_at,
    touchdown_vertical,
    yawed,
)
from mkflight.sim.vehicle_types import (
    FlightErrors,
    Sticks,
    Vec3,
    VehicleParams,
    VehicleState,
)

__all__ = [
    "MAX_SUBSTEP_S",
    "FlightErrors",
    "Sticks",
    "Vec3",
    "VehicleParams",
    "VehicleState",
    "body_to_world",
    "ground_effect_factor",
    "gust_series",
    "gusts_at",
    "hover_gas_counts",
    "initial_state",
    "step",
    "thrust_n",
]

MAX_SUBSTEP_S = 0.005  # integration step: well below every time constant
_ZERO: Vec3 = (0.0, 0.0, 0.0)


def thrust_n(gas_counts: float, battery_v: float, params: VehicleParams) -> float:
    """Steady thrust for a gas at a terminal voltage: ∝ gas and ∝ V² (§K, §M)."""
    gas = min(max(gas_counts, 0.0), params.gas_max_counts)
    weight = params.mass_kg * params.g_mps2
    return weight * gas / params.hover_gas_counts * (battery_v / params.hover_voltage_v) ** 2


def ground_effect_factor(height_m: float, params: VehicleParams) -> float:
    """``1 + ground_effect (r / (r + h))^2``: the rotors' thrust gain at ``height_m``."""
    r = params.ground_effect_height_m
    q = r / (r + max(height_m, 0.0))
    return 1.0 + params.ground_effect * q * q


def hover_gas_counts(state: VehicleState, params: VehicleParams) -> float:
    """The (fractional) gas that holds altitude level at the state's battery (a test aid).

    Out of ground effect.
    """
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
    used_ah: float | None = None,
    gust_seed: int = 0,
) -> VehicleState:
    """A vehicle at rest (resting on the floor if ``pos_w_m[2] >= 0``) with this flight's errors.

    The trims and biases are the airframe's fixed ones plus normal draws from ``rng``
    (constant for the flight); ``used_ah`` ``None`` is the airframe's
    ``battery_used_ah``; ``gust_seed`` fixes the flight's gusts (wind and disturbance
    acceleration), a function of ``(gust_seed, t)`` only.
    """
    trims = rng.normal(0.0, params.pitch_trim_std_rad, 2)
    biases = rng.normal(0.0, params.acc_bias_std_mps2, 3)
    fixed_bias = params.acc_bias_mps2
    errors = FlightErrors(
        pitch_trim_rad=params.trim_rad[0] + float(trims[0]),
        roll_trim_rad=params.trim_rad[1] + float(trims[1]),
        acc_bias_mps2=(
            fixed_bias[0] + float(biases[0]),
            fixed_bias[1] + float(biases[1]),
            fixed_bias[2] + float(biases[2]),
        ),
    )
    series = gust_series(params, gust_seed)
    wind, gust = gusts_at(series, params, 0.0)
    used = params.battery_used_ah if used_ah is None else used_ah
    z = min(pos_w_m[2], 0.0)
    on_ground = z > -params.gear_sag_m
    return VehicleState(
        pos_w_m=(pos_w_m[0], pos_w_m[1], z),
        yaw_rad=wrap_pi(yaw_rad),
        pitch_rad=0.0 if on_ground else errors.pitch_trim_rad,
        roll_rad=0.0 if on_ground else errors.roll_trim_rad,
        used_ah=used,
        battery_v=open_circuit_v(used, params)
        - params.avionics_current_a * params.battery_resistance_ohm,
        current_a=params.avionics_current_a,
        wind_w_mps=wind,
        gust_w_mps2=gust,
        on_ground=on_ground,
        errors=errors,
        gusts=series,
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

    ``rng`` is unused (the gusts are the state's series, a function of time): two calls
    of 50 ms and one of 100 ms give the same flight to within the integration's error.

    Raises:
        ValueError: ``dt_s`` not finite and positive, or a non-finite stick.
    """
    del rng
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
    series = state.gusts
    if params.gusts and (
        series is None
        or series.wind_tau_s != params.wind_tau_s
        or series.accel_tau_s != params.gust_tau_s
    ):
        series = GustSeries(
            0 if series is None else series.seed, params.wind_tau_s, params.gust_tau_s
        )
    n = max(1, math.ceil(dt_s / MAX_SUBSTEP_S - 1e-9))
    return _integrate(state, targets, series, sticks.gas_counts, dt_s / n, n, params)


def _integrate(
    s: VehicleState,
    targets: tuple[Target, ...],
    gust_source: GustSeries | None,
    gas: float,
    h: float,
    n: int,
    params: VehicleParams,
) -> VehicleState:
    """``n`` sub-steps of ``h`` from ``s`` (exact lags, exact gear; the module docstring).

    ``targets`` is the delay line and ``gust_source`` the gust series of the new state.
    Each sub-step runs :mod:`mkflight.sim.vehicle_substep`'s functions in their order.
    """
    att = attitude_constants(params, s.errors, h)
    rotors = rotor_constants(params, gas, h)
    air_source = air_constants(params, gust_source)
    gear = gear_constants(params, h)
    pack = pack_constants(params)
    segment = segment_at(s.used_ah, params)
    nxt, command = 0, NO_COMMAND
    t, pitch, roll, yaw, rate = s.t_s, s.pitch_rad, s.roll_rad, s.yaw_rad, s.yaw_rate_radps
    x, y, z = s.pos_w_m
    vx, vy, vz = s.vel_w_mps
    ax, ay, az = s.acc_w_mps2
    thrust, used, volts, amps = s.thrust_n, s.used_ah, s.battery_v, s.current_a
    touchdowns = s.touchdowns
    for _ in range(n):
        d = z + gear.sag_m  # the gear's compression (> 0: touching)
        contact = d > 0.0
        nxt, command = delayed_command(targets, nxt, command, t - att.delay_s + 1e-12)
        if contact:
            pitch, roll, rate = gear_levelled(pitch, roll, rate, att.level)
        else:
            pitch, roll, rate = attitude_tracked(pitch, roll, rate, command, att)
        thrust = motor_thrust_n(thrust, volts, rotors)
        air = air_at(air_source, t + 0.5 * h)
        ax, ay, az = free_acceleration(pitch, roll, yaw, thrust, z, (vx, vy, vz), air, rotors)
        push = gear_push_mps2(d, vz, gear) if contact else 0.0
        if push > 0.0:  # the gear carries the vehicle: friction, exact spring-damper
            fx, fy = floor_friction(vx, vy, ax, ay, push, h, gear.friction)
            ax, ay = (fx - vx) / h, (fy - vy) / h
            z_next, fz, az = gear_vertical(d, vz, az, gear)
        else:  # velocity by Euler, position by the trapezoid
            fx, fy, fz = vx + ax * h, vy + ay * h, vz + az * h
            z_next = z + 0.5 * (vz + fz) * h
            if not contact and z_next + gear.sag_m > 0.0:  # a touchdown within this sub-step
                tau, v_touch, (z_next, fz, az) = touchdown_vertical(d, vz, az, h, gear)
                if v_touch >= MIN_TOUCHDOWN_MPS:
                    touchdowns = (*touchdowns, (t + tau, v_touch))
        x += 0.5 * (vx + fx) * h
        y += 0.5 * (vy + fy) * h
        vx, vy, vz, z = fx, fy, fz, z_next
        yaw = yawed(yaw, rate, h)
        amps, used, segment, volts = battery_step(thrust, volts, used, segment, h, pack)
        t += h
    wind, gust = gusts_at(air_source.series, params, t)
    return VehicleState(  # not dataclasses.replace: twice as fast, and this is the hot path
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
        wind_w_mps=wind,
        gust_w_mps2=gust,
        on_ground=z + gear.sag_m > 0.0,
        errors=s.errors,
        targets=targets,
        touchdowns=touchdowns,
        gusts=gust_source,
    )
