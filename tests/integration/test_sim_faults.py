"""Faults in a simulated flight: how it ends, judged on the truth (issue 17).

Each fault starts 15 s into a 40 s flight (in HOLD at 0.6 m). Whatever it is, the vehicle
must never climb away (SPEC §5: max height 1.5 m); where the flight lands, every touchdown
(the truth's downward speed at contact) is at most 0.5 m/s (SPEC §8), and a hand-off to
the pilot in the air is never counted as landed.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from mkflight.config import Config, load_config
from mkflight.msgs import ImuSample
from mkflight.sim.hover import END_GROUND, END_LANDED, HoverFaults, HoverResult, run_hover

MAX_TOUCHDOWN_MPS = 0.5


def fly(tmp_path: Path, faults: HoverFaults, cfg: Config | None = None) -> HoverResult:
    cfg = Config() if cfg is None else cfg
    return run_hover(cfg, duration_s=40.0, seed=1, log_dir=tmp_path / "f", faults=faults)


def assert_landed_softly(r: HoverResult) -> None:
    assert r.max_height_m < 1.0, f"climbed to {r.max_height_m:.2f} m"
    assert r.end == END_LANDED, f"ended {r.end!r}, failsafes {r.failsafes}"
    assert r.landed
    assert r.touchdowns_mps, "landed without touching down"
    assert r.touchdown_mps <= MAX_TOUCHDOWN_MPS, f"touchdowns {r.touchdowns_mps} m/s"
    assert r.final_height_m < 0.05


def battery_zero(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, battery_v=0.0)


def acc_nan(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, acc_x_mps2=math.nan)


def pitch_nan(imu: ImuSample) -> ImuSample:
    return dataclasses.replace(imu, pitch_rad=math.nan)


def huge(imu: ImuSample) -> ImuSample:
    """The fault campaign's ``huge-estimate``: finite, absurd values."""
    return dataclasses.replace(
        imu, acc_x_mps2=1e300, acc_y_mps2=-1e300, pitch_rad=1e300, roll_rad=1e300
    )


@pytest.mark.parametrize(
    "faults",
    [
        HoverFaults(from_s=15.0, imu=battery_zero),
        HoverFaults(from_s=15.0, imu=acc_nan),
        HoverFaults(from_s=15.0, imu=pitch_nan),
        HoverFaults(from_s=15.0, imu=huge),
        HoverFaults(from_s=15.0, drop_height=True),
        HoverFaults(from_s=15.0, drop_pose=True),
        HoverFaults(from_s=15.0, drop_pose=True, drop_height=True),
        HoverFaults(from_s=15.0, until_s=17.0, drop_pose=True, drop_height=True),
    ],
    ids=[
        "battery-0",
        "acc-nan",
        "pitch-nan",
        "huge",
        "no-height",
        "no-pose",
        "no-laser",
        "stall-2s",
    ],
)
def test_a_fault_in_hold_lands_softly(tmp_path: Path, faults: HoverFaults) -> None:
    r = fly(tmp_path, faults)
    assert_landed_softly(r)
    assert r.failsafes, "the failsafe must have acted"


def test_a_normal_flight_lands_softly(tmp_path: Path) -> None:
    r = fly(tmp_path, HoverFaults())
    assert_landed_softly(r)
    assert r.failsafes == []


@pytest.mark.parametrize("airframe_seed", [2, 5])
def test_a_laser_stall_on_a_random_airframe_lands_softly(
    tmp_path: Path, airframe_seed: int
) -> None:
    """The issue's case: no pose and no height in HOLD, on an airframe not tuned for."""
    cfg = load_config(None, ["sim.airframe=random", f"sim.seed={airframe_seed}"])
    r = fly(tmp_path, HoverFaults(from_s=15.0, drop_pose=True, drop_height=True), cfg)
    assert_landed_softly(r)


@pytest.mark.parametrize("airframe_seed", [None, 9])
@pytest.mark.parametrize("from_s", [4.5, 6.0])
def test_a_laser_stall_before_the_hover_gas_is_learned_lands_softly(
    tmp_path: Path, from_s: float, airframe_seed: int | None
) -> None:
    """A stall 1.5-3 s into HOLD: the thrust model has no learned hover gas yet.

    The descent then flies on the gas flown in HOLD (acceleration-corrected) and more
    slowly: these flights touch down at 0.06-0.46 m/s (the nominal airframe 0.40-0.46
    with the Kalman filter, 0.41 with the complementary one); on the configured hover gas
    and the full descent speed they touched down at 0.45-0.50 m/s (and at 0.51-0.56 in
    longer stalls and in CI's fault campaign).
    """
    sets = [] if airframe_seed is None else ["sim.airframe=random", f"sim.seed={airframe_seed}"]
    cfg = load_config(None, sets)
    r = fly(
        tmp_path, HoverFaults(from_s=from_s, until_s=9.5, drop_pose=True, drop_height=True), cfg
    )
    assert r.learned["hover_gas_counts"] is None, "the case needs an unlearned hover gas"
    assert r.learned["descents"], "the stall must have started a descent without the hat"
    assert_landed_softly(r)  # <= 0.5 m/s, from the truth


def test_no_laser_from_the_start_never_takes_off(tmp_path: Path) -> None:
    r = fly(tmp_path, HoverFaults(from_s=0.0, drop_pose=True, drop_height=True))
    assert r.max_height_m < 0.05
    assert r.end == END_GROUND
    assert not r.landed  # it never flew: not a landing
    assert r.touchdowns_mps == []
