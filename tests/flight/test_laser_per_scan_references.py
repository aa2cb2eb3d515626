"""The laser's per-scan work against plain references, bit for bit.

The hat height, the level points and the attitude at a scan's time are computed with few
numpy calls (the hat's medians from one sort each, the beams' directions once per scan
layout, the nearest attitude by bisection). Each reference below is the direct formulation
(``np.median`` four times, trigonometry and masks over the whole scan, a look at every
sample): on random inputs, both give the same numbers to the last bit, since the height and
the poses are logged and a replay must reproduce them byte for byte.
"""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import numpy.typing as npt
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mkflight.config import Config, ScanmatchConfig
from mkflight.flight.laser_inbox import ATTITUDE_HISTORY, AttitudeHistory
from mkflight.flight.laser_pipeline import (
    FLOOR_FRACTION,
    FRONT_STEP,
    STEP_RAD,
    LaserPipeline,
    ScanLayout,
    geometry_params,
    level_points,
)
from mkflight.msgs import Scan
from mkflight.scanmatch.kernel_numpy import N_HAT_OUT
from mkflight.urg.hat import (
    MAD_TO_SIGMA,
    HatHeight,
    HatSettings,
    hat_height,
    hat_result,
    min_valid_beams,
)

PROPERTY = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
F64 = npt.NDArray[np.float64]


# --- the references ------------------------------------------------------------------------
def ref_hat_height(r: F64, pitch: float, roll: float, s: HatSettings) -> HatHeight:
    """eq 26 with ``np.median``, as the hat's height was first written."""
    nan = math.nan
    if not (math.isfinite(pitch) and math.isfinite(roll)):
        return HatHeight(nan, False, 0, 0, nan, "attitude unknown")
    if abs(pitch) > s.max_tilt_rad or abs(roll) > s.max_tilt_rad:
        return HatHeight(nan, False, 0, 0, nan, "tilt too large for the hat")
    good = r[np.isfinite(r) & (r >= s.min_range_m) & (r <= s.max_range_m)]
    n_valid = int(good.size)
    if n_valid < max(s.min_beams, math.ceil(s.min_valid_fraction * r.size)):
        return HatHeight(nan, False, n_valid, 0, nan, f"{n_valid} of {r.size} hat beams valid")
    median = float(np.median(good))
    mad = float(np.median(np.abs(good - median)))
    gate = max(3.0 * MAD_TO_SIGMA * mad, s.inlier_gate_m)
    inliers = good[np.abs(good - median) <= gate]
    n_used = int(inliers.size)
    if n_used < max(s.min_beams, math.ceil(s.min_inlier_fraction * n_valid)):
        why = f"hat beams disagree ({n_used} of {n_valid} consistent)"
        return HatHeight(nan, False, n_valid, n_used, nan, why)
    spread = MAD_TO_SIGMA * float(np.median(np.abs(inliers - np.median(inliers))))
    if spread > s.max_spread_m:
        return HatHeight(nan, False, n_valid, n_used, spread, f"hat beams spread {spread:.3f} m")
    height = math.cos(pitch) * math.cos(roll) * float(np.median(inliers)) - s.offset_m
    if height < s.min_height_m:
        why = f"implausible height {height:.3f} m"
        return HatHeight(nan, False, n_valid, n_used, spread, why)
    return HatHeight(height, True, n_valid, n_used, spread)


def ref_level_points(
    ranges: F64, steps: npt.NDArray[np.int64], pitch: float, roll: float, floor: float | None
) -> F64:
    """Every beam rotated, then the valid ones kept: SPEC §3 written out over the scan."""
    if not (math.isfinite(pitch) and math.isfinite(roll)):
        pitch = roll = 0.0
    b = -(steps.astype(np.float64) - FRONT_STEP) * STEP_RAD
    cb, sb = np.cos(b), np.sin(b)
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    lx = cp * cb + sp * sr * sb
    ly = cr * sb
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(ranges) & (ranges >= 0.02) & (ranges <= 5.6)
        if floor is not None and math.isfinite(floor):
            lz = -sp * cb + cp * sr * sb
            ok &= ranges * lz < FLOOR_FRACTION * floor
    r = ranges[ok]
    return np.stack((r * lx[ok], -(r * ly[ok])), axis=1)


