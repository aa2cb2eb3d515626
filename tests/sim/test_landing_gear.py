"""The landing gear (``mkflight.sim.landing_gear`` inside ``vehicle.step``): touchdowns."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import SimVehicleConfig
from mkflight.sim.landing_gear import crossing_time, transition
from mkflight.sim.vehicle import (
    FlightErrors,
    Sticks,
    VehicleParams,
    VehicleState,
    hover_gas_counts,
    initial_state,
    step,
)

# still air, no drag, no battery sag under load: a given gas is a constant thrust
STILL = VehicleParams.from_config(
    SimVehicleConfig(
        gusts=False, drag_linear_per_s=0.0, drag_quadratic_per_m=0.0, battery_resistance_ohm=0.0
    )
)
G = STILL.g_mps2
SAG = STILL.gear_sag_m
RNG = np.random.default_rng(0)


def _descending(
    speed_mps: float, thrust_share: float, height_m: float = 0.02, params: VehicleParams = STILL
) -> tuple[VehicleState, float]:
    """In the air at ``height_m``, going down at ``speed_mps``, thrust at that share of weight.

    Returns the state and the gas that keeps the thrust there.
    """
    s = initial_state(params, RNG, pos_w_m=(0.0, 0.0, -height_m))
    s = replace(
        s,
        vel_w_mps=(0.0, 0.0, speed_mps),
        errors=FlightErrors(),
        pitch_rad=0.0,
        roll_rad=0.0,
        thrust_n=thrust_share * params.mass_kg * params.g_mps2,
    )
    return s, thrust_share * hover_gas_counts(s, params)


def _record(
    s: VehicleState, gas: float, seconds: float, dt_s: float, params: VehicleParams = STILL
) -> tuple[VehicleState, np.ndarray]:
    """Fly ``seconds`` in steps of ``dt_s``; rows of (t, height, vz, upward acceleration)."""
    rows = []
    for _ in range(round(seconds / dt_s)):
        s = step(s, Sticks(gas_counts=gas), dt_s, params, RNG)
        rows.append((s.t_s, s.height_m, s.vel_w_mps[2], -s.acc_w_mps2[2]))
    return s, np.array(rows)


@pytest.mark.parametrize("zeta", [0.0, 0.3, 1.0, 1.0 + 1e-7, 6.0])
def test_transition_is_the_exact_damped_oscillator(zeta: float) -> None:
    w, h = 35.0, 0.005
    p0, p1, p2, p3 = transition(zeta, w, h)
    for e0, v0 in ((0.01, 0.0), (0.0, 0.5), (-0.004, 0.3)):
        e, v, dt = e0, v0, 1e-6  # fine semi-implicit Euler as the reference
        for _ in range(round(h / dt)):
            v += (-w * w * e - 2.0 * zeta * w * v) * dt
            e += v * dt
        assert p0 * e0 + p1 * v0 == pytest.approx(e, abs=1e-6)
        assert p2 * e0 + p3 * v0 == pytest.approx(v, abs=1e-4)


def test_crossing_time_is_the_first_root() -> None:
    assert crossing_time(-0.01, 1.0, 0.0, 0.05) == pytest.approx(0.01)
    tau = crossing_time(-0.01, 0.2, 9.81, 0.05)
    assert -0.01 + 0.2 * tau + 0.5 * 9.81 * tau * tau == pytest.approx(0.0, abs=1e-12)
    assert crossing_time(-0.01, -1.0, 0.0, 0.05) == 0.05  # moving away: never (clamped)


@pytest.mark.parametrize("dt_s", [0.001, 0.005, 0.02, 0.05])
@pytest.mark.parametrize("height_m", [0.02, 0.3])
def test_touchdown_speed_is_the_impact_speed(dt_s: float, height_m: float) -> None:
    """Free fall (motors off, no drag): the gear meets the floor at sqrt(2 g (h + sag))."""
    s, _ = _descending(0.0, 0.0, height_m=height_m)
    s, _ = _record(s, 0.0, 0.6, dt_s)
    ((t_touch, speed),) = s.touchdowns
    fall_m = height_m - SAG  # the gear touches at height gear_sag_m (z = -gear_sag_m)
    assert speed == pytest.approx(math.sqrt(2.0 * G * fall_m), rel=0.02)
    assert t_touch == pytest.approx(math.sqrt(2.0 * fall_m / G), rel=0.02)


@pytest.mark.parametrize("speed_mps", [0.1, 0.3, 0.5, 1.2])
def test_touchdown_at_constant_descent_records_that_speed(speed_mps: float) -> None:
    s, gas = _descending(speed_mps, 1.0, height_m=0.3)
    s, rows = _record(s, gas, 0.3 / speed_mps + 0.5, 0.005)
    assert len(s.touchdowns) == 1
    t_touch, speed = s.touchdowns[0]
    last_in_air = rows[rows[:, 0] < t_touch][-1]  # <= 5 ms before the contact
    assert speed == pytest.approx(last_in_air[2], rel=0.02)
    assert speed == pytest.approx(speed_mps, rel=0.25)  # the pack's voltage drops a little
    assert t_touch - last_in_air[0] == pytest.approx(
        (last_in_air[1] - SAG) / last_in_air[2], abs=1e-4
    )


@pytest.mark.parametrize("speed_mps", [0.3, 0.5])
@pytest.mark.parametrize("thrust_share", [0.0, 0.5, 0.9])  # motors cut ... still descending
def test_a_touchdown_is_stopped_over_40_to_100_ms(speed_mps: float, thrust_share: float) -> None:
    s, gas = _descending(speed_mps, thrust_share, height_m=SAG + 1e-4)
    s, rows = _record(s, gas, 0.5, 0.0005)
    ((t0, v0),) = s.touchdowns
    assert v0 == pytest.approx(speed_mps, rel=0.02)
    after = rows[rows[:, 0] >= t0]
    t, vz = after[:, 0] - t0, after[:, 2]
    moving = t[np.abs(vz) > 0.05 * v0]
    stop_s = float(moving.max()) if moving.size else 0.0  # from then on within 5 % of v0
    assert 0.040 <= stop_s <= 0.100
    up_mps2 = after[:, 3]  # the vehicle's upward acceleration: 0 once at rest
    spread_s = float(np.sum(up_mps2 >= 0.25 * up_mps2.max())) * 0.0005
    assert spread_s >= 0.040  # not a one-sample spike


@pytest.mark.parametrize("speed_mps", [0.3, 0.5])
def test_a_sampled_accelerometer_sees_most_touchdowns(speed_mps: float) -> None:
    """The FC's DebugOut (every ~53 ms) catches >= 3 m/s² of deceleration at most phases."""
    s, gas = _descending(speed_mps, 0.9, height_m=SAG + 1e-4)
    s, rows = _record(s, gas, 0.4, 0.0005)
    t0 = s.touchdowns[0][0]
    decel = rows[:, 3]  # upward acceleration
    phases = np.arange(0.0, 0.053, 0.001)
    seen = 0
    for phase in phases:
        idx = np.searchsorted(rows[:, 0], t0 + phase + np.arange(0.0, 0.2, 0.053))
        seen += bool((decel[idx[idx < len(rows)]] >= 3.0).any())
    assert seen / len(phases) >= 0.7


