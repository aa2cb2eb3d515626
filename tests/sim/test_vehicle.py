from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import Config, SimVehicleConfig
from mkflight.sim.airframe import airframe_from_config
from mkflight.sim.battery import open_circuit_v
from mkflight.sim.vehicle import (
    FlightErrors,
    Sticks,
    VehicleParams,
    VehicleState,
    body_to_world,
    ground_effect_factor,
    hover_gas_counts,
    initial_state,
    step,
    thrust_n,
)
from mkflight.sim.vehicle_sensors import battery_reading_v, imu_measured_si, imu_truth_si

NOMINAL = VehicleParams.from_config(SimVehicleConfig())
CALM = VehicleParams.from_config(SimVehicleConfig(gusts=False))
DT = 0.05
WEIGHT_N = CALM.mass_kg * CALM.g_mps2


def _hovering(params: VehicleParams, height_m: float = 1.0, used_ah: float = 1.1) -> VehicleState:
    """In the air, no trim or bias, thrust settled at the weight."""
    s = initial_state(
        params, np.random.default_rng(0), pos_w_m=(0.0, 0.0, -height_m), used_ah=used_ah
    )
    return replace(
        s,
        errors=FlightErrors(),
        pitch_rad=0.0,
        roll_rad=0.0,
        thrust_n=params.mass_kg * params.g_mps2,
    )


def _fly(
    s: VehicleState, sticks: Sticks, seconds: float, params: VehicleParams, seed: int = 0
) -> VehicleState:
    rng = np.random.default_rng(seed)
    for _ in range(round(seconds / DT)):
        s = step(s, sticks, DT, params, rng)
    return s


def test_defaults_hover_at_the_airframes_hover_gas_not_the_controllers() -> None:
    cfg = Config()
    p = airframe_from_config(cfg.sim)
    assert p == NOMINAL  # the nominal airframe is the sim.vehicle section's defaults
    assert p.hover_gas_counts == cfg.sim.vehicle.hover_gas == 104
    assert cfg.control.hover_gas == 100  # the controller's feed-forward is off by 4 %
    assert thrust_n(104, 11.8, p) == pytest.approx(p.mass_kg * p.g_mps2)
    assert thrust_n(104, 11.8 * 0.9, p) == pytest.approx(0.81 * p.mass_kg * p.g_mps2)


def test_hover_gas_holds_altitude() -> None:
    s0 = _hovering(CALM)
    s = _fly(s0, Sticks(gas_counts=hover_gas_counts(s0, CALM)), 3.0, CALM)
    assert abs(s.height_m - 1.0) < 0.01
    assert math.hypot(s.pos_w_m[0], s.pos_w_m[1]) < 1e-9
    assert not s.on_ground


def test_more_gas_climbs_less_gas_sinks() -> None:
    s0 = _hovering(CALM)
    gas = hover_gas_counts(s0, CALM)
    assert _fly(s0, Sticks(gas_counts=gas + 5), 1.0, CALM).height_m > 1.05
    assert _fly(s0, Sticks(gas_counts=gas - 5), 1.0, CALM).height_m < 0.95


@pytest.mark.parametrize(
    ("sticks", "axis", "sign"),
    [
        (Sticks(nick_counts=12), 0, +1),  # + nick: nose down, accelerates forward
        (Sticks(nick_counts=-12), 0, -1),
        (Sticks(roll_counts=12), 1, -1),  # + roll: left side down, accelerates left
        (Sticks(roll_counts=-12), 1, +1),
    ],
)
def test_command_signs(sticks: Sticks, axis: int, sign: int) -> None:
    s0 = _hovering(CALM)
    gas = hover_gas_counts(s0, CALM) / math.cos(0.1)
    s = _fly(s0, replace(sticks, gas_counts=gas), 1.0, CALM)
    assert sign * s.vel_w_mps[axis] > 0.3
    angle = s.pitch_rad if axis == 0 else s.roll_rad
    expected = -(sticks.nick_counts + sticks.roll_counts) / CALM.counts_per_rad  # ±0.1 rad
    assert angle == pytest.approx(expected, abs=0.01)