def ref_attitude(samples: list[tuple[int, float, float]], t_ns: int) -> tuple[float, float]:
    kept = samples[-ATTITUDE_HISTORY:]
    if not kept:
        return math.nan, math.nan
    best = min(kept, key=lambda a: abs(a[0] - t_ns))  # the first of the nearest
    return best[1], best[2]


# --- the properties --------------------------------------------------------------------------
def same_floats(a: tuple[object, ...], b: tuple[object, ...]) -> bool:
    """Equal field by field, a NaN equal to a NaN, a float equal to the last bit."""
    for x, y in zip(a, b, strict=True):
        if isinstance(x, float) and isinstance(y, float):
            if not (math.isnan(x) and math.isnan(y)) and x.hex() != y.hex():
                return False
        elif x != y:
            return False
    return True


ranges_m = st.one_of(
    st.floats(0.0, 6.0),
    st.sampled_from([math.nan, math.inf, -math.inf, -1.0, 0.02, 4.0]),
    st.floats(0.6, 0.62),  # a floor: beams that agree
)
hat_beams = hnp.arrays(np.float64, st.integers(0, 100), elements=ranges_m) | hnp.arrays(
    np.float64, st.integers(8, 100), elements=st.floats(0.6, 0.62) | st.just(math.nan)
)
tilts = st.floats(-0.7, 0.7) | st.sampled_from([math.nan, math.inf, 0.0])


@PROPERTY
@given(
    hat_beams,
    tilts,
    tilts,
    st.floats(0.0, 0.3),
    st.floats(0.0, 0.1),
    st.floats(0.001, 0.2),
)
def test_hat_height_is_np_median_s_to_the_bit(
    beams: F64, pitch: float, roll: float, offset_m: float, gate_m: float, spread_m: float
) -> None:
    s = HatSettings(
        offset_m=offset_m, min_range_m=0.02, inlier_gate_m=gate_m, max_spread_m=spread_m
    )
    got, want = hat_height(beams, pitch, roll, s), ref_hat_height(beams, pitch, roll, s)
    fields = ("height_m", "valid", "beams_valid", "beams_used", "spread_m", "reason")
    assert same_floats(
        tuple(getattr(got, f) for f in fields), tuple(getattr(want, f) for f in fields)
    )


def test_hat_height_of_a_noisy_floor_is_np_median_s_to_the_bit() -> None:
    """Valid heights too, not only refusals: 1 cm noise on a 0.65 m floor, odd and even counts."""
    rng = np.random.default_rng(21)
    s = HatSettings(offset_m=0.05, min_range_m=0.02)
    valid = 0
    for n in range(60, 90):
        beams = 0.65 + rng.normal(0.0, 0.01, n)
        beams[rng.integers(0, n, 5)] = np.nan
        pitch, roll = rng.normal(0.0, 0.1, 2)
        got, want = hat_height(beams, pitch, roll, s), ref_hat_height(beams, pitch, roll, s)
        assert got.height_m.hex() == want.height_m.hex()
        assert got.spread_m.hex() == want.spread_m.hex()
        valid += got.valid
    assert valid == 30


@PROPERTY
@given(
    st.integers(44, 725),
    hnp.arrays(np.float64, st.integers(0, 700), elements=ranges_m),
    tilts,
    tilts,
    st.none() | st.floats(0.0, 3.0) | st.just(math.nan),
)
def test_level_points_are_the_whole_scan_formulas_to_the_bit(
    first: int, ranges: F64, pitch: float, roll: float, floor: float | None
) -> None:
    steps = np.arange(first, first + ranges.size, dtype=np.int64)
    want = ref_level_points(ranges, steps, pitch, roll, floor)
    got = level_points(
        ranges, steps, pitch, roll, min_range_m=0.02, max_range_m=5.6, floor_depth_m=floor
    )
    layout = ScanLayout.build(first, ranges.size, Config().laser)
    cached = level_points(
        ranges[layout.scan],
        layout.scan_steps,
        pitch,
        roll,
        min_range_m=0.02,
        max_range_m=5.6,
        floor_depth_m=floor,
        directions=layout.directions,
    )
    in_scan = (steps >= 150) & (steps <= 725)
    want_scan = ref_level_points(ranges[in_scan], steps[in_scan], pitch, roll, floor)
    assert got.shape == want.shape
    assert got.tobytes() == want.tobytes()
    assert cached.tobytes() == want_scan.tobytes()
    assert got.flags.c_contiguous
    assert cached.flags.c_contiguous


