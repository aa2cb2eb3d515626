"""The pure matcher: identity, recovered motion, bad scans, degeneracy, keyframe tracking."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mkflight.config import ScanmatchConfig
from mkflight.scanmatch import (
    KeyframeMatcher,
    Pose,
    between,
    build_reference,
    compose,
    match,
    scan_to_points,
)
from mkflight.sim.room import Room, box_room, random_room, raycast

STEPS = np.arange(150, 726)
ANGLES = (STEPS - 384) * (2.0 * math.pi / 1024.0)
MAX_RANGE_M = 5.6
FAST = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def scan(room: Room, pose: Pose, rng: np.random.Generator | None = None) -> np.ndarray:
    r = raycast(room, pose[0], pose[1], pose[2], ANGLES, MAX_RANGE_M)
    if rng is not None:
        r = r + rng.normal(0.0, 0.01, r.shape)
    return scan_to_points(r, ANGLES, 0.02, MAX_RANGE_M)


def test_scan_to_points_drops_invalid_ranges() -> None:
    r = np.array([1.0, np.nan, 0.001, 5.6, 2.0, np.inf])
    a = np.zeros(6)
    pts = scan_to_points(r, a, 0.02, 5.6)
    assert pts.shape == (2, 2)
    assert np.allclose(pts[:, 0], [1.0, 2.0])


@FAST
@given(seed=st.integers(0, 10_000))
def test_scan_matched_against_itself_is_identity(seed: int) -> None:
    room = random_room(seed)
    pts = scan(room, (0.1, -0.2, 0.3), np.random.default_rng(seed))
    ref = build_reference(pts)
    assert ref is not None
    res = match(ref, pts)
    assert res.valid
    # Not exactly 0: each point is matched to the LINE fitted through its noisy (1 cm)
    # neighbours, not to itself, so a few mm of bias remain in poor geometry (seed 215:
    # 2.0 mm). The bound is the matcher's, well under the scan noise.
    assert math.hypot(res.pose[0], res.pose[1]) < 4e-3
    assert abs(res.pose[2]) < 3e-3  # seed 3462: 1.45 mrad


@FAST
@given(
    seed=st.integers(0, 10_000),
    dx=st.floats(-0.15, 0.15),
    dy=st.floats(-0.15, 0.15),
    dth=st.floats(-0.1, 0.1),
)
def test_rigid_motion_is_recovered_in_unseen_rooms(
    seed: int, dx: float, dy: float, dth: float
) -> None:
    room = random_room(seed)
    rng = np.random.default_rng(seed)
    a: Pose = (0.0, 0.0, 0.2)
    b = compose(a, (dx, dy, dth))
    ref = build_reference(scan(room, a, rng))
    assert ref is not None
    res = match(ref, scan(room, b, rng))  # no prior: the guess is the identity
    truth = between(a, b)
    assert res.valid
    err = between(truth, res.pose)
    assert math.hypot(err[0], err[1]) < 0.01
    assert abs(err[2]) < 0.005


BAD_RANGES = st.sampled_from(["nan", "zero", "inf", "tiny", "few", "empty"])


@FAST
@given(kind=BAD_RANGES, guess=st.tuples(st.floats(allow_nan=True), st.floats(), st.floats()))
def test_bad_scans_give_invalid_finite_results(kind: str, guess: Pose) -> None:
    room = box_room(6.0, 5.0)
    ref = build_reference(scan(room, (0.0, 0.0, 0.0)))
    assert ref is not None
    n = ANGLES.shape[0]
    ranges = {
        "nan": np.full(n, np.nan),
        "zero": np.zeros(n),
        "inf": np.full(n, np.inf),
        "tiny": np.full(n, 0.001),
        "few": np.where(np.arange(n) < 5, 2.0, np.nan),
        "empty": np.empty(0),
    }[kind]
    angles = ANGLES if ranges.shape[0] == n else np.empty(0)
    pts = scan_to_points(ranges, angles, 0.02, MAX_RANGE_M)
    res = match(ref, pts, guess)
    assert not res.valid
    assert all(math.isfinite(v) for v in res.pose)
    assert build_reference(pts) is None
    tracker = KeyframeMatcher()
    for _ in range(3):
        upd = tracker.update(pts, motion_prior=guess)
        assert not upd.result.valid
        assert all(math.isfinite(v) for v in upd.pose)


def test_nan_points_are_ignored_not_propagated() -> None:
    room = box_room(6.0, 5.0, [(1.0, 1.0, 1.5, 1.6)])
    pts = scan(room, (0.0, 0.0, 0.0))
    ref = build_reference(pts)
    assert ref is not None
    dirty = pts.copy()
    dirty[::7] = np.nan
    res = match(ref, dirty)
    assert res.valid
    assert all(math.isfinite(v) for v in res.pose)


def test_corridor_is_degenerate_and_keeps_the_prior_along_it() -> None:
    corridor = box_room(12.0, 2.4)  # end walls beyond 5.6 m from the middle
    a: Pose = (0.0, 0.0, 0.0)
    b: Pose = (0.05, 0.03, 0.02)
    rng = np.random.default_rng(3)
    ref = build_reference(scan(corridor, a, rng))
    assert ref is not None
    guess: Pose = (0.20, 0.0, 0.0)  # wrong along the corridor, and a bit off elsewhere
    res = match(ref, scan(corridor, b, rng), guess)
    assert res.valid
    assert res.degenerate
    assert res.min_information < ScanmatchConfig().degeneracy_threshold
    assert abs(res.pose[0] - guess[0]) < 0.02  # x stays the prediction's
    assert abs(res.pose[1] - b[1]) < 0.01  # y and theta are measured
    assert abs(res.pose[2] - b[2]) < 0.005


def test_box_room_is_not_degenerate() -> None:
    room = box_room(6.0, 5.0, [(1.4, 0.9, 2.2, 1.5)])
    rng = np.random.default_rng(4)
    ref = build_reference(scan(room, (0.0, 0.0, 0.0), rng))
    assert ref is not None
    res = match(ref, scan(room, (0.04, -0.02, 0.01), rng))
    assert res.valid
    assert not res.degenerate
    assert res.min_information > 0.05
    assert 0.0 < res.rms_m < 0.03
    assert res.matched_fraction > 0.8
    assert res.iterations >= 1


def test_keyframe_tracking_does_not_drift_at_hover() -> None:
    room = random_room(11)
    rng = np.random.default_rng(11)
    tracker = KeyframeMatcher(start_pose=(0.0, 0.0, 0.0))
    new_keyframes = 0
    for i in range(60):
        t = 0.1 * i
        truth: Pose = (0.05 * math.sin(t), 0.04 * math.sin(0.7 * t), 0.03 * math.sin(0.5 * t))
        upd = tracker.update(scan(room, truth, rng), dt_s=0.1)
        new_keyframes += upd.new_keyframe
        assert upd.result.valid
    err = between(truth, upd.pose)
    assert math.hypot(err[0], err[1]) < 0.01
    assert abs(err[2]) < 0.005
    assert new_keyframes <= 3  # the first scan, and hardly any other, at +-5 cm
