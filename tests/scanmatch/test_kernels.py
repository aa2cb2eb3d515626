"""The compiled matcher and the numpy one give the same lines, correspondences and poses."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from numba import njit
from scipy.spatial import cKDTree

from mkflight.config import ScanmatchConfig
from mkflight.errors import ConfigError
from mkflight.scanmatch import (
    KeyframeMatcher,
    build_reference,
    kernel_numba,
    kernel_numpy,
    kernels,
    scan_to_points,
)
from mkflight.scanmatch.geometry import LINE_HALF_WINDOWS
from mkflight.sim.room import random_room, raycast

STEPS = np.arange(150, 726)
ANGLES = (STEPS - 384) * (2.0 * math.pi / 1024.0)
FULL_TURN = np.linspace(-math.pi, math.pi, 720, endpoint=False)
#: Poses of the two kernels agree to rounding: sums are taken in a different order
#: (BLAS vs a loop), so not bit for bit.
SAME_POSE = 1e-9
FAST = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def room_points(
    seed: int,
    pose: tuple[float, float, float],
    angles: np.ndarray,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """A noisy scan of random room ``seed`` (1 cm noise, rounded to 1 mm)."""
    rng = rng if rng is not None else np.random.default_rng(seed)
    r = raycast(random_room(seed), *pose, angles, 5.6)
    r = np.round(r + rng.normal(0.0, 0.01, r.shape), 3)
    return scan_to_points(r, angles, 0.02, 5.6)


def test_auto_picks_the_compiled_kernel_and_numpy_is_there_by_name() -> None:
    assert kernels.load_kernel("auto").name == "numba"
    assert kernels.load_kernel("numba").name == "numba"
    assert kernels.load_kernel("numpy") is kernels.NUMPY


def test_asking_for_numba_without_it_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(kernels, "_compiled", lambda: None)
    assert kernels.load_kernel("auto") is kernels.NUMPY
    with pytest.raises(ConfigError, match=r"scanmatch\.kernel"):
        kernels.load_kernel("numba")


@FAST
@given(seed=st.integers(0, 10_000), full_turn=st.booleans())
def test_reference_rows_are_the_same(seed: int, full_turn: bool) -> None:
    pts = room_points(seed, (0.2, -0.1, 0.3), FULL_TURN if full_turn else ANGLES)
    windows = np.asarray(LINE_HALF_WINDOWS, dtype=np.int64)
    a = kernel_numpy.reference_rows(pts, windows, 0.12, 0.5, 0.03)
    b = kernel_numba.reference_rows(pts, windows, 0.12, 0.5, 0.03)
    assert a.shape == b.shape
    assert a.shape[1] > 100  # lines were fitted: the comparison is not of two empties
    assert np.all(np.diff(a[0]) >= 0.0)  # sorted by bearing
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@FAST
@given(
    seed=st.integers(0, 10_000),
    gate_m=st.floats(0.05, 3.0),
    full_turn=st.booleans(),
)
def test_the_bearing_walk_finds_the_kd_trees_nearest_centre(
    seed: int, gate_m: float, full_turn: bool
) -> None:
    ref = build_reference(room_points(seed, (0.0, 0.0, 0.0), FULL_TURN if full_turn else ANGLES))
    assert ref is not None
    rng = np.random.default_rng(seed)
    queries = rng.uniform(-4.0, 4.0, (300, 2))
    tree = cKDTree(ref.rows[1:3].T)
    dist, _ = tree.query(queries, k=1, distance_upper_bound=gate_m)
    hint = np.full(queries.shape[0], -1, dtype=np.int64)
    for i, (qx, qy) in enumerate(queries):
        got = kernel_numba._nearest(ref.rows, qx, qy, gate_m, hint, i)
        if math.isinf(dist[i]):
            assert got == -1
        else:  # the same centre, or one exactly as near (a tie)
            d = math.hypot(qx - ref.rows[1, got], qy - ref.rows[2, got])
            assert d == pytest.approx(dist[i], abs=1e-12)


@pytest.mark.parametrize("seed", [1, 7, 42, 1234])
def test_both_kernels_track_the_same_poses(seed: int) -> None:
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2.0 * math.pi, 3)
    tracks = {}
    for name in ("numpy", "numba"):
        noise = np.random.default_rng(seed)
        matcher = KeyframeMatcher(ScanmatchConfig(kernel=name))
        poses = []
        for i in range(40):
            t = 0.1 * i
            pose = (
                0.3 * math.sin(0.8 * t + phase[0]),
                0.3 * math.sin(0.6 * t + phase[1]),
                0.3 * math.sin(0.5 * t + phase[2]),
            )
            update = matcher.update(room_points(seed, pose, ANGLES, noise), dt_s=0.1)
            poses.append(update.pose)
            assert update.result.valid
        tracks[name] = np.array(poses)
    np.testing.assert_allclose(tracks["numba"], tracks["numpy"], rtol=0, atol=SAME_POSE)


def test_the_warm_up_command_names_the_kernel() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "mkflight.scanmatch"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert proc.stdout.startswith("scan matcher kernel: numba (ready in ")


def test_the_flight_path_does_not_import_scipys_kd_tree() -> None:
    """scipy.spatial costs 0.8 s of start-up; the compiled kernel needs none of it."""
    code = (
        "import sys\n"
        "import mkflight.commands.fly, mkflight.flight.app\n"
        "from mkflight.config import Config\n"
        "from mkflight.flight.matcher_worker import warm_up\n"
        "warm_up(Config())\n"
        "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"


@njit(cache=False)
def compiled_hypot(dx: float, dy: float) -> float:
    return math.hypot(dx, dy)


@settings(max_examples=300, deadline=None)
@given(
    dx=st.floats(-1e3, 1e3, allow_nan=False),
    dy=st.floats(-1e3, 1e3, allow_nan=False),
    nudge=st.sampled_from([-2, -1, 0, 1, 2, None]),
    or_equal=st.booleans(),
)
@example(dx=1e-36, dy=1e-36, nudge=-2, or_equal=False)  # Python's hypot differs here
def test_length_tests_answer_as_hypot_does(
    dx: float, dy: float, nudge: int | None, or_equal: bool
) -> None:
    """The squared-length shortcut gives the compiled hypot's answer, also a few ulps from
    the tie (the compiled hypot is libm's; Python's own may differ from it by an ulp)."""
    exact = compiled_hypot(dx, dy)
    if nudge is None:
        limits = [0.5, 0.12, 1e-120, 0.0, -1.0]
    else:
        limits = [exact]
        for _ in range(abs(nudge)):
            limits.append(math.nextafter(limits[-1], math.inf if nudge > 0 else -math.inf))
    for limit in limits:
        want = exact >= limit if or_equal else exact > limit
        assert kernel_numba._hypot_above(dx, dy, limit, or_equal) == want


@pytest.mark.parametrize("order", ["sweep", "reversed", "shuffled"])
def test_reference_rows_sort_any_order_of_points(order: str) -> None:
    """In sweep order the centres come sorted (the sort is skipped); otherwise it runs."""
    pts = room_points(3, (0.1, 0.2, 0.3), FULL_TURN)
    if order == "reversed":
        pts = np.ascontiguousarray(pts[::-1])
    elif order == "shuffled":  # blocks of the scan swapped: lines fit, bearings jump
        pts = np.ascontiguousarray(np.concatenate((pts[400:], pts[:400])))
    windows = np.asarray(LINE_HALF_WINDOWS, dtype=np.int64)
    a = kernel_numpy.reference_rows(pts, windows, 0.12, 0.5, 0.03)
    b = kernel_numba.reference_rows(pts, windows, 0.12, 0.5, 0.03)
    assert a.shape == b.shape
    assert a.shape[1] > 100
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
