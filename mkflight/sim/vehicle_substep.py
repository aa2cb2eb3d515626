"""One integration sub-step of the simulated vehicle, as pure functions of plain floats.

:func:`mkflight.sim.vehicle.step` cuts a step into sub-steps of at most
:data:`~mkflight.sim.vehicle.MAX_SUBSTEP_S` and runs these in order (the model and its
sources: :mod:`mkflight.sim.vehicle`'s docstring):

1. :func:`delayed_command`: the attitude command in force after the FC's delay;
2. :func:`attitude_tracked` in the air, :func:`gear_levelled` on the floor;
3. :func:`motor_thrust_n`: the motors' first-order lag towards the gas's thrust;
4. :func:`air_at`: wind and disturbance acceleration at the sub-step's midpoint;
5. :func:`free_acceleration`: thrust (with ground effect), gravity, drag and gust;
6. the floor: :func:`gear_push_mps2`, then while it pushes :func:`floor_friction` and
   :func:`gear_vertical`; else Euler velocity, trapezoid position, and
   :func:`touchdown_vertical` when the gear meets the floor within the sub-step;
7. :func:`yawed`, then :func:`battery_step`.

Plain floats and tuples, not numpy: this is most of the simulator's run time. Each
function keeps its arithmetic in one fixed order, so a flight's every bit is reproducible
from the same inputs.
"""

from __future__ import annotations

import functools
import math
from typing import Final, NamedTuple

from mkflight.conversions import S_PER_H
from mkflight.sim.battery import open_circuit_segment
from mkflight.sim.gusts import CHUNK_POINTS, GRID_S, GustSeries, Unit6
from mkflight.sim.landing_gear import GEAR_LEVEL_TAU_S, Transition, crossing_time, transition
from mkflight.sim.vehicle_types import FlightErrors, Vec3, VehicleParams

#: One entry of the delay line: ``(t_s, pitch_cmd_rad, roll_cmd_rad, yaw_rate_cmd_radps)``.
Target = tuple[float, float, float, float]
#: The open-circuit voltage's line: ``(volts, dv_per_ah, until_ah, from_ah)``
#: (:func:`~mkflight.sim.battery.open_circuit_segment`, read from ``from_ah``).
Segment = tuple[float, float, float, float]

NO_COMMAND: Final[Target] = (0.0, 0.0, 0.0, 0.0)  # before the first entry takes over
STILL_AIR: Final[Unit6] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
_TINY: Final = 1e-12  # angles and rates this small on the floor are zero (no denormal decay)
_PER_GRID: Final = 1.0 / GRID_S
_CHUNK_BITS: Final = CHUNK_POINTS.bit_length() - 1
_CHUNK_MASK: Final = CHUNK_POINTS - 1


class Attitude(NamedTuple):
    """The attitude loop's constants over a sub-step (first-order lags as step factors)."""

    delay_s: float  # the FC's pure delay before a command takes over
    lag: float  # 1 - exp(-h / attitude_tau_s)
    level: float  # 1 - exp(-h / GEAR_LEVEL_TAU_S): the gear levelling on the floor
    drift_radps: float  # yaw rate at a neutral stick
    pitch_trim_rad: float  # this flight's horizon error
    roll_trim_rad: float


class Rotors(NamedTuple):
    """Thrust, drag and gravity over a sub-step at a constant gas."""

    thrust_per_v2: float  # steady thrust per V² at this gas (N/V²)
    thrust_lag: float  # 1 - exp(-h / thrust_tau_s)
    mass_kg: float
    g_mps2: float
    drag_linear_per_s: float  # k1
    drag_quadratic_per_m: float  # k2
    ground_effect: float
    ground_effect_height_m: float


class Air(NamedTuple):
    """The flight's gust series and the standard deviations that scale it (None: still air)."""

    series: GustSeries | None
    wind_std_mps: float
    wind_std_z_mps: float
    accel_std_mps2: float
    accel_z_std_mps2: float


class Gear(NamedTuple):
    """The landing gear's spring-damper per unit mass (:mod:`mkflight.sim.landing_gear`)."""

    w2: float  # ω² = g / gear_sag_m (1/s²)
    sag_m: float  # g / ω²: the static compression, so that a resting vehicle sits at z = 0
    w: float  # ω (rad/s)
    c_comp: float  # 2 ζ_c ω while compressing (1/s)
    c_ext: float  # 2 ζ_e ω while extending
    zeta_comp: float
    zeta_ext: float
    friction: float  # Coulomb coefficient on the floor
    compress: Transition  # exact transition over a whole sub-step, compressing
    extend: Transition  # ... extending


