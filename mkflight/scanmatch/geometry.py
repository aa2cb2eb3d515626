"""Planar rigid transforms, scan-to-points conversion and the reference-scan line model.

Everything is standard 2D math: x, y in metres, angles counter-clockwise from +x toward +y.
SPEC's body frame (x forward, y right, yaw clockwise) is the same math written in
``(x, y_right)`` coordinates, so a caller converts only at the sensor edge.

A pose ``(x_m, y_m, theta_rad)`` is a transform: applied to a point ``p`` it gives
``R(theta) p + (x, y)``. ``compose(a, b)`` is ``a (+) b`` (b expressed in a's frame, then in
a's parent), ``between(a, b) = a^-1 (+) b`` -- the operators of Lu & Milios and of
Kuemmerle et al.'s relation metric.

The reference model follows the idea of PL-ICP (Censi 2008, "An ICP variant using a
point-to-line metric"): the reference scan is a chain of short line pieces, and a point of
the current scan is compared with the line of its nearest reference point. Unlike CSM,
which takes the line through the two nearest raw reference points at every iteration,
each reference point here carries a line fitted once per reference scan over a window of
its scan-order neighbours (a local principal-component fit), and the fitted centroid
replaces the noisy raw point. That costs a few microseconds per keyframe (compiled),
removes most of the range noise of the reference from every residual, and leaves each
iteration only the search for the nearest line centre along the bearings.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mkflight.scanmatch.kernel_numpy import wrap_angle as wrap_angle
from mkflight.scanmatch.kernels import KernelName, load_kernel

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
IntArray64 = npt.NDArray[np.int64]
Pose = tuple[float, float, float]

IDENTITY: Pose = (0.0, 0.0, 0.0)

#: Half-widths (in beams) of the scan-order windows tried for each reference line, smallest
#: first; a point takes the smallest window whose chord reaches ``min_line_length_m``.
LINE_HALF_WINDOWS = (1, 2, 4, 8, 16)
#: Shortest chord of a line window, for the URG's dense 0.35-degree beams with 1 cm noise
#: (close, densely sampled walls get wide windows, so the noise does not tilt the normal).
MIN_LINE_LENGTH_M = 0.12
#: Largest distance between consecutive points inside a line window (a jump edge).
MAX_LINE_GAP_M = 0.5
#: Largest RMS distance of a window's points from its line, and of its centre point.
MAX_LINE_RMS_M = 0.03


def compose(a: Pose, b: Pose) -> Pose:
    """``a (+) b``: the pose ``b`` (given in the frame ``a``) expressed in ``a``'s parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2]))


def inverse(a: Pose) -> Pose:
    """``a^-1``: the parent frame's origin expressed in the frame ``a``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap_angle(-a[2]))


def between(a: Pose, b: Pose) -> Pose:
    """``a^-1 (+) b``: the pose ``b`` expressed in the frame of ``a`` (a relative motion)."""
    return compose(inverse(a), b)


def is_finite_pose(p: Pose) -> bool:
    """True when all three components are finite numbers."""
    return math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])


def transform_points(points_xy: FloatArray, pose: Pose) -> FloatArray:
    """Apply ``pose`` to an (N, 2) array of points: ``R(theta) p + t``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])  # transposed rotation for row vectors
    out: FloatArray = points_xy @ rot + np.array([pose[0], pose[1]])
    return out


def scan_to_points(
    ranges_m: npt.ArrayLike,
    angles_rad: npt.ArrayLike,
    min_range_m: float,
    max_range_m: float,
) -> FloatArray:
    """Cartesian points of the valid beams, in scan order, in the sensor frame.

    Valid means finite and ``min_range_m <= r < max_range_m`` (SPEC §2: URG values below
    20 mm are error codes, not distances). The caller chooses which beams to pass (e.g. only
    ``laser.scan_steps`` for URG data, so the laser hat and the mirror edge never enter),
    and the range window (``laser.min_range_m`` and ``max_range_m`` for URG data).

    Args:
        ranges_m: (N,) ranges in metres; NaN or out-of-range values are dropped.
        angles_rad: (N,) beam angles, counter-clockwise from +x.
        min_range_m: smallest valid range (inclusive).
        max_range_m: largest valid range (exclusive).

    Returns:
        (M, 2) float64 array, M <= N; empty (0, 2) when nothing is valid or the inputs
        do not have matching shapes.
    """
    r = np.asarray(ranges_m, dtype=np.float64).ravel()
    a = np.asarray(angles_rad, dtype=np.float64).ravel()
    if r.shape != a.shape:
        return np.empty((0, 2))
    # NaN and infinite ranges fail the comparisons (no warning for comparisons).
    ok = (r >= min_range_m) & (r < max_range_m) & np.isfinite(a)
    r, a = r[ok], a[ok]
    out = np.empty((r.shape[0], 2))
    np.multiply(r, np.cos(a), out=out[:, 0])
    np.multiply(r, np.sin(a), out=out[:, 1])
    return out