@pytest.mark.parametrize("thrust_share", [0.0, 0.7, 0.9, 0.98])
def test_no_bounce_from_a_half_metre_per_second_touchdown(thrust_share: float) -> None:
    s, gas = _descending(0.5, thrust_share, height_m=0.05)
    s, rows = _record(s, gas, 2.0, 0.005)
    t0 = s.touchdowns[0][0]
    assert len(s.touchdowns) == 1
    assert rows[rows[:, 0] > t0, 1].max() < SAG + 0.01  # never 1 cm above the first contact
    assert s.on_ground
    assert s.height_m == pytest.approx(thrust_share * SAG, abs=2e-4)  # static compression


def test_static_compression_is_a_few_mm() -> None:
    rest = initial_state(STILL, RNG)
    assert rest.height_m == 0.0  # the motors-off rest position is z = 0
    assert rest.on_ground
    assert 0.002 <= SAG <= 0.01
    s, _ = _record(rest, 0.5 * STILL.hover_gas_counts, 3.0, 0.05)
    assert s.on_ground
    share = s.thrust_n / (STILL.mass_kg * G)
    assert s.height_m == pytest.approx(share * SAG, abs=5e-5)


def test_a_landed_vehicle_rests_level_and_does_not_slide() -> None:
    gusty = VehicleParams.from_config(SimVehicleConfig(gust_accel_std_mps2=0.25))
    s, gas = _descending(0.4, 0.8, height_m=0.2, params=gusty)
    s = replace(s, vel_w_mps=(0.3, -0.2, 0.4), pitch_rad=0.06, roll_rad=-0.04, yaw_rate_radps=0.3)
    s, _ = _record(s, gas, 1.0, 0.05, gusty)
    assert s.on_ground
    assert (s.pitch_rad, s.roll_rad, s.yaw_rate_radps) == (0.0, 0.0, 0.0)
    assert s.vel_w_mps[:2] == (0.0, 0.0)
    before = s.pos_w_m[:2]
    s, rows = _record(s, gas, 5.0, 0.05, gusty)
    assert s.pos_w_m[:2] == before  # held by friction against the gusts
    assert np.abs(rows[20:, 2]).max() < 3e-3  # the gear's springing under the gusts
    assert len(s.touchdowns) == 1