def test_positive_yaw_command_turns_the_nose_left() -> None:
    s0 = _hovering(CALM)
    s = _fly(s0, Sticks(yaw_counts=20, gas_counts=hover_gas_counts(s0, CALM)), 1.0, CALM)
    assert s.yaw_rate_radps == pytest.approx(-20 * CALM.yaw_rate_radps_per_count, rel=0.01)
    assert s.yaw_rad < -0.1


def test_attitude_response_is_delay_plus_first_order_lag() -> None:
    s0 = _hovering(CALM)
    target = 12 / CALM.counts_per_rad  # + nick 12 -> pitch -0.1 rad
    sticks = Sticks(nick_counts=12, gas_counts=hover_gas_counts(s0, CALM))
    rng = np.random.default_rng(0)
    pitch = {}
    s = s0
    for k in range(1, 9):
        s = step(s, sticks, 0.05, CALM, rng)
        pitch[k * 50] = -s.pitch_rad / target
    assert pitch[100] == pytest.approx(0.0, abs=1e-9)  # pure delay: nothing for 0.1 s
    assert pitch[200] == pytest.approx(1 - math.exp(-1), abs=0.01)  # 63 % after ~0.2 s
    assert pitch[400] == pytest.approx(1 - math.exp(-3), abs=0.01)


def test_ground_contact() -> None:
    s0 = initial_state(CALM, np.random.default_rng(0))
    assert s0.on_ground
    assert s0.pos_w_m == (0.0, 0.0, 0.0)  # z = 0: resting with the motors off
    idle = _fly(s0, Sticks(nick_counts=50, yaw_counts=30, gas_counts=60), 2.0, CALM)
    assert idle.on_ground
    assert idle.pos_w_m[:2] == (0.0, 0.0)  # the sticks neither tilt, turn nor slide it
    assert (idle.pitch_rad, idle.roll_rad, idle.yaw_rad) == (0.0, 0.0, 0.0)
    # gas 60 carries ~58 % of the weight: the gear's compression is ~42 % of the sag
    share = idle.thrust_n / WEIGHT_N
    assert idle.height_m == pytest.approx(share * CALM.gear_sag_m, abs=1e-4)
    assert idle.vel_w_mps == pytest.approx((0.0, 0.0, 0.0), abs=1e-4)  # the gear creeps
    assert imu_truth_si(idle, CALM)[3:] == pytest.approx((0.0, 0.0, -CALM.g_mps2), abs=1e-3)
    assert idle.touchdowns == ()
    up = _fly(idle, Sticks(gas_counts=130), 1.0, CALM)
    assert not up.on_ground
    assert up.height_m > 0.2
    assert up.touchdowns == ()  # a take-off is not a touchdown
    down = _fly(up, Sticks(gas_counts=0), 4.0, CALM)
    assert down.on_ground
    assert down.height_m == pytest.approx(0.0, abs=1e-3)
    assert down.vel_w_mps == pytest.approx((0.0, 0.0, 0.0), abs=1e-3)
    ((t_touch, speed),) = down.touchdowns  # a hard one: the motors were cut in the air
    assert up.t_s < t_touch < down.t_s
    assert speed > 2.0


def test_same_seed_same_flight() -> None:
    p = NOMINAL
    runs = []
    for _ in range(2):
        rng = np.random.default_rng(42)
        s = initial_state(p, rng, pos_w_m=(0.0, 0.0, -0.6))
        for k in range(100):
            s = step(s, Sticks(nick_counts=k % 7 - 3, gas_counts=95), DT, p, rng)
        runs.append((s, imu_measured_si(s, p, rng), battery_reading_v(s, p, rng)))
    assert runs[0] == runs[1]
    other = initial_state(p, np.random.default_rng(43))
    assert other.errors != initial_state(p, np.random.default_rng(42)).errors


def test_gusts_push_a_few_cm_per_s2() -> None:
    p = NOMINAL
    s0 = replace(
        initial_state(p, np.random.default_rng(0), pos_w_m=(0.0, 0.0, -1.0), gust_seed=3),
        errors=FlightErrors(),
        thrust_n=WEIGHT_N,
    )
    gas = hover_gas_counts(s0, p)
    rng = np.random.default_rng(3)
    acc = []
    s = s0
    for _ in range(1200):
        s = step(s, Sticks(gas_counts=gas), DT, p, rng)
        acc.append(s.acc_w_mps2[0])
    assert 0.005 < float(np.std(acc)) < 0.1


