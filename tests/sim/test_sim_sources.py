"""DebugOut value sources of the FlightCtrl emulator (SPEC §1, §8)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from mkflight.config import SimFcConfig, SimVehicleConfig
from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import DebugOut, debug_request
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug
from mkflight.sim.fc import FcModel
from mkflight.sim.sources import FixedSource, RestingVehicleSource
from mkflight.sim.vehicle import VehicleParams

G = DEFAULT_CALIBRATION.g_mps2
# the simulated airframe's own scales (the flight decodes)
NOMINAL = VehicleParams.from_config(SimVehicleConfig())
FC = FcModel(SimFcConfig(), FixedSource({}))


def test_fixed_source_checks_indexes_and_values() -> None:
    assert FixedSource({0: -5, 31: 32767}).analog(0, FC) == {0: -5, 31: 32767}
    with pytest.raises(ValueError, match="index 32"):
        FixedSource({32: 0})
    with pytest.raises(ValueError, match="signed 16-bit"):
        FixedSource({3: 40000})


@pytest.mark.parametrize(
    ("pitch", "roll", "yaw"), [(0.0, 0.0, 0.0), (0.2, -0.1, 1.0), (-0.3, 0.25, -2.5)]
)
def test_resting_vehicle_reads_its_attitude_and_gravity(
    pitch: float, roll: float, yaw: float
) -> None:
    source = RestingVehicleSource(
        NOMINAL, seed=1, pitch_rad=pitch, roll_rad=roll, yaw_rad=yaw, noise=False
    )
    imu = imu_from_debug(DebugOut.from_values(dict(source.analog(0, FC))), 0, DEFAULT_CALIBRATION)
    assert imu.pitch_rad == pytest.approx(pitch, abs=0.001)
    assert imu.roll_rad == pytest.approx(roll, abs=0.001)
    assert imu.yaw_rad == pytest.approx(yaw, abs=0.01)
    assert imu.acc_x_mps2 == pytest.approx(G * math.sin(pitch), abs=0.02)
    assert imu.acc_y_mps2 == pytest.approx(-G * math.sin(roll) * math.cos(pitch), abs=0.02)
    assert imu.acc_z_mps2 == pytest.approx(-G * math.cos(roll) * math.cos(pitch), abs=0.07)
    assert imu.battery_v == pytest.approx(12.4)


def test_resting_vehicle_noise_is_small_and_seeded() -> None:
    def samples(seed: int) -> list[dict[int, int]]:
        source = RestingVehicleSource(NOMINAL, seed, pitch_rad=0.1)
        return [dict(source.analog(i, FC)) for i in range(50)]

    base = RestingVehicleSource(NOMINAL, 0, pitch_rad=0.1, noise=False).base_counts
    first = samples(3)
    assert first == samples(3)
    assert first != samples(4)
    for sample in first:
        assert all(abs(sample[i] - base[i]) <= 2 for i in (2, 3, 6))
        assert all(abs(sample[i] - base[i]) <= 1 for i in (0, 1))
        assert sample[9] == base[9]
    assert len({s[2] for s in first}) > 1


def test_resting_vehicle_behind_the_fc_model() -> None:
    source = RestingVehicleSource(NOMINAL, seed=7, battery_v=11.8)
    fc = FcModel(SimFcConfig(mk3mag_frames=False), source)
    fc.receive(debug_request(5), 1_000_000)
    found = FrameParser().feed(b"".join(fc.poll(30_000_000)))
    debug = DebugOut.decode(found[0])
    assert debug.analog[9] == 118  # the source's voltage wins over settings.battery_v
    assert debug.analog[7] == 4 * 200  # Gas filled by the model: the stick gas
    assert abs(debug.analog[6]) <= 2  # level: AccZ ≈ 0


def test_non_finite_attitude_is_rejected() -> None:
    with pytest.raises(ValueError, match="pitch_rad"):
        RestingVehicleSource(NOMINAL, 1, pitch_rad=math.nan)


def test_resting_vehicle_counts_are_the_airframes_scales() -> None:
    """The sim encodes with its airframe's accelerometer, whatever the flight believes."""
    other = dataclasses.replace(NOMINAL, acc_nick_counts_per_g=650.0, acc_z_counts_per_mps2=17.0)
    pitch = 0.2
    counts = RestingVehicleSource(other, seed=1, pitch_rad=pitch, noise=False).base_counts
    assert counts[2] == round(-G * math.sin(pitch) * 650.0 / G)  # AccNick
    imu = imu_from_debug(DebugOut.from_values(counts), 0, DEFAULT_CALIBRATION)
    assert imu.acc_x_mps2 == pytest.approx(G * math.sin(pitch) * 650.0 / 606.3, abs=0.02)