class Pack(NamedTuple):
    """The battery's constants: current by thrust at constant power, ``I R`` sag."""

    weight_n: float
    hover_current_a: float
    hover_voltage_v: float
    avionics_current_a: float
    resistance_ohm: float
    params: VehicleParams  # for the LiPo curve's segments


def attitude_constants(params: VehicleParams, errors: FlightErrors, h_s: float) -> Attitude:
    """The attitude loop's constants over sub-steps of ``h_s``."""
    return Attitude(
        delay_s=params.attitude_delay_s,
        lag=1.0 - math.exp(-h_s / params.attitude_tau_s),
        level=1.0 - math.exp(-h_s / GEAR_LEVEL_TAU_S),
        drift_radps=params.yaw_drift_radps,
        pitch_trim_rad=errors.pitch_trim_rad,
        roll_trim_rad=errors.roll_trim_rad,
    )


def rotor_constants(params: VehicleParams, gas_counts: float, h_s: float) -> Rotors:
    """Thrust at ``gas_counts`` (∝ gas and V², module :mod:`~mkflight.sim.vehicle`), drag, g."""
    weight = params.mass_kg * params.g_mps2
    gas = min(max(gas_counts, 0.0), params.gas_max_counts)
    return Rotors(
        thrust_per_v2=weight * gas / params.hover_gas_counts / params.hover_voltage_v**2,
        thrust_lag=1.0 - math.exp(-h_s / params.thrust_tau_s),
        mass_kg=params.mass_kg,
        g_mps2=params.g_mps2,
        drag_linear_per_s=params.drag_linear_per_s,
        drag_quadratic_per_m=params.drag_quadratic_per_m,
        ground_effect=params.ground_effect,
        ground_effect_height_m=params.ground_effect_height_m,
    )


def air_constants(params: VehicleParams, series: GustSeries | None) -> Air:
    """The air of ``series`` scaled by ``params``' stds (still air when ``params.gusts`` is off)."""
    sa = params.gust_accel_std_mps2
    return Air(
        series=series if params.gusts else None,
        wind_std_mps=params.wind_std_mps,
        wind_std_z_mps=params.wind_std_z_mps,
        accel_std_mps2=sa,
        accel_z_std_mps2=sa * params.gust_accel_z_ratio,
    )


def gear_constants(params: VehicleParams, h_s: float) -> Gear:
    """The gear's spring-damper (ω² = g / gear_sag_m) and its transitions over ``h_s``."""
    w2 = params.g_mps2 / params.gear_sag_m
    w = math.sqrt(w2)
    zeta_c, zeta_e = params.gear_compression_zeta, params.gear_rebound_zeta
    compress, extend = _transitions(zeta_c, zeta_e, w, h_s)
    return Gear(
        w2=w2,
        sag_m=params.g_mps2 / w2,
        w=w,
        c_comp=2.0 * zeta_c * w,
        c_ext=2.0 * zeta_e * w,
        zeta_comp=zeta_c,
        zeta_ext=zeta_e,
        friction=params.gear_friction,
        compress=compress,
        extend=extend,
    )


@functools.lru_cache(maxsize=16)
def _transitions(
    zeta_comp: float, zeta_ext: float, w: float, h_s: float
) -> tuple[Transition, Transition]:
    """:func:`~mkflight.sim.landing_gear.transition` compressing and extending (cached)."""
    return transition(zeta_comp, w, h_s), transition(zeta_ext, w, h_s)


def pack_constants(params: VehicleParams) -> Pack:
    """The battery's constants of ``params``."""
    return Pack(
        weight_n=params.mass_kg * params.g_mps2,
        hover_current_a=params.hover_current_a,
        hover_voltage_v=params.hover_voltage_v,
        avionics_current_a=params.avionics_current_a,
        resistance_ohm=params.battery_resistance_ohm,
        params=params,
    )


def segment_at(used_ah: float, params: VehicleParams) -> Segment:
    """The LiPo curve's line through ``used_ah``, read from there."""
    volts, slope, until = open_circuit_segment(used_ah, params)
    return volts, slope, until, used_ah


