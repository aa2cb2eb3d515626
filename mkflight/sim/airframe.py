"""The simulated airframe: the nominal one of the config, or one drawn from the envelope.

The simulator is a second opinion (SPEC §8): its vehicle's true constants come from the
``sim`` config section only, never from ``mk``, ``control`` or the flight code's
calibration. :func:`airframe_from_config` gives the :class:`~mkflight.sim.vehicle.VehicleParams`
of a flight:

* ``sim.airframe: nominal`` — SPEC §8's airframe, ``sim.vehicle`` as configured;
* ``sim.airframe: random`` — every constant drawn with ``sim.seed`` from :data:`ENVELOPE`,
  uniformly within each range: another build, another FC tuning, a worn prop, ground
  effect, a late USB laser. The flight is judged on many of these (``mkflight sim
  envelope``), never on the airframe its gains were tuned on.

The envelope (units in the names; § alone: a section of the 2011 QUT CyPhy MikroKopter
documentation):

====================================  ===============  ======================================
constant                              range            what it models
====================================  ===============  ======================================
``attitude_delay_s``                  0.06 .. 0.18     the FC's attitude response: pure delay
``attitude_tau_s``                    0.06 .. 0.22     ... and first-order lag (§F)
``counts_per_rad``                    100 .. 140       the FC's stick counts per radian
``yaw_rate_radps_per_count``          0.015 .. 0.025   the yaw stick's rate
``hover_gas_counts``                  82 .. 115        gas holding the weight at take-off
``thrust_tau_s``                      0.03 .. 0.10     motors + ESCs
``drag_linear_per_s``                 0.15 .. 0.5      airframe drag
``gust_accel_std_mps2``               0.1 .. 0.25      turbulence (OU acceleration, x and y;
                                                       0.4 of it on z; correlation 0.3 s)
``acc_bias_counts`` (each axis)       -10 .. 10        AccNick, AccRoll, AccZ offsets
``vibration_counts``                  5 .. 30          motor vibration on AccNick/AccRoll
``vibration_z_ratio``                 0.3 .. 0.8       ... on AccZ, as a fraction of that
``angle_bias_rad`` (pitch, roll)      -0.02 .. 0.02    the FC's horizon is off by this
``yaw_drift_radps``                   -0.02 .. 0.02    yaw rate at a neutral yaw stick
``battery_start_v``                   11.8 .. 12.6     the pack at take-off (open circuit)
``battery_sag_v_per_15min``           0.7 .. 1.5       its sag over 15 min at hover current
``ground_effect``                     0 .. 0.15        extra thrust on the ground
``laser_extra_delay_s``               0 .. 0.03        scans older than the driver assumes
``laser_jitter_s``                    0.002 .. 0.008   USB jitter per URG reply (uniform)
``debug_jitter_ticks``                0 .. 3           the FC's loop: DebugOut up to N ticks late
``debug_late_fraction``               0 .. 0.02        ... and this share 5-25 ms late
====================================  ===============  ======================================

The vibration counts are AccNick counts (606.3 per g); the AccZ vibration is that
fraction of the same acceleration. The accelerometer's scales are off by up to ±2 % (AccNick,
AccRoll) and ±3 % (AccZ), drawn too. The battery is the LiPo curve of
:mod:`mkflight.sim.battery` with the capacity and initial charge that give the drawn start
voltage and sag (:func:`battery_for`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields, replace
from typing import Final

import numpy as np

from mkflight.config import SimConfig, SimVehicleConfig
from mkflight.conversions import MIN_PER_H
from mkflight.sim.battery import LIPO_OCV_V
from mkflight.sim.vehicle import VehicleParams


@dataclass(frozen=True, slots=True)
class Range:
    """One envelope range, drawn uniformly."""

    lo: float
    hi: float
    what: str

    def draw(self, rng: np.random.Generator) -> float:
        """A value uniformly in ``[lo, hi]``."""
        return float(rng.uniform(self.lo, self.hi))


ENVELOPE: Final[dict[str, Range]] = {
    "attitude_delay_s": Range(0.06, 0.18, "the FC's attitude response: pure delay"),
    "attitude_tau_s": Range(0.06, 0.22, "... and first-order lag"),
    "counts_per_rad": Range(100.0, 140.0, "the FC's stick counts per radian"),
    "yaw_rate_radps_per_count": Range(0.015, 0.025, "the yaw stick's rate"),
    "hover_gas_counts": Range(82.0, 115.0, "gas holding the weight at take-off"),
    "thrust_tau_s": Range(0.03, 0.10, "motors + ESCs"),
    "drag_linear_per_s": Range(0.15, 0.5, "airframe drag"),
    "gust_accel_std_mps2": Range(0.1, 0.25, "turbulence (OU acceleration, x and y)"),
    "acc_bias_counts": Range(-10.0, 10.0, "accelerometer offsets, each axis"),
    "vibration_counts": Range(5.0, 30.0, "motor vibration on AccNick/AccRoll"),
    "vibration_z_ratio": Range(0.3, 0.8, "... on AccZ, as a fraction of that"),
    "angle_bias_rad": Range(-0.02, 0.02, "the FC's horizon error, pitch and roll"),
    "yaw_drift_radps": Range(-0.02, 0.02, "yaw rate at a neutral yaw stick"),
    "battery_start_v": Range(11.8, 12.6, "the pack at take-off (open circuit)"),
    "battery_sag_v_per_15min": Range(0.7, 1.5, "its sag over 15 min at hover current"),
    "ground_effect": Range(0.0, 0.15, "extra thrust on the ground"),
    "laser_extra_delay_s": Range(0.0, 0.03, "scans older than the driver assumes"),
    "laser_jitter_s": Range(0.002, 0.008, "USB jitter per URG reply"),
    "debug_jitter_ticks": Range(0.0, 3.0, "DebugOut up to N FC ticks late"),
    "debug_late_fraction": Range(0.0, 0.02, "... and this share 5-25 ms late"),
}
GUST_TAU_S: Final = 0.3
"""The turbulence's correlation time (s), not a range of the envelope: over 50
airframes an oracle's std peaks near 0.15-0.3 s (0.0076-0.0078 m median), so 0.3 s is the
hardest case for a position loop (1 s: 0.0059 m)."""
ACC_SCALE_ERROR_XY: Final = 0.02
ACC_SCALE_ERROR_Z: Final = 0.03
NOMINAL_VEHICLE: Final = VehicleParams.from_config(SimVehicleConfig())
SAG_MINUTES: Final = 15.0


def airframe_from_config(sim: SimConfig) -> VehicleParams:
    """The airframe ``sim`` describes: nominal (``sim.vehicle``) or random (``sim.seed``)."""
    if sim.airframe == "random":
        return random_airframe(sim.seed)
    return nominal_airframe(sim)


def nominal_airframe(sim: SimConfig) -> VehicleParams:
    """SPEC §8's airframe with the constants of ``sim.vehicle``."""
    return VehicleParams.from_config(sim.vehicle)


