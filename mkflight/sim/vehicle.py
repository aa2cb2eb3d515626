"""The simulated MikroKopter: an FRD rigid body flown by the FC's own attitude loop (SPEC §8).

Pure and synchronous: :func:`step` takes a :class:`VehicleState`, the sticks the FC applies
(:class:`Sticks`, after its own rules: extern + pilot sticks, gas capped by the stick gas),
a time step and a ``numpy.random.Generator`` (kept for the signature: the vehicle itself
draws nothing, its randomness is fixed at :func:`initial_state`), and returns the next
state. Nothing reads a clock; time is ``state.t_s``.

Model (world frame W: x forward, y right, z down; body B FRD; SPEC §1):

* **Attitude** (seed §F, ~200 ms response): the MK's attitude loop tracks the commanded
  angles after a pure delay (``attitude_delay_s`` ≈ 0.1 s) through a first-order lag
  (``attitude_tau_s`` ≈ 0.1 s). Commanded angle = ``sign * counts / counts_per_rad`` with
  ``sign = -1`` (SPEC §1: + nick tilts the nose down, our pitch is + nose up; + roll lowers
  the left side, our roll is + right side down). The yaw stick commands a yaw *rate*
  ``sign_yaw * yaw * yaw_rate_radps_per_count + yaw_drift_radps`` (+ yaw turns the nose
  left, our ψ is clockwise; the drift is the rate at a neutral stick) through the same
  delay and lag. The true angle also carries the flight's attitude trim: the FC levels its
  own (slightly wrong) horizon.
* **Thrust** (seed §K, §M): ``T = m g (gas / hover_gas) (V / V_hover)^2`` with the battery's
  terminal voltage V, through a motor lag ``thrust_tau_s``; at ``hover_gas_counts`` and
  ``hover_voltage_v`` it equals the weight. Near the floor the rotors push harder (ground
  effect): the force is ``T (1 + ground_effect (r / (r + h))^2)``, ``r =
  ground_effect_height_m``, ``h`` the height above the landed position (+``ground_effect``
  on the floor, 2 % of it at 0.6 m). ``thrust_n`` is the rotors' own thrust, without it.
* **Battery** (seed §L, §M): open-circuit voltage from a LiPo curve of the state of charge
  (:mod:`mkflight.sim.battery`, per cell) minus ``I R``; ``I`` = avionics current + the motors'
  current, which scales as ``(T / W)^1.5`` (momentum theory: power ∝ T^1.5) at the seed's
  6.8 A hover current, divided by ``V / V_hover`` (same power, other voltage).
* **Translation** (SPEC §8): ``a_W = R(ψ) R_y(θ) R_x(φ) (0, 0, -T/m) + (0, 0, g) - drag +
  gust``, drag = ``k1 v_rel + k2 |v_rel| v_rel`` per unit mass on the air-relative velocity.
  Integration: 5 ms sub-steps, velocity by Euler, position by the trapezoid (exact under a
  constant acceleration, so a touchdown's speed is exact).
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

from mkflight.conversions import S_PER_H
from mkflight.frames import wrap_pi
from mkflight.sim.battery import current_a, open_circuit_segment, open_circuit_v
from mkflight.sim.gusts import CHUNK_POINTS, GRID_S, GustSeries, gust_series, gusts_at
from mkflight.sim.landing_gear import (
    GEAR_LEVEL_TAU_S,
    MIN_TOUCHDOWN_MPS,
    Transition,
    crossing_time,
    transition,
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
_TINY = 1e-12  # angles and rates this small on the floor are zero (no denormal decay)
_PER_GRID = 1.0 / GRID_S
_CHUNK_BITS = CHUNK_POINTS.bit_length() - 1
_CHUNK_MASK = CHUNK_POINTS - 1
_ZERO: Vec3 = (0.0, 0.0, 0.0)


def thrust_n(gas_counts: float, battery_v: float, params: VehicleParams) -> float:
    """Steady thrust for a gas at a terminal voltage: ∝ gas and ∝ V² (seed §K, §M)."""
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
    targets: tuple[tuple[float, float, float, float], ...],
    gust_source: GustSeries | None,
    gas: float,
    h: float,
    n: int,
    params: VehicleParams,
) -> VehicleState:
    """``n`` integration steps of ``h`` from ``s`` (exact lags, exact gear; module docstring).

    ``targets`` is the delay line and ``gust_source`` the gust series of the new state.

    Plain floats, not numpy, no function call that can be avoided (thrust, battery, the
    delay line and the gusts are inlined): this loop is most of the simulator's run time.
    """
    g, m = params.g_mps2, params.mass_kg
    lag = 1.0 - math.exp(-h / params.attitude_tau_s)
    thrust_lag = 1.0 - math.exp(-h / params.thrust_tau_s)
    level = 1.0 - math.exp(-h / GEAR_LEVEL_TAU_S)
    drift = params.yaw_drift_radps
    k1, k2 = params.drag_linear_per_s, params.drag_quadratic_per_m
    # thrust_n(gas, V) = thrust_per_v2 V^2; the battery (mkflight.sim.battery) inlined
    weight = m * g
    gas_c = min(max(gas, 0.0), params.gas_max_counts)
    thrust_per_v2 = weight * gas_c / params.hover_gas_counts / params.hover_voltage_v**2
    hover_a, hover_v = params.hover_current_a, params.hover_voltage_v
    avionics_a, ohm = params.avionics_current_a, params.battery_resistance_ohm
    ocv, ocv_slope, ocv_until = open_circuit_segment(s.used_ah, params)
    ocv_from = s.used_ah
    # the landing gear (mkflight.sim.landing_gear)
    w2 = g / params.gear_sag_m  # the gear's ω²
    sag = g / w2  # == gear_sag_m, written so that a resting vehicle sits at z = 0.0 exactly
    w = math.sqrt(w2)
    c_comp, c_ext = 2.0 * params.gear_compression_zeta * w, 2.0 * params.gear_rebound_zeta * w
    mu = params.gear_friction
    phi_comp: Transition | None = None
    phi_ext: Transition | None = None
    ge, ge_r = params.ground_effect, params.ground_effect_height_m
    # the air (mkflight.sim.gusts)
    series = gust_source if params.gusts else None
    sw, swz = params.wind_std_mps, params.wind_std_z_mps
    sa = params.gust_accel_std_mps2
    saz = sa * params.gust_accel_z_ratio
    chunk_index = -1
    c0 = c1 = c2 = c3 = c4 = c5 = [0.0]
    wx = wy = wz = gx = gy = gz = 0.0
    e = s.errors
    trim_p, trim_r = e.pitch_trim_rad, e.roll_trim_rad
    # the delay line: entry ``nxt`` takes over at targets[nxt][0] + delay
    delay = params.attitude_delay_s
    nxt = 0
    p_cmd = r_cmd = rate_cmd = 0.0
    t, pitch, roll, yaw, rate = s.t_s, s.pitch_rad, s.roll_rad, s.yaw_rad, s.yaw_rate_radps
    x, y, z = s.pos_w_m
    vx, vy, vz = s.vel_w_mps
    ax, ay, az = s.acc_w_mps2
    thrust, used, volts, amps = s.thrust_n, s.used_ah, s.battery_v, s.current_a
    touchdowns = s.touchdowns
    for _ in range(n):
        d = z + sag  # the gear's compression (> 0: touching)
        contact = d > 0.0
        t_cmd = t - delay + 1e-12
        while nxt < len(targets) and targets[nxt][0] <= t_cmd:
            _, p_cmd, r_cmd, rate_cmd = targets[nxt]
            nxt += 1
        if contact:  # the gear holds the vehicle level and stops its yaw
            pitch -= pitch * level
            roll -= roll * level
            rate -= rate * level
            if abs(pitch) < _TINY and abs(roll) < _TINY and abs(rate) < _TINY:
                pitch = roll = rate = 0.0
        else:
            pitch += (p_cmd + trim_p - pitch) * lag
            roll += (r_cmd + trim_r - roll) * lag
            rate += (rate_cmd + drift - rate) * lag
        thrust += (thrust_per_v2 * volts * volts - thrust) * thrust_lag
        if series is not None:  # the air at the sub-step's midpoint (mkflight.sim.gusts)
            u = (t + 0.5 * h) * _PER_GRID
            k = int(u)
            f = u - k
            i = k & _CHUNK_MASK
            if k >> _CHUNK_BITS != chunk_index:
                chunk_index = k >> _CHUNK_BITS
                c0, c1, c2, c3, c4, c5 = series.chunk(chunk_index)
            j = i + 1
            wx = sw * (c0[i] + f * (c0[j] - c0[i]))
            wy = sw * (c1[i] + f * (c1[j] - c1[i]))
            wz = swz * (c2[i] + f * (c2[j] - c2[i]))
            gx = sa * (c3[i] + f * (c3[j] - c3[i]))
            gy = sa * (c4[i] + f * (c4[j] - c4[i]))
            gz = saz * (c5[i] + f * (c5[j] - c5[i]))
        rx, ry, rz = vx - wx, vy - wy, vz - wz
        kd = k1 + k2 * math.sqrt(rx * rx + ry * ry + rz * rz)
        a_t = -thrust / m
        if ge != 0.0:
            q = ge_r / (ge_r + (-z if z < 0.0 else 0.0))
            a_t *= 1.0 + ge * q * q
        # third column of R(ψ) R_y(θ) R_x(φ): the body z axis in W
        cp, sp = math.cos(pitch), math.sin(pitch)
        cr, sr = math.cos(roll), math.sin(roll)
        cy, sy = math.cos(yaw), math.sin(yaw)
        ax = (cy * sp * cr + sy * sr) * a_t - kd * rx + gx
        ay = (sy * sp * cr - cy * sr) * a_t - kd * ry + gy
        az = cp * cr * a_t + g - kd * rz + gz  # everything but the gear
        push = w2 * d + (c_comp if vz > 0.0 else c_ext) * vz if contact else 0.0
        if push > 0.0:  # the gear carries the vehicle: friction, exact spring-damper
            fx, fy = vx + ax * h, vy + ay * h
            slip = math.sqrt(fx * fx + fy * fy)
            grip = mu * push * h
            if slip <= grip:  # static friction holds
                fx = fy = 0.0
            else:
                fx -= fx * grip / slip
                fy -= fy * grip / slip
            ax, ay = (fx - vx) / h, (fy - vy) / h
            x += 0.5 * (vx + fx) * h
            y += 0.5 * (vy + fy) * h
            vx, vy = fx, fy
            if vz > 0.0:
                if phi_comp is None:
                    phi_comp = transition(params.gear_compression_zeta, w, h)
                p0, p1, p2, p3 = phi_comp
            else:
                if phi_ext is None:
                    phi_ext = transition(params.gear_rebound_zeta, w, h)
                p0, p1, p2, p3 = phi_ext
            d_eq = az / w2
            e0 = d - d_eq
            e1 = p0 * e0 + p1 * vz
            vz = p2 * e0 + p3 * vz
            z = d_eq + e1 - sag
            az = -(w2 * e1 + (c_comp if vz > 0.0 else c_ext) * vz)  # at the sub-step's end
        else:
            fx, fy, fz = vx + ax * h, vy + ay * h, vz + az * h
            x += 0.5 * (vx + fx) * h
            y += 0.5 * (vy + fy) * h
            z_next = z + 0.5 * (vz + fz) * h
            if not contact and z_next + sag > 0.0:  # a touchdown within this sub-step
                tau = crossing_time(d, vz, az, h)
                v_touch = vz + az * tau
                if v_touch >= MIN_TOUCHDOWN_MPS:
                    touchdowns = (*touchdowns, (t + tau, v_touch))
                zeta = params.gear_compression_zeta if v_touch > 0.0 else params.gear_rebound_zeta
                p0, p1, p2, p3 = transition(zeta, w, h - tau)
                d_eq = az / w2
                e1 = p0 * -d_eq + p1 * v_touch
                fz = p2 * -d_eq + p3 * v_touch
                z_next = d_eq + e1 - sag
                az = -(w2 * e1 + (c_comp if fz > 0.0 else c_ext) * fz)
            vx, vy, vz, z = fx, fy, fz, z_next
        yaw += rate * h
        if yaw > math.pi:
            yaw -= 2.0 * math.pi
        elif yaw <= -math.pi:
            yaw += 2.0 * math.pi
        # current_a(): avionics + motors at (T/W)^1.5, constant power
        ratio = thrust / weight if thrust > 0.0 else 0.0
        amps = avionics_a + hover_a * ratio * math.sqrt(ratio) * hover_v / max(volts, 0.1 * hover_v)
        used += amps * h / S_PER_H
        if used > ocv_until:  # the next segment of the LiPo curve
            ocv, ocv_slope, ocv_until = open_circuit_segment(used, params)
            ocv_from = used
        volts = ocv + ocv_slope * (used - ocv_from) - amps * ohm
        t += h
    wind, gust = gusts_at(series, params, t)
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
        on_ground=z + sag > 0.0,
        errors=s.errors,
        targets=targets,
        touchdowns=touchdowns,
        gusts=gust_source,
    )