def test_resting_at_nearly_hover_thrust_adds_no_touchdowns() -> None:
    """Spinning up to 95 % of the hover thrust in gusts: the gear chatters, no touchdowns."""
    gusty = VehicleParams.from_config(SimVehicleConfig(gust_accel_std_mps2=0.25))
    s = initial_state(gusty, RNG, gust_seed=2)
    s, rows = _record(s, 0.95 * hover_gas_counts(s, gusty), 20.0, 0.05, gusty)
    assert s.touchdowns == ()
    assert rows[:, 1].max() < SAG  # the gear never left the floor


def test_slow_contacts_are_not_touchdowns() -> None:
    s, gas = _descending(0.03, 0.9, height_m=SAG + 1e-4)  # meets the floor at 0.033 m/s
    s, _ = _record(s, gas, 0.5, 0.05)
    assert s.on_ground
    assert s.touchdowns == ()


def test_it_takes_off_from_the_gear() -> None:
    s = initial_state(STILL, RNG)
    s, _ = _record(s, 1.3 * STILL.hover_gas_counts, 1.5, 0.05)
    assert not s.on_ground
    assert s.height_m > 0.3
    assert s.touchdowns == ()


@settings(max_examples=25, deadline=None)
@given(
    st.floats(0.05, 3.0),
    st.floats(0.0, 0.95),  # thrust below the weight: it stays down
    st.sampled_from([0.002, 0.005, 0.01, 0.05, 0.1]),
)
def test_any_touchdown_is_recorded_once_and_settles(
    speed_mps: float, thrust_share: float, dt_s: float
) -> None:
    s, gas = _descending(speed_mps, thrust_share, height_m=0.05)
    v_impact = math.sqrt(speed_mps**2 + 2.0 * G * (1.0 - thrust_share) * (0.05 - SAG))
    s, rows = _record(s, gas, 2.0, dt_s)
    assert len(s.touchdowns) == 1
    assert s.touchdowns[0][1] == pytest.approx(v_impact, rel=0.02)
    assert s.on_ground
    assert abs(s.vel_w_mps[2]) < 0.01
    assert np.all(np.isfinite(rows))
    assert rows[:, 1].min() > -0.1  # the gear stops a 3 m/s fall within a few cm