def battery_for(start_v: float, sag_v: float, params: VehicleParams) -> tuple[float, float]:
    """``(capacity_ah, used_ah)`` of a pack at ``start_v`` sagging ``sag_v`` in 15 minutes.

    ``start_v`` is the open-circuit voltage at take-off, the sag is over
    :data:`SAG_MINUTES` at the hover current, on the LiPo curve per cell. The curve gives
    the state of charge at both voltages; the charge drawn in 15 minutes at
    ``hover_current_a + avionics_current_a`` spans their difference.
    """
    soc0 = _soc_of(start_v / params.battery_cells)
    soc1 = _soc_of((start_v - sag_v) / params.battery_cells)
    drawn_ah = (params.hover_current_a + params.avionics_current_a) * SAG_MINUTES / MIN_PER_H
    capacity = drawn_ah / max(soc0 - soc1, 1e-3)
    return capacity, capacity * (1.0 - soc0)


def _soc_of(cell_v: float) -> float:
    """The state of charge at which the LiPo curve reads ``cell_v`` (clamped to 0..1)."""
    pts = LIPO_OCV_V
    if cell_v <= pts[0][1]:
        return 0.0
    for (s0, v0), (s1, v1) in itertools.pairwise(pts):
        if cell_v <= v1:
            return s0 + (s1 - s0) * (cell_v - v0) / (v1 - v0)
    return 1.0


@dataclass(frozen=True, slots=True)
class DrawnAirframe:
    """An airframe drawn from :data:`ENVELOPE`: the drawn values and its parameters."""

    seed: int
    drawn: dict[str, float]
    params: VehicleParams