@pytest.mark.parametrize("pitch", [-0.4, 0.0, 0.25])
@pytest.mark.parametrize("roll", [-0.3, 0.1])
def test_static_imu_reading_at_tilt_is_spec_formula(pitch: float, roll: float) -> None:
    g = CALM.g_mps2
    s = VehicleState(pitch_rad=pitch, roll_rad=roll, yaw_rad=1.0)
    f = imu_truth_si(s, CALM)
    assert f[:3] == (pitch, roll, 1.0)
    expected = (
        g * math.sin(pitch),
        -g * math.sin(roll) * math.cos(pitch),
        -g * math.cos(roll) * math.cos(pitch),
    )
    assert f[3:] == pytest.approx(expected, abs=1e-12)


def test_flying_specific_force_is_thrust_along_body_z_minus_drag() -> None:
    s = _fly(_hovering(CALM), Sticks(nick_counts=12, gas_counts=110), 1.0, CALM)
    f = np.array(imu_truth_si(s, CALM)[3:])
    v = np.array(s.vel_w_mps)
    drag_w = (CALM.drag_linear_per_s + CALM.drag_quadratic_per_m * np.linalg.norm(v)) * v
    rot = body_to_world(s.pitch_rad, s.roll_rad, s.yaw_rad)
    expected = np.array([0.0, 0.0, -s.thrust_n / CALM.mass_kg]) - rot.T @ drag_w
    assert np.abs(f - expected).max() < 0.005


def test_measured_imu_adds_trim_bias_and_vibration() -> None:
    p = VehicleParams.from_config(SimVehicleConfig(angle_noise_std_rad=0.0))
    s = replace(_hovering(p), errors=FlightErrors(0.01, -0.02, (0.1, 0.0, -0.1)))
    rng = np.random.default_rng(0)
    samples = np.array([imu_measured_si(s, p, rng) for _ in range(2000)])
    truth = np.array(imu_truth_si(s, p))
    assert samples[:, 0].mean() == pytest.approx(truth[0] - 0.01)
    assert samples[:, 1].mean() == pytest.approx(truth[1] + 0.02)
    mean_acc = samples[:, 3:].mean(axis=0) - truth[3:]
    assert mean_acc == pytest.approx([0.1, 0.0, -0.1], abs=0.02)
    assert 0.1 < samples[:, 3].std() < 0.3  # vibration left in the FC's averages


def test_battery_sags_with_load_and_with_use() -> None:
    p = CALM
    assert open_circuit_v(0.0, p) == pytest.approx(12.6)
    assert open_circuit_v(p.battery_capacity_ah * 0.5, p) == pytest.approx(3 * 3.84)
    s0 = _hovering(p, used_ah=0.0)
    s = _fly(s0, Sticks(gas_counts=hover_gas_counts(s0, p)), 1.0, p)
    assert s.battery_v < open_circuit_v(s.used_ah, p) - 0.3  # I R sag at ~7 A
    assert s.current_a == pytest.approx(7.3, abs=0.6)  # §L: 6.8 A + 0.5 A
    assert s.used_ah == pytest.approx(7.3 / 3600, rel=0.1)


def test_invalid_inputs_are_refused() -> None:
    s = _hovering(CALM)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"sticks\.gas_counts must be finite"):
        step(s, Sticks(gas_counts=math.nan), DT, CALM, rng)
    with pytest.raises(ValueError, match="dt_s must be finite"):
        step(s, Sticks(), 0.0, CALM, rng)


