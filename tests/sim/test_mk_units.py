"""The simulator's own MK unit conversions (``mkflight.sim.mk_units``).

Checked against the protocol's worked example and against the flight code's independent
decoder: the two copies must agree, neither may borrow from the other.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import SimVehicleConfig
from mkflight.mk.messages import (
    ANALOG_ACC_NICK,
    ANALOG_ACC_ROLL,
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_GYRO_COMPASS,
    ANALOG_VOLTAGE,
    DebugOut,
)
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug
from mkflight.sim.airframe import draw_airframe
from mkflight.sim.mk_units import INT16_MAX, INT16_MIN, decode_analog, encode_analog
from mkflight.sim.vehicle import VehicleParams
from mkflight.sim.vehicle_sensors import ImuSi

NOMINAL = VehicleParams.from_config(SimVehicleConfig())

# /work/shared/protocols/mk-serial.md §6.2, "Worked example (vector MK-08, using SPEC §1's
# conversions, g = 9.81)", transcribed: raw DebugOut counts and the SI values they mean.
MK08_RAW = {
    ANALOG_ANGLE_NICK: -12,  # -> pitch +0.020944 rad
    ANALOG_ANGLE_ROLL: 31,  # -> roll -0.054105 rad
    ANALOG_ACC_NICK: -13,  # -> f_x +0.210341 m/s²
    ANALOG_ACC_ROLL: 33,  # -> f_y +0.536474 m/s²
    ANALOG_ACC_Z: -2,  # -> f_z -9.670968 m/s²
    ANALOG_GYRO_COMPASS: 271,  # -> -89° = -1.553343 rad
    ANALOG_VOLTAGE: 118,  # -> 11.8 V
}
MK08_SI = ImuSi(
    pitch_rad=0.020944,
    roll_rad=-0.054105,
    yaw_rad=-1.553343,
    acc_x_mps2=0.210341,
    acc_y_mps2=0.536474,
    acc_z_mps2=-9.670968,
)
MK08_BATTERY_V = 11.8


def test_mk08_worked_example_decodes() -> None:
    imu, battery_v = decode_analog(MK08_RAW, NOMINAL)
    assert imu == pytest.approx(MK08_SI, abs=1e-6)
    assert battery_v == pytest.approx(MK08_BATTERY_V)


def test_mk08_worked_example_encodes() -> None:
    assert encode_analog(MK08_SI, MK08_BATTERY_V, NOMINAL) == MK08_RAW


def test_the_airframes_own_scales_are_used() -> None:
    params = draw_airframe(3).params
    assert params.acc_nick_counts_per_g != NOMINAL.acc_nick_counts_per_g
    level = ImuSi(0.0, 0.0, 0.0, 2.0, -1.0, -9.81)
    counts = encode_analog(level, 12.0, params)
    assert counts[ANALOG_ACC_NICK] == round(-2.0 * params.acc_nick_counts_per_g / 9.81)
    assert counts[ANALOG_ACC_ROLL] == round(-1.0 * params.acc_roll_counts_per_g / 9.81)
    assert counts[ANALOG_ACC_Z] == round((9.81 - 9.8) * params.acc_z_counts_per_mps2)
    offset = replace(NOMINAL, acc_z_offset_mps2=9.81)
    assert encode_analog(level, 12.0, offset)[ANALOG_ACC_Z] == 0


def test_saturates_to_int16_and_encodes_non_finite_as_zero() -> None:
    huge = ImuSi(1e6, -1e6, math.inf, -1e9, 1e9, math.nan)
    counts = encode_analog(huge, math.nan, NOMINAL)
    assert counts[ANALOG_ANGLE_NICK] == INT16_MIN
    assert counts[ANALOG_ANGLE_ROLL] == INT16_MAX
    assert counts[ANALOG_GYRO_COMPASS] == 0
    assert counts[ANALOG_ACC_NICK] == INT16_MAX
    assert counts[ANALOG_ACC_ROLL] == INT16_MAX
    assert counts[ANALOG_ACC_Z] == 0
    assert counts[ANALOG_VOLTAGE] == 0


@pytest.mark.parametrize(
    ("yaw_rad", "counts"),
    [(0.0, 0), (math.pi / 2, 90), (-math.pi / 2, 270), (math.pi, 180), (-1e-9, 0), (-0.009, 359)],
)
def test_heading_is_clockwise_degrees_0_to_359(yaw_rad: float, counts: int) -> None:
    m = ImuSi(0.0, 0.0, yaw_rad, 0.0, 0.0, -9.81)
    assert encode_analog(m, 12.0, NOMINAL)[ANALOG_GYRO_COMPASS] == counts


def test_the_simulator_never_reads_the_flight_codes_conversions() -> None:
    source = (Path(__file__).parents[2] / "mkflight/sim/mk_units.py").read_text()
    for borrowed in ("mkflight.mk.units", "MkCalibration", "cfg.mk", "MkConfig"):
        assert borrowed not in source.split('"""', 2)[2]  # the code, not its docstring