def draw_airframe(seed: int) -> DrawnAirframe:
    """Draw every :data:`ENVELOPE` constant with ``seed`` (reproducible) and build the airframe."""
    rng = np.random.default_rng([seed, 17])
    d: dict[str, float] = {}
    for name, rng_range in ENVELOPE.items():
        if name in ("acc_bias_counts", "angle_bias_rad", "debug_jitter_ticks"):
            continue
        d[name] = rng_range.draw(rng)
    bias = ENVELOPE["acc_bias_counts"]
    d["acc_bias_nick_counts"] = bias.draw(rng)
    d["acc_bias_roll_counts"] = bias.draw(rng)
    d["acc_bias_z_counts"] = bias.draw(rng)
    angle = ENVELOPE["angle_bias_rad"]
    d["angle_bias_pitch_rad"] = angle.draw(rng)
    d["angle_bias_roll_rad"] = angle.draw(rng)
    d["acc_scale_nick"] = float(rng.uniform(-ACC_SCALE_ERROR_XY, ACC_SCALE_ERROR_XY))
    d["acc_scale_roll"] = float(rng.uniform(-ACC_SCALE_ERROR_XY, ACC_SCALE_ERROR_XY))
    d["acc_scale_z"] = float(rng.uniform(-ACC_SCALE_ERROR_Z, ACC_SCALE_ERROR_Z))
    d["debug_jitter_ticks"] = float(rng.integers(0, 4))  # 0..3 ticks, equally likely

    base = NOMINAL_VEHICLE
    g = base.g_mps2
    k_nick = base.acc_nick_counts_per_g * (1.0 + d["acc_scale_nick"])
    k_roll = base.acc_roll_counts_per_g * (1.0 + d["acc_scale_roll"])
    k_z = base.acc_z_counts_per_mps2 * (1.0 + d["acc_scale_z"])
    vib_xy = d["vibration_counts"] * g / k_nick
    capacity, used = battery_for(d["battery_start_v"], d["battery_sag_v_per_15min"], base)
    amps = base.hover_current_a + base.avionics_current_a
    hover_v = d["battery_start_v"] - amps * base.battery_resistance_ohm
    params = replace(
        base,
        counts_per_rad=d["counts_per_rad"],
        attitude_delay_s=d["attitude_delay_s"],
        attitude_tau_s=d["attitude_tau_s"],
        yaw_rate_radps_per_count=d["yaw_rate_radps_per_count"],
        yaw_drift_radps=d["yaw_drift_radps"],
        hover_gas_counts=d["hover_gas_counts"],
        hover_voltage_v=hover_v,
        thrust_tau_s=d["thrust_tau_s"],
        drag_linear_per_s=d["drag_linear_per_s"],
        gust_accel_std_mps2=d["gust_accel_std_mps2"],
        gust_tau_s=GUST_TAU_S,
        ground_effect=d["ground_effect"],
        pitch_trim_std_rad=0.0,
        trim_rad=(d["angle_bias_pitch_rad"], d["angle_bias_roll_rad"]),
        acc_bias_std_mps2=0.0,
        acc_bias_mps2=(
            # AccNick counts = -k f_x / g, AccRoll = +k f_y / g, AccZ = -(f_z + offset) k_z
            -d["acc_bias_nick_counts"] * g / k_nick,
            d["acc_bias_roll_counts"] * g / k_roll,
            -d["acc_bias_z_counts"] / k_z,
        ),
        vibration_std_mps2=vib_xy,
        vibration_z_ratio=d["vibration_z_ratio"],
        acc_nick_counts_per_g=k_nick,
        acc_roll_counts_per_g=k_roll,
        acc_z_counts_per_mps2=k_z,
        battery_capacity_ah=capacity,
        battery_used_ah=used,
        laser_extra_delay_s=d["laser_extra_delay_s"],
        laser_jitter_s=d["laser_jitter_s"],
        debug_jitter_ticks=int(d["debug_jitter_ticks"]),
        debug_late_fraction=d["debug_late_fraction"],
    )
    d["battery_used_ah"] = used
    return DrawnAirframe(seed, d, params)


def random_airframe(seed: int) -> VehicleParams:
    """The parameters of :func:`draw_airframe` (``sim.airframe: random``)."""
    return draw_airframe(seed).params


def describe(params: VehicleParams) -> dict[str, float | int | bool | list[float]]:
    """Every constant of ``params`` as plain values (reports, ``flight.json``)."""
    out: dict[str, float | int | bool | list[float]] = {}
    for f in fields(params):
        value = getattr(params, f.name)
        if isinstance(value, tuple):
            out[f.name] = [round(float(v), 6) for v in value]
        elif isinstance(value, float):
            out[f.name] = round(value, 6) if math.isfinite(value) else value
        else:
            out[f.name] = value
    return out