stick = st.integers(min_value=-300, max_value=300)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.tuples(stick, stick, stick, st.integers(0, 255)), min_size=1, max_size=40),
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.005, 0.02, 0.05, 0.1]),
)
def test_random_inputs_stay_finite_and_physical(
    commands: list[tuple[int, int, int, int]], seed: int, dt_s: float
) -> None:
    p = NOMINAL
    rng = np.random.default_rng(seed)
    s = initial_state(p, rng, pos_w_m=(0.0, 0.0, -1.0))
    for _ in range(5):
        for nick, roll, yaw, gas in commands:
            used = s.used_ah
            s = step(s, Sticks(nick, roll, yaw, gas), dt_s, p, rng)
            values = [*s.pos_w_m, *s.vel_w_mps, *s.acc_w_mps2, s.pitch_rad, s.roll_rad, s.yaw_rad]
            values += [*imu_truth_si(s, p), s.battery_v, s.thrust_n]
            assert all(math.isfinite(v) for v in values)
            # never far into the floor: the gear stops even a 10 m/s crash within ~0.3 m
            assert s.pos_w_m[2] <= 0.3
            assert s.on_ground == (s.pos_w_m[2] > -p.gear_sag_m)
            assert max(abs(s.pitch_rad), abs(s.roll_rad)) <= p.max_tilt_rad + 0.02
            assert math.hypot(*s.vel_w_mps) < 40.0  # drag bounds the speed
            assert s.used_ah >= used
            assert 0.0 < s.battery_v <= 12.6


