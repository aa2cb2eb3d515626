"""The simulated airframe (``mkflight.sim.airframe``): nominal from ``sim``, or drawn."""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import Config, ControlConfig, MkConfig, SimConfig, SimVehicleConfig
from mkflight.sim.airframe import (
    ACC_SCALE_ERROR_XY,
    ACC_SCALE_ERROR_Z,
    ENVELOPE,
    NOMINAL_VEHICLE,
    SAG_MINUTES,
    airframe_from_config,
    battery_for,
    describe,
    draw_airframe,
    nominal_airframe,
    random_airframe,
)
from mkflight.sim.battery import open_circuit_v
from mkflight.sim.vehicle import VehicleParams, initial_state

# drawn name -> its ENVELOPE range (the per-axis draws share one range)
RANGE_OF = {
    "acc_bias_nick_counts": "acc_bias_counts",
    "acc_bias_roll_counts": "acc_bias_counts",
    "acc_bias_z_counts": "acc_bias_counts",
    "angle_bias_pitch_rad": "angle_bias_rad",
    "angle_bias_roll_rad": "angle_bias_rad",
}


def _within(value: float, name: str) -> bool:
    r = ENVELOPE[name]
    return r.lo - 1e-12 <= value <= r.hi + 1e-12


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_every_drawn_value_is_within_the_envelope(seed: int) -> None:
    a = draw_airframe(seed)
    for name, value in a.drawn.items():
        if name.startswith("acc_scale_"):
            limit = ACC_SCALE_ERROR_Z if name == "acc_scale_z" else ACC_SCALE_ERROR_XY
            assert abs(value) <= limit
        elif name == "battery_used_ah":
            assert 0.0 <= value < a.params.battery_capacity_ah
        else:
            assert _within(value, RANGE_OF.get(name, name)), (name, value)
    assert set(ENVELOPE) <= {RANGE_OF.get(n, n) for n in a.drawn}  # every range is drawn
    p = a.params
    for name in (
        "attitude_delay_s",
        "attitude_tau_s",
        "counts_per_rad",
        "yaw_rate_radps_per_count",
        "yaw_drift_radps",
        "hover_gas_counts",
        "drag_linear_per_s",
        "gust_accel_std_mps2",
        "vibration_z_ratio",
        "ground_effect",
        "laser_extra_delay_s",
        "laser_jitter_s",
        "debug_jitter_ticks",
        "debug_late_fraction",
    ):
        assert _within(getattr(p, name), name), name
    assert _within(p.thrust_tau_s, "thrust_tau_s")
    assert all(_within(t, "angle_bias_rad") for t in p.trim_rad)
    assert p.pitch_trim_std_rad == p.acc_bias_std_mps2 == 0.0  # all fixed, none per flight
    # the accelerometer's errors, back in the counts of its own scales
    g = p.g_mps2
    assert _within(-p.acc_bias_mps2[0] * p.acc_nick_counts_per_g / g, "acc_bias_counts")
    assert _within(p.acc_bias_mps2[1] * p.acc_roll_counts_per_g / g, "acc_bias_counts")
    assert _within(-p.acc_bias_mps2[2] * p.acc_z_counts_per_mps2, "acc_bias_counts")
    assert _within(p.vibration_std_mps2 * p.acc_nick_counts_per_g / g, "vibration_counts")
    start_v = open_circuit_v(p.battery_used_ah, p)
    assert start_v == pytest.approx(a.drawn["battery_start_v"], abs=0.05)


def test_draws_are_reproducible_and_differ_by_seed() -> None:
    assert draw_airframe(7) == draw_airframe(7)
    assert draw_airframe(7).params != draw_airframe(8).params
    assert random_airframe(7) == draw_airframe(7).params
    assert airframe_from_config(SimConfig(airframe="random", seed=7)) == draw_airframe(7).params


def test_draws_cover_the_envelope() -> None:
    drawn = [draw_airframe(s).drawn for s in range(300)]
    for name, r in ENVELOPE.items():
        if name in ("acc_bias_counts", "angle_bias_rad"):
            continue
        values = np.array([d[name] for d in drawn])
        span = r.hi - r.lo
        assert values.min() < r.lo + 0.1 * span, name
        assert values.max() > r.hi - 0.1 * span, name


@settings(max_examples=40, deadline=None)
@given(st.floats(11.8, 12.6), st.floats(0.7, 1.5))
def test_battery_for_gives_the_start_voltage_and_the_sag(start_v: float, sag_v: float) -> None:
    capacity, used = battery_for(start_v, sag_v, NOMINAL_VEHICLE)
    p = replace(NOMINAL_VEHICLE, battery_capacity_ah=capacity, battery_used_ah=used)
    assert open_circuit_v(used, p) == pytest.approx(start_v, abs=0.05)
    amps = p.hover_current_a + p.avionics_current_a
    after = used + amps * SAG_MINUTES / 60.0
    assert open_circuit_v(used, p) - open_circuit_v(after, p) == pytest.approx(sag_v, abs=0.05)
    s = initial_state(p, np.random.default_rng(0))  # the flight starts at that voltage
    assert s.used_ah == used


def test_nominal_airframe_reads_only_the_sim_section() -> None:
    base = airframe_from_config(Config().sim)
    assert base == nominal_airframe(Config().sim) == VehicleParams.from_config(SimVehicleConfig())
    other_flight_code = Config(
        mk=MkConfig(counts_per_rad=90.0, acc_nick_counts_per_g=500.0, g_mps2=9.8),
        control=ControlConfig(hover_gas=120.0, hover_voltage_v=12.5),
    )
    assert airframe_from_config(other_flight_code.sim) == base


@pytest.mark.parametrize(
    ("key", "value", "field", "expected"),
    [
        ("counts_per_rad", 110.0, "counts_per_rad", 110.0),
        ("hover_gas", 95.0, "hover_gas_counts", 95.0),
        ("hover_voltage_v", 12.0, "hover_voltage_v", 12.0),
        ("yaw_drift_radps", 0.01, "yaw_drift_radps", 0.01),
        ("gas_tau_s", 0.08, "thrust_tau_s", 0.08),
        ("ground_effect", 0.1, "ground_effect", 0.1),
        ("gust_accel_std_mps2", 0.2, "gust_accel_std_mps2", 0.2),
        ("vibration_z_ratio", 0.5, "vibration_z_ratio", 0.5),
        ("battery_used_ah", 0.4, "battery_used_ah", 0.4),
        ("debug_jitter_ticks", 2, "debug_jitter_ticks", 2),
        ("gear_friction", 0.8, "gear_friction", 0.8),
        ("hat_offset_m", 0.04, "hat_offset_m", 0.04),
        ("wind_std_mps", 0.3, "wind_std_z_mps", 0.15),
    ],
)
def test_nominal_airframe_takes_each_sim_vehicle_key(
    key: str, value: float, field: str, expected: float
) -> None:
    vehicle = msgspec.structs.replace(SimVehicleConfig(), **{key: value})
    params = nominal_airframe(SimConfig(vehicle=vehicle))
    assert getattr(params, field) == expected


def test_describe_is_plain_json_of_every_field() -> None:
    d = describe(draw_airframe(5).params)
    assert set(d) == {f.name for f in fields(VehicleParams)}
    again = json.loads(json.dumps(d))
    assert again == d
    assert all(not isinstance(v, float) or math.isfinite(v) for v in d.values())
