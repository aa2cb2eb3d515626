"""One compiled call a scan: the same tracks, results and points as the Python path, to the bit.

The compiled ``track_step`` repeats the keyframe matcher's Python steps (prediction, match,
validity, keyframe policy, line fits, state update) with the same operations, so the two
must agree exactly, not to rounding: every field of every :class:`TrackUpdate` is compared
by ``repr`` (exact for floats, NaN included). The log tracker's cheaper points and odometry
priors are held to the formulas they replace the same way.
"""

from __future__ import annotations

import dataclasses
import gzip
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from mkflight.config import ScanmatchConfig
from mkflight.scanmatch import (
    KeyframeMatcher,
    Pose,
    between,
    compose,
    inverse,
    kernels,
    keyframe,
    parse_carmen,
    scan_to_points,
)
from mkflight.scanmatch import log_tracking as lt
from mkflight.scanmatch.carmen import LaserRecord
from mkflight.scanmatch.icp import match
from mkflight.sim.room import box_room, random_room, raycast

from .relpose import HOVER_100_CLF

STEPS = np.arange(150, 726)
ANGLES = (STEPS - 384) * (2.0 * math.pi / 1024.0)

#: One scan's input: the points and update()'s keywords.
Scan = tuple[Any, dict[str, Any]]


def points(room_seed: int, pose: Pose, rng: np.random.Generator) -> np.ndarray:
    """A noisy scan in a random room (``room_seed`` >= 0) or a corridor (-1)."""
    room = box_room(12.0, 2.4) if room_seed < 0 else random_room(room_seed)
    r = raycast(room, *pose, ANGLES, 5.6) + rng.normal(0.0, 0.01, ANGLES.shape)
    ok = r < 5.6
    return np.stack((r[ok] * np.cos(ANGLES[ok]), r[ok] * np.sin(ANGLES[ok])), axis=1)


def scans(seed: int) -> list[Scan]:
    """A walk with every kind of input: priors, no prior, odd dt, bad and odd point arrays."""
    rng = np.random.default_rng(seed)
    room = -1 if seed % 2 else seed
    out: list[Scan] = []
    for i in range(60):
        pose = (0.04 * i, 0.3 * math.sin(0.2 * i), 0.2 * math.sin(0.15 * i))
        pts = points(room, pose, rng)
        kwargs: dict[str, Any] = {"dt_s": 0.1}
        if i % 7 == 3:
            kwargs["motion_prior"] = (0.04, 0.01, -0.02)
        kwargs["dt_s"] = {10: None, 11: None, 20: math.nan, 21: 2.0, 22: 0.0}.get(i, 0.1)
        if i == 30:
            kwargs["motion_prior"] = (math.nan, 0.0, 0.0)
        if i == 31:
            kwargs["motion_prior"] = (0, 0, 0)  # ints: the compiled step takes floats
        if i == 12:
            pts = pts.copy()
            pts[5] = math.nan  # a non-finite point: the Python path matches this scan
        if i == 13:
            pts = np.asfortranarray(pts)
        if i == 14:
            pts = pts[:10]  # too few points
        if i == 15:
            pts = np.empty((0, 2))
        if i == 16:
            pts = pts.astype(np.float32)
        if i == 17:
            pts.flags.writeable = False  # numba would compile a variant for it
        if i == 40:
            pts = pts + np.array([1.5, -1.0])  # a jump: the match fails, a new keyframe
        out.append((pts, kwargs))
    return out


def track(matcher: KeyframeMatcher, walk: list[Scan]) -> list[str]:
    return [repr(matcher.update(pts, **kwargs)) for pts, kwargs in walk]