@settings(max_examples=20, deadline=None)
@given(st.floats(0.2, 3.0), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
def test_without_thrust_or_wind_energy_never_grows(
    h: float, vx: float, vy: float, vz: float
) -> None:
    s = replace(_hovering(CALM, height_m=h), vel_w_mps=(vx, vy, vz), thrust_n=0.0)
    rng = np.random.default_rng(0)

    w2 = CALM.g_mps2 / CALM.gear_sag_m  # the gear's spring per unit mass

    def energy(v: VehicleState) -> float:
        compression = max(v.pos_w_m[2] + CALM.gear_sag_m, 0.0)
        spring = 0.5 * w2 * compression * compression
        return 0.5 * sum(c * c for c in v.vel_w_mps) + CALM.g_mps2 * v.height_m + spring

    e = energy(s)
    for _ in range(40):
        s = step(s, Sticks(gas_counts=0), 0.02, CALM, rng)
        assert energy(s) <= e + 1e-3
        e = energy(s)


def test_ground_effect_adds_thrust_near_the_floor_only() -> None:
    p = replace(CALM, ground_effect=0.15, drag_linear_per_s=0.0, drag_quadratic_per_m=0.0)
    r = p.ground_effect_height_m
    assert ground_effect_factor(0.0, p) == pytest.approx(1.15)
    assert ground_effect_factor(-0.003, p) == pytest.approx(1.15)  # the gear compressed
    assert ground_effect_factor(r, p) == pytest.approx(1.0 + 0.15 / 4)
    assert (ground_effect_factor(0.6, p) - 1.0) / 0.15 == pytest.approx(0.0204, abs=1e-3)
    for height in (0.05, 0.2, 0.6, 2.0):
        s = replace(_hovering(p, height_m=height), thrust_n=WEIGHT_N)
        s = step(s, Sticks(gas_counts=hover_gas_counts(s, p)), 1e-4, p, np.random.default_rng(0))
        up_mps2 = -s.acc_w_mps2[2]  # the weight is held: what is left is the ground effect
        assert up_mps2 == pytest.approx(
            p.g_mps2 * (ground_effect_factor(height, p) - 1.0), abs=2e-3
        )
    # on the floor the same gas lifts it sooner: the hover gas out of ground effect would not
    on_floor = initial_state(p, np.random.default_rng(0))
    gas = 0.9 * hover_gas_counts(on_floor, p)
    assert not _fly(on_floor, Sticks(gas_counts=gas), 2.0, p).on_ground  # 0.9 * 1.15 > 1
    assert _fly(on_floor, Sticks(gas_counts=gas), 2.0, CALM).on_ground


def test_yaw_drifts_at_a_neutral_stick_and_not_on_the_floor() -> None:
    p = replace(CALM, yaw_drift_radps=0.015)
    s0 = _hovering(p)
    s = _fly(s0, Sticks(gas_counts=hover_gas_counts(s0, p)), 3.0, p)
    assert s.yaw_rate_radps == pytest.approx(0.015, rel=1e-3)
    assert s.yaw_rad == pytest.approx(0.015 * (3.0 - p.attitude_tau_s), rel=0.02)
    turning = _fly(s0, Sticks(yaw_counts=10, gas_counts=hover_gas_counts(s0, p)), 3.0, p)
    assert turning.yaw_rate_radps == pytest.approx(-10 * p.yaw_rate_radps_per_count + 0.015)
    landed = _fly(initial_state(p, np.random.default_rng(0)), Sticks(gas_counts=50), 3.0, p)
    assert (landed.yaw_rad, landed.yaw_rate_radps) == (0.0, 0.0)


def test_fixed_trims_and_biases_add_to_the_per_flight_draws() -> None:
    fixed = replace(
        NOMINAL,
        trim_rad=(0.01, -0.02),
        acc_bias_mps2=(0.1, 0.0, -0.2),
        pitch_trim_std_rad=0.0,
        acc_bias_std_mps2=0.0,
    )
    e = initial_state(fixed, np.random.default_rng(5)).errors
    assert e == FlightErrors(0.01, -0.02, (0.1, 0.0, -0.2))
    drawn = replace(fixed, pitch_trim_std_rad=0.005, acc_bias_std_mps2=0.05)
    errors = [initial_state(drawn, np.random.default_rng(k)).errors for k in range(400)]
    trims = np.array([(x.pitch_trim_rad, x.roll_trim_rad) for x in errors])
    biases = np.array([x.acc_bias_mps2 for x in errors])
    assert trims.mean(axis=0) == pytest.approx([0.01, -0.02], abs=0.001)
    assert trims.std(axis=0) == pytest.approx([0.005, 0.005], rel=0.15)
    assert biases.mean(axis=0) == pytest.approx([0.1, 0.0, -0.2], abs=0.01)
    assert biases.std(axis=0) == pytest.approx([0.05] * 3, rel=0.15)
    # the vehicle flies command + trim, the FC reports true - trim: level reads level
    s = _fly(replace(_hovering(fixed), errors=e), Sticks(gas_counts=104), 1.0, fixed)
    assert (s.pitch_rad, s.roll_rad) == pytest.approx((0.01, -0.02), abs=1e-4)
    m = imu_measured_si(
        s, replace(fixed, angle_noise_std_rad=0.0, vibration_std_mps2=0.0), np.random.default_rng(0)
    )
    assert (m.pitch_rad, m.roll_rad) == pytest.approx((0.0, 0.0), abs=1e-4)


def test_initial_charge_defaults_to_the_airframes() -> None:
    p = replace(CALM, battery_used_ah=1.0)
    assert initial_state(p, np.random.default_rng(0)).used_ah == 1.0
    assert initial_state(p, np.random.default_rng(0), used_ah=0.5).used_ah == 0.5
    s = initial_state(p, np.random.default_rng(0))
    assert s.battery_v == pytest.approx(open_circuit_v(1.0, p) - 0.5 * p.battery_resistance_ohm)


@pytest.mark.parametrize("ratio", [0.3, 0.8, 1.0])
def test_vibration_on_z_is_its_ratio_of_x_and_y(ratio: float) -> None:
    p = VehicleParams.from_config(SimVehicleConfig(vibration_std_mps2=0.3, vibration_z_ratio=ratio))
    s = replace(_hovering(p), thrust_n=WEIGHT_N)
    rng = np.random.default_rng(1)
    samples = np.array([imu_measured_si(s, p, rng) for _ in range(4000)])
    std = samples[:, 3:].std(axis=0)
    assert std[0] == pytest.approx(0.3, rel=0.05)
    assert std[1] == pytest.approx(0.3, rel=0.05)
    assert std[2] == pytest.approx(0.3 * ratio, rel=0.05)
    half = replace(s, thrust_n=0.5 * WEIGHT_N)  # scaled by thrust / weight, all three
    std_half = np.array([imu_measured_si(half, p, rng) for _ in range(4000)])[:, 3:].std(axis=0)
    assert std_half == pytest.approx(0.5 * std, rel=0.08)


def test_the_rng_passed_to_step_changes_nothing() -> None:
    """The vehicle draws nothing per step: its gusts are a function of (gust_seed, t)."""
    p = VehicleParams.from_config(SimVehicleConfig(gust_accel_std_mps2=0.2))
    s0 = initial_state(p, np.random.default_rng(0), pos_w_m=(0.0, 0.0, -1.0), gust_seed=4)
    a = _fly(s0, Sticks(nick_counts=3, gas_counts=104), 2.0, p, seed=1)
    b = _fly(s0, Sticks(nick_counts=3, gas_counts=104), 2.0, p, seed=2)
    assert a == b