def delayed_command(
    targets: tuple[Target, ...], nxt: int, command: Target, t_cmd_s: float
) -> tuple[int, Target]:
    """The delay line at ``t_cmd_s`` (= now - delay): ``(next entry, command in force)``.

    Entry ``nxt`` takes over once its time is at or before ``t_cmd_s``; the last entry
    that did is the command in force (``command`` if none did).
    """
    while nxt < len(targets) and targets[nxt][0] <= t_cmd_s:
        command = targets[nxt]
        nxt += 1
    return nxt, command


def gear_levelled(
    pitch_rad: float, roll_rad: float, rate_radps: float, level: float
) -> tuple[float, float, float]:
    """On the floor the gear levels the vehicle and stops its yaw (exact first-order lag)."""
    pitch_rad -= pitch_rad * level
    roll_rad -= roll_rad * level
    rate_radps -= rate_radps * level
    if abs(pitch_rad) < _TINY and abs(roll_rad) < _TINY and abs(rate_radps) < _TINY:
        return 0.0, 0.0, 0.0
    return pitch_rad, roll_rad, rate_radps


def attitude_tracked(
    pitch_rad: float, roll_rad: float, rate_radps: float, command: Target, a: Attitude
) -> tuple[float, float, float]:
    """In the air the attitude lags towards the command plus the trim (yaw: rate + drift)."""
    _, pitch_cmd, roll_cmd, rate_cmd = command
    pitch_rad += (pitch_cmd + a.pitch_trim_rad - pitch_rad) * a.lag
    roll_rad += (roll_cmd + a.roll_trim_rad - roll_rad) * a.lag
    rate_radps += (rate_cmd + a.drift_radps - rate_radps) * a.lag
    return pitch_rad, roll_rad, rate_radps


def motor_thrust_n(thrust_n: float, battery_v: float, r: Rotors) -> float:
    """The motors' thrust after a sub-step's lag towards ``thrust_per_v2 V²``."""
    return thrust_n + (r.thrust_per_v2 * battery_v * battery_v - thrust_n) * r.thrust_lag


def air_at(air: Air, t_s: float) -> Unit6:
    """``(wind x, y, z (m/s), gust x, y, z (m/s²))`` at ``t_s`` (:mod:`mkflight.sim.gusts`).

    :meth:`~mkflight.sim.gusts.GustSeries.unit_at` scaled, without its clamp and divmod.
    """
    if air.series is None:
        return STILL_AIR
    u = t_s * _PER_GRID
    k = int(u)
    f = u - k
    i = k & _CHUNK_MASK
    j = i + 1
    c0, c1, c2, c3, c4, c5 = air.series.chunk(k >> _CHUNK_BITS)
    sw, sa = air.wind_std_mps, air.accel_std_mps2
    return (
        sw * (c0[i] + f * (c0[j] - c0[i])),
        sw * (c1[i] + f * (c1[j] - c1[i])),
        air.wind_std_z_mps * (c2[i] + f * (c2[j] - c2[i])),
        sa * (c3[i] + f * (c3[j] - c3[i])),
        sa * (c4[i] + f * (c4[j] - c4[i])),
        air.accel_z_std_mps2 * (c5[i] + f * (c5[j] - c5[i])),
    )


def free_acceleration(
    pitch_rad: float,
    roll_rad: float,
    yaw_rad: float,
    thrust_n: float,
    z_m: float,
    vel_w_mps: Vec3,
    air: Unit6,
    r: Rotors,
) -> Vec3:
    """Every acceleration but the gear's (W, m/s²): thrust along body -z, g, drag, gust.

    The thrust is along the third column of R(ψ) R_y(θ) R_x(φ) (SPEC §8), times the
    ground effect at the height ``-z_m``; the drag is ``k1 v + k2 |v| v`` on the
    air-relative velocity.
    """
    vx, vy, vz = vel_w_mps
    rx, ry, rz = vx - air[0], vy - air[1], vz - air[2]
    kd = r.drag_linear_per_s + r.drag_quadratic_per_m * math.sqrt(rx * rx + ry * ry + rz * rz)
    a_t = -thrust_n / r.mass_kg
    ge = r.ground_effect
    if ge != 0.0:
        ge_r = r.ground_effect_height_m
        q = ge_r / (ge_r + (-z_m if z_m < 0.0 else 0.0))
        a_t *= 1.0 + ge * q * q
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return (
        (cy * sp * cr + sy * sr) * a_t - kd * rx + air[3],
        (sy * sp * cr - cy * sr) * a_t - kd * ry + air[4],
        cp * cr * a_t + r.g_mps2 - kd * rz + air[5],
    )