si_angle = st.floats(-1.5, 1.5)
si_acc = st.floats(-40.0, 40.0)


@given(
    si_angle, si_angle, st.floats(-math.pi, math.pi), si_acc, si_acc, si_acc, st.floats(0.0, 25.0)
)
def test_flight_decoder_reads_what_the_simulator_encodes(
    pitch: float, roll: float, yaw: float, fx: float, fy: float, fz: float, volts: float
) -> None:
    """Two independent copies of SPEC §1 (this one and ``mkflight.mk.units``) agree."""
    m = ImuSi(pitch, roll, yaw, fx, fy, fz)
    counts = encode_analog(m, volts, NOMINAL)
    flight = imu_from_debug(DebugOut.from_values(counts), 0, DEFAULT_CALIBRATION)
    ours, ours_v = decode_analog(counts, NOMINAL)
    half_angle = math.radians(0.05) + 1e-12
    assert abs(flight.pitch_rad - pitch) <= half_angle
    assert abs(flight.roll_rad - roll) <= half_angle
    assert abs(math.remainder(flight.yaw_rad - yaw, 2 * math.pi)) <= math.radians(0.5) + 1e-9
    assert abs(flight.acc_x_mps2 - fx) <= 0.5 * 9.81 / 606.3 + 1e-9
    assert abs(flight.acc_y_mps2 - fy) <= 0.5 * 9.81 / 603.44 + 1e-9
    assert abs(flight.acc_z_mps2 - fz) <= 0.5 / 15.5 + 1e-9
    assert abs(flight.battery_v - volts) <= 0.05 + 1e-9
    # and the simulator's own decoder is the same function as the flight code's
    assert ours.pitch_rad == pytest.approx(flight.pitch_rad, abs=1e-12)
    assert ours.roll_rad == pytest.approx(flight.roll_rad, abs=1e-12)
    assert ours.yaw_rad == pytest.approx(flight.yaw_rad, abs=1e-12)
    assert ours.acc_x_mps2 == pytest.approx(flight.acc_x_mps2, abs=1e-12)
    assert ours.acc_y_mps2 == pytest.approx(flight.acc_y_mps2, abs=1e-12)
    assert ours.acc_z_mps2 == pytest.approx(flight.acc_z_mps2, abs=1e-12)
    assert ours_v == pytest.approx(flight.battery_v, abs=1e-12)


@given(st.dictionaries(st.sampled_from(sorted(MK08_RAW)), st.integers(-3000, 3000)))
def test_decode_then_encode_gives_the_counts_back(raw: dict[int, int]) -> None:
    counts = {i: raw.get(i, 0) for i in MK08_RAW}
    counts[ANALOG_GYRO_COMPASS] %= 360
    counts[ANALOG_VOLTAGE] = abs(counts[ANALOG_VOLTAGE])
    imu, volts = decode_analog(counts, NOMINAL)
    assert encode_analog(imu, volts, NOMINAL) == counts