def python_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Matchers made after this take the Python path with the compiled ICP and line fits."""

    def no_step(name: kernels.KernelName) -> kernels.Kernel:
        return dataclasses.replace(kernels.load_kernel(name), track_step=None)

    monkeypatch.setattr(keyframe, "load_kernel", no_step)


def count_python_matches(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls = [0]
    real: Callable[..., Any] = match

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(keyframe, "match", counted)
    return calls


@pytest.mark.parametrize("seed", [2, 3, 8, 11])
def test_the_compiled_step_tracks_exactly_as_the_python_path(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    walk = scans(seed)
    calls = count_python_matches(monkeypatch)
    compiled = track(KeyframeMatcher(start_pose=(1.0, -2.0, 0.5)), walk)
    # The compiled step took every scan but the first (the first keyframe) and those
    # it leaves to Python: the NaN point, the Fortran-ordered, float32 and read-only arrays.
    assert calls[0] == 4
    python_only(monkeypatch)
    calls[0] = 0
    reference = track(KeyframeMatcher(start_pose=(1.0, -2.0, 0.5)), walk)
    assert calls[0] == len(walk) - 1
    assert compiled == reference
    summary = " ".join(compiled)
    for seen in ("valid=False", "degenerate=True" if seed % 2 else "valid=True"):
        assert seen in summary  # the walk reached the cases it is meant to
    assert sum("new_keyframe=True" in u for u in compiled) > 3


def test_thinning_and_the_numpy_kernel_take_the_python_path() -> None:
    assert KeyframeMatcher(ScanmatchConfig(max_points=100))._compiled is None
    assert KeyframeMatcher(ScanmatchConfig(kernel="numpy"))._compiled is None
    assert KeyframeMatcher()._compiled is not None


def test_the_pose_property_is_the_last_update() -> None:
    walk = scans(2)[:5]
    matcher = KeyframeMatcher(start_pose=(0.5, 0.25, 0.125))
    assert matcher.pose == (0.5, 0.25, 0.125)
    for pts, kwargs in walk:
        update = matcher.update(pts, **kwargs)
        assert matcher.pose == update.pose
        assert all(type(v) is float for v in matcher.pose)


def flaser_record(n: int, rng: np.random.Generator, t_s: float) -> LaserRecord:
    ranges = rng.uniform(0.5, 9.0, n)
    ranges[rng.random(n) < 0.1] = 81.83  # no return
    line = f"FLASER {n} {' '.join(f'{r:.3f}' for r in ranges)} 1 2 0.3 1 2 0.3 {t_s} h {t_s}"
    rec = parse_carmen([line]).records
    assert len(rec) == 1
    return rec[0]


def old_points(rec: LaserRecord) -> np.ndarray:
    """The points as the tracker made them before: beam_mask, then scan_to_points."""
    mask = lt.beam_mask(rec, (150, 725))
    return scan_to_points(rec.ranges_m[mask], rec.angles_rad[mask], -math.inf, math.inf)


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_beam_points_are_those_of_beam_mask_and_scan_to_points(kernel: str) -> None:
    rng = np.random.default_rng(4)
    urg = parse_carmen(gzip.decompress(HOVER_100_CLF.read_bytes()).decode().splitlines()).records
    urg = urg[:20]
    records = [*urg[:10], *(flaser_record(n, rng, 1.0) for n in (180, 180, 361)), *urg[10:]]
    odd = dataclasses.replace(urg[0], angles_rad=urg[0].angles_rad.copy())
    odd.angles_rad[3] = math.nan  # a non-finite angle: its beam is not a point
    records.append(odd)
    flipped = dataclasses.replace(urg[1], ranges_m=urg[1].ranges_m[::-1].copy()[::-1])
    records.append(flipped)  # ranges as a reversed view: the numpy formula takes it
    compiled = kernels.load_kernel("numba").beam_points if kernel == "numba" else None
    beam_points = lt._BeamPoints((150, 725), compiled)
    for rec in records:
        got, want = beam_points(rec), old_points(rec)
        assert got.shape == want.shape
        assert got.shape[0] > 100
        assert got.flags.c_contiguous
        assert got.tobytes() == want.tobytes()


def old_prior(
    odom: tuple[np.ndarray, np.ndarray], prev: int, t_s: float, mount: Pose
) -> tuple[Pose | None, int]:
    """The prior as the tracker computed it before, and the sample index for the next."""
    cur = lt._lookup(odom[0], t_s)
    if prev < 0 or cur < 0:
        return None, cur
    a, b = odom[1][prev], odom[1][cur]
    inc = between((a[0], a[1], a[2]), (b[0], b[1], b[2]))
    return compose(compose(inverse(mount), inc), mount), cur


def test_odometry_priors_are_the_lookups_and_compositions_they_replace() -> None:
    rng = np.random.default_rng(9)
    t = np.cumsum(rng.uniform(0.05, 0.15, 200))
    odom = (t, np.cumsum(rng.normal(0.0, 0.05, (200, 3)), axis=0))
    times = [*(t[5:40] + rng.uniform(-0.0012, 0.0012, 35)).tolist(), 1e6, *t[40:60].tolist()]
    times.insert(10, float(t[9]) + 0.0005)  # between two samples, both in tolerance
    mount = (0.1, -0.05, 0.2)
    priors = lt._OdomPriors(odom, times, mount)
    prev = -1
    found = 0
    for i, t_s in enumerate(times):
        want, prev = old_prior(odom, prev, t_s, mount)
        got = priors.prior(i, t_s)
        # the same numbers (the old ones were numpy scalars, the new ones are floats)
        assert repr(got) == repr(None if want is None else tuple(float(v) for v in want))
        found += got is not None
    assert 20 < found < len(times) - 2  # some within the tolerance, some not