def gear_push_mps2(compression_m: float, vz_mps: float, gear: Gear) -> float:
    """The spring-damper's force per unit mass at a compression (> 0: touching), up +."""
    return gear.w2 * compression_m + (gear.c_comp if vz_mps > 0.0 else gear.c_ext) * vz_mps


def floor_friction(
    vx_mps: float,
    vy_mps: float,
    ax_mps2: float,
    ay_mps2: float,
    push_mps2: float,
    h_s: float,
    mu: float,
) -> tuple[float, float]:
    """The horizontal velocity after a sub-step on the floor (Coulomb friction ``mu push``)."""
    fx, fy = vx_mps + ax_mps2 * h_s, vy_mps + ay_mps2 * h_s
    slip = math.sqrt(fx * fx + fy * fy)
    grip = mu * push_mps2 * h_s
    if slip <= grip:  # static friction holds
        return 0.0, 0.0
    fx -= fx * grip / slip
    fy -= fy * grip / slip
    return fx, fy


def gear_vertical(compression_m: float, vz_mps: float, az_mps2: float, gear: Gear) -> Vec3:
    """``(z, vz, az)`` after a sub-step on the gear: the exact spring-damper about equilibrium.

    ``az_mps2`` (every acceleration but the gear's) is held over the sub-step; the returned
    acceleration is the gear's total at the sub-step's end.
    """
    p0, p1, p2, p3 = gear.compress if vz_mps > 0.0 else gear.extend
    d_eq = az_mps2 / gear.w2
    e0 = compression_m - d_eq
    e1 = p0 * e0 + p1 * vz_mps
    vz = p2 * e0 + p3 * vz_mps
    z = d_eq + e1 - gear.sag_m
    return z, vz, -(gear.w2 * e1 + (gear.c_comp if vz > 0.0 else gear.c_ext) * vz)


def touchdown_vertical(
    compression_m: float, vz_mps: float, az_mps2: float, h_s: float, gear: Gear
) -> tuple[float, float, Vec3]:
    """``(tau, v_touch, (z, vz, az))``: the gear meets the floor ``tau`` into the sub-step.

    Free fall up to the crossing (:func:`~mkflight.sim.landing_gear.crossing_time`), at
    ``v_touch`` down, then the exact spring-damper for the rest of the sub-step.
    """
    tau = crossing_time(compression_m, vz_mps, az_mps2, h_s)
    v_touch = vz_mps + az_mps2 * tau
    zeta = gear.zeta_comp if v_touch > 0.0 else gear.zeta_ext
    p0, p1, p2, p3 = transition(zeta, gear.w, h_s - tau)
    d_eq = az_mps2 / gear.w2
    e1 = p0 * -d_eq + p1 * v_touch
    vz = p2 * -d_eq + p3 * v_touch
    z = d_eq + e1 - gear.sag_m
    az = -(gear.w2 * e1 + (gear.c_comp if vz > 0.0 else gear.c_ext) * vz)
    return tau, v_touch, (z, vz, az)


def yawed(yaw_rad: float, rate_radps: float, h_s: float) -> float:
    """The yaw after a sub-step at ``rate_radps``, wrapped to (-π, π]."""
    yaw_rad += rate_radps * h_s
    if yaw_rad > math.pi:
        return yaw_rad - 2.0 * math.pi
    if yaw_rad <= -math.pi:
        return yaw_rad + 2.0 * math.pi
    return yaw_rad


def battery_step(
    thrust_n: float, battery_v: float, used_ah: float, segment: Segment, h_s: float, pack: Pack
) -> tuple[float, float, Segment, float]:
    """``(current_a, used_ah, segment, battery_v)`` after a sub-step at ``thrust_n``.

    The current is avionics + motors at ``(T/W)^1.5`` and constant power (as
    :func:`~mkflight.sim.battery.current_a`, at the sub-step's start voltage); the terminal
    voltage is the open-circuit voltage of the charge drawn minus ``I R``.
    """
    ratio = thrust_n / pack.weight_n if thrust_n > 0.0 else 0.0
    hover_v = pack.hover_voltage_v
    amps = pack.avionics_current_a + pack.hover_current_a * ratio * math.sqrt(
        ratio
    ) * hover_v / max(battery_v, 0.1 * hover_v)
    used_ah += amps * h_s / S_PER_H
    if used_ah > segment[2]:  # the next line of the LiPo curve
        segment = segment_at(used_ah, pack.params)
    ocv, slope, _, from_ah = segment
    return amps, used_ah, segment, ocv + slope * (used_ah - from_ah) - amps * pack.resistance_ohm
