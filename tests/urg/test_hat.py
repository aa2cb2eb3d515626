"""Height from the laser hat (eq 26): exact on clean beams, robust, or no height."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mkflight.config import LaserConfig
from mkflight.urg.hat import HatSettings, hat_height

#: The configured hat's thresholds (the defaults of the ``laser`` section).
HAT = HatSettings.from_config(LaserConfig())

N_HAT = 84  # steps 44..127
OFFSET_M = 0.05


def beams(
    height_m: float,
    pitch_rad: float = 0.0,
    roll_rad: float = 0.0,
    seed: int = 0,
    noise_m: float = 0.01,
) -> np.ndarray:
    """What the hat measures: eq 26 inverted, plus 1 cm noise."""
    rng = np.random.default_rng(seed)
    slant = (height_m + OFFSET_M) / (math.cos(pitch_rad) * math.cos(roll_rad))
    return slant + rng.normal(0.0, noise_m, N_HAT)


@pytest.mark.parametrize("height_m", [0.0, 0.3, 0.6, 1.5])
def test_level_height_within_noise(height_m: float) -> None:
    h = hat_height(beams(height_m), 0.0, 0.0, HAT)
    assert h.valid
    assert h.height_m == pytest.approx(height_m, abs=0.005)  # 1 cm noise, 84 beams
    assert h.beams_used >= 80


@pytest.mark.parametrize(("pitch", "roll"), [(0.2, 0.0), (0.0, -0.25), (-0.15, 0.2)])
def test_tilt_is_projected_eq26(pitch: float, roll: float) -> None:
    h = hat_height(beams(0.6, pitch, roll, noise_m=0.0), pitch, roll, HAT)
    assert h.valid
    assert h.height_m == pytest.approx(0.6, abs=1e-9)
    level = hat_height(beams(0.6, pitch, roll, noise_m=0.0), 0.0, 0.0, HAT)
    assert level.height_m > 0.6 + 0.005  # ignoring the tilt would overestimate


def test_invalid_beams_are_not_distances() -> None:
    r = beams(0.6)
    r[::2] = np.nan  # error codes, already NaN
    h = hat_height(r, 0.0, 0.0, HAT)
    assert h.valid
    assert h.height_m == pytest.approx(0.6, abs=0.01)
    assert h.beams_valid == N_HAT // 2


def test_too_few_valid_beams_is_no_height() -> None:
    r = np.full(N_HAT, np.nan)
    r[:5] = 0.65
    h = hat_height(r, 0.0, 0.0, HAT)
    assert not h.valid
    assert math.isnan(h.height_m)
    assert "5 of 84 hat beams valid" in h.reason


def test_outlier_beams_are_rejected() -> None:
    r = beams(0.6)
    r[:15] = 0.12  # a leg in the folded beam
    r[15:20] = 3.9  # specular returns
    h = hat_height(r, 0.0, 0.0, HAT)
    assert h.valid
    assert h.height_m == pytest.approx(0.6, abs=0.01)
    assert h.beams_used <= N_HAT - 20


def test_disagreeing_beams_give_no_height() -> None:
    r = np.concatenate([beams(0.6)[: N_HAT // 2], beams(1.2)[: N_HAT // 2]])
    h = hat_height(r, 0.0, 0.0, HAT)
    assert not h.valid
    assert "spread" in h.reason or "disagree" in h.reason


@pytest.mark.parametrize(("pitch", "roll"), [(math.nan, 0.0), (0.0, math.inf), (0.9, 0.0)])
def test_unknown_or_steep_attitude_gives_no_height(pitch: float, roll: float) -> None:
    assert not hat_height(beams(0.6), pitch, roll, HAT).valid


def test_implausible_negative_height_is_no_height() -> None:
    r = np.full(N_HAT, 0.021)  # far shorter than the hat's own standing range
    h = hat_height(r, 0.0, 0.0, HatSettings(offset_m=0.3, min_range_m=HAT.min_range_m))
    assert not h.valid
    assert "implausible" in h.reason


@given(
    hnp.arrays(
        np.float64,
        st.integers(0, 100),
        elements=st.floats(allow_nan=True, allow_infinity=True, width=64),
    ),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(allow_nan=True, allow_infinity=True),
)
def test_never_raises_and_never_a_wrong_kind_of_value(
    r: np.ndarray, pitch: float, roll: float
) -> None:
    h = hat_height(r, pitch, roll, HAT)
    if h.valid:
        assert math.isfinite(h.height_m)
        assert h.beams_used >= 8
    else:
        assert math.isnan(h.height_m)
        assert h.reason


def _reference_hat(r: np.ndarray, pitch: float, roll: float) -> tuple[float, int, int, float]:
    """The estimate written out with ``np.median``: inliers, their median, their spread."""
    good = r[(r >= HAT.min_range_m) & (r <= HAT.max_range_m)]
    median = np.median(good)
    mad = np.median(np.abs(good - median))
    inliers = good[np.abs(good - median) <= max(3.0 * 1.4826 * mad, HAT.inlier_gate_m)]
    inlier_median = float(np.median(inliers))
    spread = 1.4826 * float(np.median(np.abs(inliers - inlier_median)))
    height = math.cos(pitch) * math.cos(roll) * inlier_median - HAT.offset_m
    return height, good.size, inliers.size, spread


@given(
    st.floats(0.0, 2.0),
    st.floats(-0.3, 0.3),
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(st.integers(0, N_HAT - 1), st.floats(-0.5, 0.5)), max_size=30),
)
def test_every_figure_is_the_median_formulations_bit_for_bit(
    height_m: float, pitch: float, seed: int, outliers: list[tuple[int, float]]
) -> None:
    r = beams(height_m, pitch, -pitch / 2, seed=seed, noise_m=0.005)
    for i, shift_m in outliers:  # with none, or few, every beam is an inlier
        r[i] += shift_m
    h = hat_height(r, pitch, -pitch / 2, HAT)
    height, n_valid, n_used, spread = _reference_hat(r, pitch, -pitch / 2)
    assert (h.beams_valid, h.beams_used) == (n_valid, n_used)
    if h.valid or h.reason.startswith("hat beams spread"):
        assert h.spread_m == spread
    if h.valid:
        assert h.height_m == height
