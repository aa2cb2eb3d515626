"""Faults in a simulated flight: the vehicle ends on the ground or in the pilot's hands.

Each fault starts 15 s into a 40 s flight (in HOLD at 0.6 m). Whatever it is, the vehicle
must never climb away (SPEC §5: max height 1.5 m) and must end landed or released.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from mkflight.config import Config
from mkflight.msgs import ImuSample
from mkflight.sim.hover import HoverFaults, HoverResult, run_hover


def fly(tmp_path: Path, faults: HoverFaults) -> HoverResult:
    return run_hover(Config(), duration_s=40.0, seed=1, log_dir=tmp_path / "f", faults=faults)


def assert_safe_end(r: HoverResult) -> None:
    assert r.max_height_m < 1.0, f"climbed to {r.max_height_m:.2f} m"
    assert r.landed or r.released
    assert r.final_height_m < 0.1 or r.released


def battery_zero(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, battery_v=0.0)


def acc_nan(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, acc_x_mps2=math.nan)


def pitch_nan(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, pitch_rad=math.nan)


@pytest.mark.parametrize(
    "faults",
    [
        HoverFaults(from_s=15.0, imu=battery_zero),
        HoverFaults(from_s=15.0, imu=acc_nan),
        HoverFaults(from_s=15.0, imu=pitch_nan),
        HoverFaults(from_s=15.0, drop_height=True),
        HoverFaults(from_s=15.0, drop_pose=True),
        HoverFaults(from_s=15.0, drop_pose=True, drop_height=True),
    ],
    ids=["battery-0", "acc-nan", "pitch-nan", "no-height", "no-pose", "no-laser"],
)
def test_a_fault_in_hold_ends_landed_or_released(tmp_path: Path, faults: HoverFaults) -> None:
    r = fly(tmp_path, faults)
    assert_safe_end(r)
    assert r.failsafes, "the failsafe must have acted"


def test_no_laser_from_the_start_never_takes_off(tmp_path: Path) -> None:
    r = fly(tmp_path, HoverFaults(from_s=0.0, drop_pose=True, drop_height=True))
    assert r.max_height_m < 0.05