@PROPERTY
@given(st.integers(-800, 800), st.integers(0, 800))
def test_the_layout_slices_are_the_step_masks(first: int, n: int) -> None:
    laser = Config().laser
    steps = np.arange(first, first + n)
    layout = ScanLayout.build(first, n, laser)
    for part, (lo, hi) in ((layout.hat, laser.hat_steps), (layout.scan, laser.scan_steps)):
        assert steps[part].tolist() == steps[(steps >= lo) & (steps <= hi)].tolist()
    assert layout.scan_steps.tolist() == steps[layout.scan].tolist()


def test_a_bad_scan_between_good_ones_keeps_the_layout_right() -> None:
    pipeline = LaserPipeline(Config())
    ranges = np.full(682, 1.5)
    ranges[:84] = 0.65
    good = pipeline.process(Scan(t_ns=0, ranges_m=ranges, first_step=44, seq=1), 0.0, 0.0)
    shifted = pipeline.process(Scan(t_ns=10**8, ranges_m=ranges, first_step=150, seq=2), 0, 0)
    bad = pipeline.process(Scan(t_ns=2 * 10**8, ranges_m=ranges[:, None], first_step=44), 0, 0)
    again = pipeline.process(Scan(t_ns=3 * 10**8, ranges_m=ranges, first_step=44, seq=4), 0, 0)
    assert good.height_m is not None
    assert good.n_points == 576
    assert shifted.height_m is None
    assert "no hat steps" in shifted.height_reason
    assert shifted.n_points == 576  # steps 150..725 of 682 beams from 150: 576 in the scan
    assert bad.height_m is None
    assert bad.height_reason.startswith("bad scan")
    assert again.height_m == good.height_m
    assert again.n_points == good.n_points


samples_in_order = st.lists(st.integers(0, 5_000), max_size=2 * ATTITUDE_HISTORY + 10).map(sorted)
samples_any = st.lists(st.integers(0, 5_000), max_size=2 * ATTITUDE_HISTORY + 10)