@dataclass(frozen=True, slots=True, eq=False)
class ReferenceScan:
    """A reference (keyframe) scan as fitted line pieces, built once and matched many times.

    Attributes:
        rows: (7, M) one column per line piece, sorted by bearing: the bearing of its
            centre from the sensor (rad), centre x, centre y (m, on the line), unit
            normal x, y, and the bearing's cosine and sine. Correspondences are looked up
            along the bearings
            (:mod:`mkflight.scanmatch.kernel_numpy`).
        n_points: number of valid points the scan had before line fitting.
    """

    rows: FloatArray
    n_points: int

    @property
    def n_lines(self) -> int:
        """Number of usable line pieces."""
        return int(self.rows.shape[1])

    @property
    def centers_xy(self) -> FloatArray:
        """(M, 2) centre of each line piece, in bearing order."""
        return self.rows[1:3].T

    @property
    def normals_xy(self) -> FloatArray:
        """(M, 2) unit normal of each line piece, in bearing order."""
        return self.rows[3:5].T


@functools.lru_cache(maxsize=8)
def _windows(half_windows: tuple[int, ...]) -> IntArray64:
    """The half-widths as the kernels' int64 array (one per tuple, shared, only read)."""
    return np.asarray(half_windows, dtype=np.int64)


def build_reference(
    points_xy: FloatArray,
    *,
    min_line_length_m: float = MIN_LINE_LENGTH_M,
    max_gap_m: float = MAX_LINE_GAP_M,
    max_line_rms_m: float = MAX_LINE_RMS_M,
    half_windows: tuple[int, ...] = LINE_HALF_WINDOWS,
    kernel: KernelName = "auto",
) -> ReferenceScan | None:
    """Fit a local line to every point of a scan and sort the lines by bearing.

    For each point and each candidate half-width ``w`` (smallest first) the points
    ``i-w .. i+w`` in scan order are fitted by principal components (window sums from
    cumulative sums). A window qualifies when its chord (first to last point) is at least
    ``min_line_length_m`` (waived for the widest window) -- so close, densely sampled
    walls get wide windows and the 1 cm range noise does not tilt the normal -- no gap
    between consecutive points exceeds ``max_gap_m`` (a jump edge), and both the RMS
    distance of the points from the fitted line and the centre point's own distance from
    it are at most ``max_line_rms_m`` (a corner or clutter). Points with no qualifying
    window are dropped: they would give wrong normals.

    Args:
        points_xy: (N, 2) valid points in scan order (from :func:`scan_to_points`).
        min_line_length_m: shortest chord of a fitting window.
        max_gap_m: largest distance between consecutive points inside a window.
        max_line_rms_m: largest RMS point-to-line distance of a window.
        half_windows: the window half-widths tried, increasing.
        kernel: which implementation fits (``scanmatch.kernel``; same lines either way).

    Returns:
        The reference, or None when fewer than 3 lines could be fitted.
    """
    pts = np.ascontiguousarray(points_xy, dtype=np.float64)
    n = int(pts.shape[0]) if pts.ndim == 2 and pts.shape[1:] == (2,) else 0
    if n < 5 or not math.isfinite(float(pts.sum())):  # a NaN or inf anywhere shows
        return None
    rows = load_kernel(kernel).reference_rows(
        pts, _windows(half_windows), min_line_length_m, max_gap_m, max_line_rms_m
    )
    if rows.shape[1] < 3:
        return None
    return ReferenceScan(rows=rows, n_points=n)
