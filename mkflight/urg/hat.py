"""Height from the laser hat (SPEC §2-3, §K eq 26): robust, or no height at all.

§K and eq 26 are those of the 2011 QUT CyPhy MikroKopter documentation. A mirror folds the
steps ``laser.hat_steps`` (default 44-127) down to the floor. Each of them measures the
slant distance to the floor; the height is

    height = cos(pitch) * cos(roll) * range - hat_offset_m        (eq 26)

with ``hat_offset_m`` the range the hat reads when the vehicle stands on the floor.

Real hat beams fail in ways a plain median does not survive: error codes (already NaN
here), a leg or a cable in the folded beam, the floor's edge near a wall, specular
returns. The estimate therefore uses the median of the valid beams after rejecting
outliers by the median absolute deviation, and reports *no height* (NaN with a reason)
when too few beams are valid, when they disagree, when the attitude is unknown or too
steep, or when the result is implausible. The altitude loop can hold on "no height"; it
cannot hold on a wrong one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from mkflight.config import LaserConfig

MAD_TO_SIGMA = 1.4826  # for Gaussian noise, sigma = 1.4826 * MAD

# The outcomes of the estimate past its attitude checks, as :func:`hat_result` takes them
# (the compiled twin of :func:`hat_height`, mkflight.scanmatch.kernel_scan, hands its
# outcome over as one of these numbers; its on-disk cache holds them: change them, and
# touch kernel_scan.py).
HAT_VALID: Final = 0
TILT_TOO_LARGE: Final = "tilt too large for the hat"
HAT_FEW_VALID: Final = 1
HAT_DISAGREE: Final = 2
HAT_SPREAD: Final = 3
HAT_IMPLAUSIBLE: Final = 4


@dataclass(frozen=True, slots=True)
class HatHeight:
    """The height estimate of one scan: ``height_m`` is NaN when ``valid`` is False."""

    height_m: float
    valid: bool
    beams_valid: int
    beams_used: int
    spread_m: float
    reason: str = ""


@dataclass(frozen=True, slots=True)
class HatSettings:
    """Thresholds of :func:`hat_height` (the defaults suit the URG-04LX's 84 hat steps).

    ``offset_m`` and ``min_range_m`` come from the ``laser`` section (:meth:`from_config`),
    their one home.
    """

    offset_m: float
    min_range_m: float
    max_range_m: float = 4.0
    min_beams: int = 8
    min_valid_fraction: float = 0.25
    min_inlier_fraction: float = 0.5
    inlier_gate_m: float = 0.03
    max_spread_m: float = 0.05
    max_tilt_rad: float = 0.6
    min_height_m: float = -0.10

    @classmethod
    def from_config(cls, laser: LaserConfig) -> HatSettings:
        """The thresholds for the configured hat (``laser.hat_offset_m``, ``min_range_m``)."""
        return cls(offset_m=laser.hat_offset_m, min_range_m=laser.min_range_m)


def _none(reason: str, valid: int = 0, used: int = 0, spread: float = math.nan) -> HatHeight:
    return HatHeight(math.nan, False, valid, used, spread, reason)


def hat_height(
    ranges_m: npt.NDArray[np.float64],
    pitch_rad: float,
    roll_rad: float,
    settings: HatSettings,
) -> HatHeight:
    """Height above the floor from the hat beams' ranges (NaN = invalid beam), eq 26.

    Args:
        ranges_m: the ranges of the hat steps only, in metres; NaN for error codes.
        pitch_rad: pitch at the time of the scan (SPEC §1).
        roll_rad: roll at the time of the scan.
        settings: the thresholds (``HatSettings.from_config(cfg.laser)`` for the configured hat).

    Returns:
        The height and how it was obtained, or an invalid result with the reason.
    """
    s = settings
    if not (math.isfinite(pitch_rad) and math.isfinite(roll_rad)):
        return _none("attitude unknown")
    if abs(pitch_rad) > s.max_tilt_rad or abs(roll_rad) > s.max_tilt_rad:
        return _none(TILT_TOO_LARGE)
    r = np.asarray(ranges_m, dtype=np.float64).ravel()
    low, high = s.min_range_m, s.max_range_m
    ok = (r >= low) & (r <= high)
    if not (math.isfinite(low) and math.isfinite(high)):
        ok &= np.isfinite(r)  # finite bounds already leave out NaN and inf
    good = r[ok]
    n_valid = good.size
    if n_valid < min_valid_beams(s, r.size):
        return hat_result(HAT_FEW_VALID, r.size, n_valid)
    good.sort()
    median = _median(good)
    deviation = np.abs(good - median)
    ordered = np.sort(deviation)
    mad = _median(ordered)
    gate = max(3.0 * MAD_TO_SIGMA * mad, s.inlier_gate_m)
    # every beam an inlier is the usual case: then the inliers are ``good`` itself, and
    # their median and deviations the numbers just computed (bit for bit)
    inliers = good if ordered[-1] <= gate else good[deviation <= gate]  # sorted
    n_used = inliers.size
    if n_used < max(s.min_beams, math.ceil(s.min_inlier_fraction * n_valid)):
        return hat_result(HAT_DISAGREE, r.size, n_valid, n_used)
    if inliers is good:
        inlier_median, inlier_mad = median, mad
    else:
        inlier_median = _median(inliers)
        inlier_mad = _median(np.sort(np.abs(inliers - inlier_median)))
    spread = MAD_TO_SIGMA * inlier_mad
    if spread > s.max_spread_m:
        return hat_result(HAT_SPREAD, r.size, n_valid, n_used, spread)
    height = math.cos(pitch_rad) * math.cos(roll_rad) * inlier_median - s.offset_m
    outcome = HAT_IMPLAUSIBLE if height < s.min_height_m else HAT_VALID
    return hat_result(outcome, r.size, n_valid, n_used, spread, height)


def min_valid_beams(settings: HatSettings, n_beams: int) -> int:
    """How many of ``n_beams`` hat beams must be valid for a height."""
    return max(settings.min_beams, math.ceil(settings.min_valid_fraction * n_beams))


def hat_result(
    outcome: int,
    n_beams: int,
    n_valid: int,
    n_used: int = 0,
    spread_m: float = math.nan,
    height_m: float = math.nan,
) -> HatHeight:
    """The :class:`HatHeight` of outcome ``HAT_*`` of ``n_beams`` hat beams, with its reason."""
    if outcome == HAT_VALID:
        return HatHeight(height_m, True, n_valid, n_used, spread_m)
    if outcome == HAT_FEW_VALID:
        return _none(f"{n_valid} of {n_beams} hat beams valid", n_valid)
    if outcome == HAT_DISAGREE:
        return _none(f"hat beams disagree ({n_used} of {n_valid} consistent)", n_valid, n_used)
    if outcome == HAT_SPREAD:
        return _none(f"hat beams spread {spread_m:.3f} m", n_valid, n_used, spread_m)
    return _none(f"implausible height {height_m:.3f} m", n_valid, n_used, spread_m)


def _median(ordered: npt.NDArray[np.float64]) -> float:
    """The median of sorted finite values, as ``np.median`` computes it, bit for bit.

    The middle value, or for an even count the mean of the middle two, ``(a + b) / 2``.
    ``np.median`` itself costs ~20 numpy calls of overhead: on the hat's 84 beams, many
    times the arithmetic, four times a scan.
    """
    half = ordered.size // 2
    if ordered.size % 2:
        return float(ordered[half])
    return (float(ordered[half - 1]) + float(ordered[half])) / 2