@PROPERTY
@given(samples_in_order | samples_any, st.lists(st.integers(-100, 5_100), min_size=1))
def test_the_attitude_at_a_time_is_the_first_nearest_sample(
    times: list[int], queries: list[int]
) -> None:
    history = AttitudeHistory()
    samples: list[tuple[int, float, float]] = []
    # on every sample, beside it and halfway between neighbours: where ties are decided
    ordered = sorted(set(times))
    queries = queries + [t + d for t in ordered for d in (-1, 0, 1)]
    queries += [(a + b) // 2 for a, b in pairwise(ordered)]
    for k, t in enumerate(times):  # equal times carry different attitudes
        sample = (t, 0.001 * k, -0.001 * k)
        history.add(*sample)
        samples.append(sample)
        for q in queries:
            assert same_floats(history.at(q), ref_attitude(samples, q))
    if not samples:
        assert all(math.isnan(v) for q in queries for v in history.at(q))


# --- the compiled geometry against the numpy one ---------------------------------------------
def same_geometry(got: tuple[float | None, str, F64], want: tuple[float | None, str, F64]) -> None:
    """The same height (to the bit), reason and points (to the bit, in order)."""
    assert (got[0] is None) == (want[0] is None)
    if got[0] is not None and want[0] is not None:
        assert got[0].hex() == want[0].hex()
    assert got[1] == want[1]
    assert got[2].shape == want[2].shape
    assert got[2].tobytes() == want[2].tobytes()
    assert got[2].flags.c_contiguous
    assert got[2].flags.writeable  # what the compiled matcher takes without a new compile


COMPILED = LaserPipeline(Config())
hat_or_floor = st.floats(0.6, 0.62) | st.floats(0.3, 1.2) | st.sampled_from([math.nan, 0.01])


@PROPERTY
@given(
    st.sampled_from([(44, 682), (44, 700), (100, 600), (150, 576), (0, 769), (30, 90)]),
    st.data(),
    tilts,
    tilts,
)
def test_the_compiled_geometry_is_the_numpy_one_to_the_bit(
    shape: tuple[int, int], data: st.DataObject, pitch: float, roll: float
) -> None:
    first, n = shape
    hat = data.draw(hnp.arrays(np.float64, 128, elements=hat_or_floor))
    rest = data.draw(hnp.arrays(np.float64, n, elements=ranges_m))
    ranges = rest.copy()
    ranges[: min(n, 128)] = np.where(np.arange(min(n, 128)) % 7 == 0, rest[:128], hat[:n])
    if not (math.isfinite(pitch) and math.isfinite(roll)):
        pitch = roll = 0.0  # process() levels an unknown attitude before either
    layout = ScanLayout.build(first, n, Config().laser)
    assert COMPILED._geometry is not None
    same_geometry(
        COMPILED._compiled(ranges, layout, pitch, roll),
        COMPILED._geometry_numpy(ranges, layout, pitch, roll),
    )


def test_the_compiled_geometry_gives_every_hat_outcome_as_numpy_does() -> None:
    """A valid floor (with outliers or without), too few beams, spread, too tilted.

    (With the defaults, beams that disagree need fewer than ``min_beams`` within the MAD,
    and an implausible height a range below ``laser.min_range_m``: neither happens.)
    """
    rng = np.random.default_rng(5)
    layout = ScanLayout.build(44, 682, Config().laser)
    walls = rng.uniform(0.5, 4.0, 682)
    floors = {
        "valid": 0.65 + rng.normal(0.0, 0.003, 84),
        "few": np.where(np.arange(84) < 10, 0.65, np.nan),
        "two floors": np.where(np.arange(84) % 2 == 0, 0.65, 1.5),
        "spread": 0.65 + rng.normal(0.0, 0.05, 84),
        "some outliers": np.where(np.arange(84) % 9 == 0, 0.9, 0.65 + rng.normal(0, 0.003, 84)),
    }
    reasons = set()
    for floor in floors.values():
        for pitch, roll in ((0.0, 0.0), (0.1, -0.05), (0.7, 0.0)):
            ranges = walls.copy()
            ranges[:84] = floor
            got = COMPILED._compiled(ranges, layout, pitch, roll)
            same_geometry(got, COMPILED._geometry_numpy(ranges, layout, pitch, roll))
            reasons.add(" ".join(w for w in got[1].split(" ")[:3] if w.isalpha()))
    assert reasons == {"", "of", "hat beams spread", "tilt too large"}


def test_a_pipeline_on_the_numpy_kernel_has_no_compiled_geometry() -> None:
    pipeline = LaserPipeline(Config(scanmatch=ScanmatchConfig(kernel="numpy")))
    assert pipeline._geometry is None
    ranges = np.full(682, 1.5)
    ranges[:84] = 0.65
    result = pipeline.process(Scan(t_ns=0, ranges_m=ranges, first_step=44, seq=1), 0.0, 0.0)
    assert result.height_m is not None
    assert result.height_m.hex() == (0.65 - 0.05).hex()


@PROPERTY
@given(
    hat_beams,
    st.floats(-0.5, 0.5),
    st.floats(-0.5, 0.5),
    st.floats(0.0, 0.3),
    st.floats(0.0, 0.1),
    st.floats(0.001, 0.2),
    st.integers(1, 60),
    st.floats(-0.1, 0.6),
)
def test_the_compiled_hat_is_hat_height_to_the_bit(
    beams: F64,
    pitch: float,
    roll: float,
    offset_m: float,
    gate_m: float,
    spread_m: float,
    min_beams: int,
    min_height_m: float,
) -> None:
    """Every outcome, with settings that reach them all (few beams, disagreement, too low).

    (The pipeline asks for a hat height only with hat beams in the scan.)
    """
    assume(beams.size > 0)
    s = HatSettings(
        offset_m=offset_m,
        min_range_m=0.02,
        inlier_gate_m=gate_m,
        max_spread_m=spread_m,
        min_beams=min_beams,
        min_height_m=min_height_m,
    )
    geometry = COMPILED._geometry
    assert geometry is not None
    out = np.zeros(N_HAT_OUT)
    params = geometry_params(s, Config().laser)
    cp, cr = math.cos(pitch), math.cos(roll)
    no_beams = np.empty(0)
    geometry(
        beams,
        0,
        beams.size,
        min_valid_beams(s, beams.size),
        0,
        0,
        no_beams,
        no_beams,
        cp,
        math.sin(pitch),
        cr,
        math.sin(roll),
        cp * cr,
        params,
        out,
    )
    o = out.tolist()
    got = hat_result(int(o[0]), beams.size, int(o[1]), int(o[2]), o[3], o[4])
    want = hat_height(beams, pitch, roll, s)
    fields = ("height_m", "valid", "beams_valid", "beams_used", "spread_m", "reason")
    assert same_floats(
        tuple(getattr(got, f) for f in fields), tuple(getattr(want, f) for f in fields)
    )
