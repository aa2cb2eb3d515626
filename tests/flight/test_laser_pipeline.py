"""LaserPipeline: RoomScene scans with known truth -> W poses, hat heights, never a raise."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mkflight.config import Config
from mkflight.flight.laser_pipeline import (
    FLOOR_FRACTION,
    LaserPipeline,
    LaserResult,
    level_points,
    pose_from_math,
    pose_to_math,
)
from mkflight.msgs import Scan
from mkflight.scanmatch.geometry import Pose, between
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg_scene import RoomScene, ScenePose
from mkflight.urg.units import URG_04LX

CFG = Config()
STEPS = np.arange(URG_04LX.amin_step, URG_04LX.amax_step + 1)  # 44..725, as MD streams them
PERIOD_NS = 100_000_000
FRONT_OFFSET_NS = URG_04LX.step_offset_ns(URG_04LX.afront_step)  # step 0 -> step 384
HEIGHT_M = 0.6
POS_TOL_M = 0.01
YAW_TOL_RAD = 0.01


def room_scene(
    pose: ScenePose | Callable[[int], ScenePose] | None = None, seed: int = 1
) -> RoomScene:
    """A 6 x 4.5 m room with two boxes (no symmetry), URG noise and error codes."""
    room = box_room(6.0, 4.5, [(1.0, 0.8, 1.6, 1.3), (-2.0, -1.5, -1.5, -1.0)])
    return RoomScene(room_caster(room), pose=pose, seed=seed)


def take_scan(scene: RoomScene, seq: int) -> Scan:
    """One MD scan of ``scene`` as the driver stamps it: mm -> m, errors NaN, t at step 384."""
    t0_ns = seq * PERIOD_NS
    mm = scene.ranges_mm(t0_ns, STEPS)
    ok = (mm >= URG_04LX.dmin_mm) & (mm <= URG_04LX.dmax_mm)
    ranges = np.where(ok, mm / 1000.0, np.nan)
    return Scan(t_ns=t0_ns + FRONT_OFFSET_NS, ranges_m=ranges, first_step=44, seq=seq)


def scan_at(pose: ScenePose, seq: int, seed: int = 1) -> Scan:
    return take_scan(room_scene(pose, seed=seed + seq), seq)


def as_pose(p: ScenePose) -> Pose:
    return (p.x_m, p.y_m, p.yaw_rad)


def result_pose(r: LaserResult) -> Pose:
    assert r.pose is not None, r.pose_reason
    return (r.pose.x_m, r.pose.y_m, r.pose.yaw_rad)


def assert_near(
    got: Pose, want: Pose, tol_m: float = POS_TOL_M, tol_rad: float = YAW_TOL_RAD
) -> None:
    assert abs(got[0] - want[0]) < tol_m, (got, want)
    assert abs(got[1] - want[1]) < tol_m, (got, want)
    assert abs(got[2] - want[2]) < tol_rad, (got, want)


def run(poses: list[ScenePose]) -> list[LaserResult]:
    pipeline = LaserPipeline(CFG)
    return [pipeline.process(scan_at(p, i), p.pitch_rad, p.roll_rad) for i, p in enumerate(poses)]


# --- frames and signs ----------------------------------------------------------------------


def test_frame_conversion_mirrors_y_and_yaw_and_round_trips() -> None:
    assert pose_to_math((1.0, 2.0, 0.3)) == (1.0, -2.0, -0.3)
    assert pose_from_math((1.0, -2.0, -0.3)) == pytest.approx((1.0, 2.0, 0.3))
    assert pose_from_math((0.0, 0.0, math.pi)) == pytest.approx((0.0, 0.0, math.pi))  # (-pi, pi]
    assert math.copysign(1.0, pose_from_math((0.0, 0.0, 0.0))[2]) == 1.0  # never -0.0


def test_first_valid_scan_defines_the_world_frame() -> None:
    start = ScenePose(x_m=0.4, y_m=-0.3, yaw_rad=0.5, height_m=HEIGHT_M)
    first = run([start])[0]
    assert first.pose is not None
    assert (first.pose.x_m, first.pose.y_m, first.pose.yaw_rad) == (0.0, 0.0, 0.0)
    assert first.pose.t_ns == first.scan_t_ns == FRONT_OFFSET_NS
    assert first.match_valid
    assert first.new_keyframe
    assert not first.degenerate
    assert first.pose_reason == ""
    assert first.seq == 0
    assert first.n_points > 500
    assert first.compute_s > 0
    assert first.elapsed_s > 0


@pytest.mark.parametrize(
    ("move", "axis"),
    [
        (ScenePose(x_m=0.05, height_m=HEIGHT_M), 0),  # forward -> +x
        (ScenePose(y_m=0.05, height_m=HEIGHT_M), 1),  # right -> +y
        (ScenePose(yaw_rad=0.05, height_m=HEIGHT_M), 2),  # clockwise -> +yaw
    ],
)
def test_signs_forward_right_clockwise_are_positive(move: ScenePose, axis: int) -> None:
    got = result_pose(run([ScenePose(height_m=HEIGHT_M), move])[1])
    assert got[axis] > 0.04
    assert_near(got, as_pose(move))


def test_world_frame_is_the_body_frame_of_the_first_scan() -> None:
    # Start turned 0.4 rad clockwise, then fly 6 cm along the nose, 4 cm to the right of
    # it and turn 0.03 rad further clockwise: in W that is (0.06, 0.04, 0.03).
    yaw0 = 0.4
    c, s = math.cos(yaw0), math.sin(yaw0)
    start = ScenePose(x_m=0.3, y_m=-0.2, yaw_rad=yaw0, height_m=HEIGHT_M)
    moved = ScenePose(
        x_m=0.3 + c * 0.06 - s * 0.04,
        y_m=-0.2 + s * 0.06 + c * 0.04,
        yaw_rad=yaw0 + 0.03,
        height_m=HEIGHT_M,
    )
    assert_near(result_pose(run([start, moved])[1]), (0.06, 0.04, 0.03))


def test_hover_with_small_motions_tracks_truth_within_1cm() -> None:
    def hover(t_ns: int) -> ScenePose:
        t = t_ns * 1e-9
        return ScenePose(
            x_m=0.3 + 0.12 * math.sin(0.7 * t),
            y_m=-0.1 + 0.10 * math.sin(0.5 * t + 1.0),
            yaw_rad=0.2 + 0.08 * math.sin(0.4 * t),
            height_m=HEIGHT_M + 0.05 * math.sin(0.9 * t),
            pitch_rad=0.04 * math.sin(1.3 * t),
            roll_rad=-0.03 * math.sin(1.1 * t + 0.5),
        )

    scene = room_scene(hover, seed=7)  # moving during each 70 ms sweep: smeared scans
    pipeline = LaserPipeline(CFG)
    origin: Pose | None = None
    for i in range(60):
        scan = take_scan(scene, i)
        truth = hover(scan.t_ns)
        r = pipeline.process(scan, truth.pitch_rad, truth.roll_rad)
        assert r.match_valid, r.pose_reason
        assert not r.degenerate
        origin = as_pose(truth) if origin is None else origin
        assert_near(result_pose(r), between(origin, as_pose(truth)))
        assert r.height_m is not None
        assert abs(r.height_m - truth.height_m) < 0.01


def test_motion_prior_is_taken_in_spec_signs() -> None:
    # A 0.8 m / 0.6 rad jump between two scans: only the right prior finds it.
    jump = ScenePose(x_m=0.1, y_m=0.8, yaw_rad=0.6, height_m=HEIGHT_M)
    scans = [scan_at(ScenePose(height_m=HEIGHT_M), 0), scan_at(jump, 1)]

    def second(prior: Pose | None) -> LaserResult:
        pipeline = LaserPipeline(CFG)
        pipeline.process(scans[0], 0.0, 0.0)
        return pipeline.process(scans[1], 0.0, 0.0, motion_prior=prior)

    assert_near(result_pose(second((0.1, 0.8, 0.6))), as_pose(jump))
    mirrored = second((0.1, -0.8, -0.6))
    assert mirrored.pose is None or abs(mirrored.pose.y_m - 0.8) > 0.1


def test_reset_starts_a_new_world_frame() -> None:
    pipeline = LaserPipeline(CFG)
    pipeline.process(scan_at(ScenePose(height_m=HEIGHT_M), 0), 0.0, 0.0)
    moved = pipeline.process(scan_at(ScenePose(x_m=0.05, height_m=HEIGHT_M), 1), 0.0, 0.0)
    assert result_pose(moved)[0] > 0.04
    pipeline.reset()
    again = pipeline.process(scan_at(ScenePose(x_m=0.05, height_m=HEIGHT_M), 2), 0.0, 0.0)
    assert result_pose(again) == (0.0, 0.0, 0.0)
    assert again.new_keyframe


# --- tilt: beams are projected into the level frame ----------------------------------------


def test_level_points_project_tilted_beams() -> None:
    steps = np.array([384, 640], dtype=np.int64)  # ahead, and 90 degrees to the left
    ranges = np.array([2.0, 3.0])
    level = level_points(ranges, steps, 0.0, 0.0, min_range_m=0.02, max_range_m=5.6)
    assert level == pytest.approx(np.array([[2.0, 0.0], [0.0, 3.0]]), abs=1e-12)  # x fwd, y left
    tilted = level_points(ranges, steps, 0.2, 0.1, min_range_m=0.02, max_range_m=5.6)
    assert tilted[0, 0] == pytest.approx(2.0 * math.cos(0.2))  # pitch shortens the front beam
    assert tilted[1, 1] == pytest.approx(3.0 * math.cos(0.1))  # roll the side beam
    unknown = level_points(ranges, steps, math.nan, 0.1, min_range_m=0.02, max_range_m=5.6)
    assert unknown == pytest.approx(level)  # NaN attitude: taken as level


def test_level_points_drop_invalid_ranges_and_floor_hits() -> None:
    steps = np.arange(380, 390, dtype=np.int64)
    ranges = np.array([np.nan, 0.01, 6.0, -1.0, np.inf, 1.0, 1.0, 1.0, 1.0, 1.0])
    pts = level_points(ranges, steps, 0.0, 0.0, min_range_m=0.02, max_range_m=5.6)
    assert pts.shape == (5, 2)
    # Nose 0.5 rad down, 0.65 m above the floor: the front beam meets the floor at 1.36 m.
    depth_m = 0.65
    floor_r = depth_m / math.sin(0.5)
    ahead = np.array([384, 384], dtype=np.int64)
    wall_r = FLOOR_FRACTION * depth_m / math.sin(0.5) - 0.05
    kept = level_points(
        np.array([floor_r, wall_r]),
        ahead,
        -0.5,
        0.0,
        min_range_m=0.02,
        max_range_m=5.6,
        floor_depth_m=depth_m,
    )
    assert kept[:, 0] == pytest.approx([wall_r * math.cos(0.5)])


def test_a_tilted_scan_at_the_same_place_matches_in_place() -> None:
    level = ScenePose(height_m=HEIGHT_M)
    tilted = ScenePose(height_m=HEIGHT_M, pitch_rad=0.15, roll_rad=0.1)
    assert_near(result_pose(run([level, tilted])[1]), (0.0, 0.0, 0.0), 0.003, 0.003)


# --- hat height ----------------------------------------------------------------------------


def test_hat_height_at_small_tilt() -> None:
    pose = ScenePose(height_m=0.72, pitch_rad=0.06, roll_rad=-0.05)
    r = run([pose])[0]
    assert r.height_m is not None
    assert r.height_reason == ""
    assert abs(r.height_m - 0.72) < 0.01


def test_invalid_hat_beams_give_no_height_but_a_pose() -> None:
    scan = scan_at(ScenePose(height_m=HEIGHT_M), 0)
    ranges = scan.ranges_m.copy()
    ranges[(STEPS >= 0) & (CFG.laser.hat_steps[1] >= STEPS)] = (
        np.nan
    )  # every hat beam an error code
    r = LaserPipeline(CFG).process(Scan(scan.t_ns, ranges, 44, 0), 0.0, 0.0)
    assert r.height_m is None
    assert "hat beams valid" in r.height_reason
    assert r.pose is not None


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_an_unknown_attitude_is_taken_as_level(bad: float) -> None:
    """The FC sends garbage: the landing flies level on the hat alone, so level it is."""
    r = LaserPipeline(CFG).process(scan_at(ScenePose(height_m=HEIGHT_M), 0), bad, 0.0)
    assert r.height_m == pytest.approx(HEIGHT_M, abs=0.01)
    assert r.height_reason == ""
    assert r.pose is not None


def test_scan_without_hat_steps_gives_no_height() -> None:
    scan = scan_at(ScenePose(height_m=HEIGHT_M), 0)
    part = Scan(scan.t_ns, scan.ranges_m[150 - 44 :], 150, 0)  # an MD 150..725 request
    r = LaserPipeline(CFG).process(part, 0.0, 0.0)
    assert r.height_m is None
    assert "no hat steps" in r.height_reason
    assert r.pose is not None


# --- bad scans never raise -----------------------------------------------------------------


def test_no_reference_until_a_valid_scan_then_tracking() -> None:
    pipeline = LaserPipeline(CFG)
    nan = Scan(0, np.full(STEPS.size, np.nan), 44, 0)
    r = pipeline.process(nan, 0.0, 0.0)
    assert r.pose is None
    assert not r.match_valid
    assert r.pose_reason == "no reference scan yet (0 usable points)"
    assert r.height_m is None
    assert "0 of 84 hat beams valid" in r.height_reason
    first = pipeline.process(scan_at(ScenePose(height_m=HEIGHT_M), 1), 0.0, 0.0)
    assert result_pose(first) == (0.0, 0.0, 0.0)
    lost = pipeline.process(Scan(2 * PERIOD_NS, np.full(STEPS.size, np.nan), 44, 2), 0.0, 0.0)
    assert lost.pose is None
    assert lost.pose_reason.startswith("match failed: 0 points")
    back = pipeline.process(scan_at(ScenePose(y_m=0.03, height_m=HEIGHT_M), 3), 0.0, 0.0)
    assert_near(result_pose(back), (0.0, 0.03, 0.0))


@pytest.mark.parametrize(
    ("ranges", "first_step", "reason"),
    [
        (np.full(5, 1.0), 44, "no reference scan yet"),  # wrong length
        (np.empty(0), 44, "no reference scan yet"),
        (np.ones((2, 341)), 44, "bad scan: ranges have shape (2, 341)"),
        (np.array(["a", "b"]), 44, "bad scan: could not convert"),
        (np.full(682, 1.0), 10_000, "no reference scan yet"),  # no step in range
        (np.full(682, -1.0), -1000, "no reference scan yet"),
        (np.full(682, np.inf), 44, "no reference scan yet"),
        (np.full(682, 1.0), 2**70, "bad scan"),  # a step number beyond int64
    ],
)
def test_garbage_scans_give_no_pose_and_a_reason(
    ranges: npt.NDArray[np.float64], first_step: int, reason: str
) -> None:
    r = LaserPipeline(CFG).process(Scan(0, ranges, first_step, 0), 0.0, 0.0)
    assert r.pose is None
    assert reason in r.pose_reason
    assert r.height_m is None
    assert r.height_reason


def test_time_going_backwards_or_standing_still_is_survived() -> None:
    pipeline = LaserPipeline(CFG)
    scans = [scan_at(ScenePose(y_m=0.01 * i, height_m=HEIGHT_M), i) for i in range(4)]
    stamps = [500, 400, 400, 300]  # ns: backwards, then a duplicate
    for scan, t_ns in zip(scans, stamps, strict=True):
        r = pipeline.process(Scan(t_ns, scan.ranges_m, 44, scan.seq), 0.0, 0.0)
        assert_near(result_pose(r), (0.0, 0.01 * scan.seq, 0.0))


ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=60, deadline=None)
@given(
    ranges=hnp.arrays(np.float64, st.integers(0, 800), elements=ANY_FLOAT),
    first_step=st.integers(-2000, 2000),
    t_ns=st.integers(-(2**62), 2**62),
    pitch=ANY_FLOAT,
    roll=ANY_FLOAT,
    prior=st.one_of(st.none(), st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT)),
)
def test_any_scan_any_attitude_never_raises(
    ranges: npt.NDArray[np.float64],
    first_step: int,
    t_ns: int,
    pitch: float,
    roll: float,
    prior: Pose | None,
) -> None:
    pipeline = LaserPipeline(CFG)
    good = scan_at(ScenePose(height_m=HEIGHT_M), 0, seed=3)
    pipeline.process(good, 0.0, 0.0)
    for scan in (Scan(t_ns, ranges, first_step, 1), good):
        r = pipeline.process(scan, pitch, roll, prior)
        if r.pose is not None:
            assert all(math.isfinite(v) for v in result_pose(r))
        else:
            assert r.pose_reason
        assert r.height_m is None or math.isfinite(r.height_m)
        assert (r.height_m is None) == bool(r.height_reason)
