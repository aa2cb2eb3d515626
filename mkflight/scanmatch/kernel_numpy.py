"""The matcher's two inner loops in plain numpy: line fits of a reference, ICP iterations.

This is the reference implementation; :mod:`mkflight.scanmatch.kernel_numba` compiles the
same arithmetic, step for step, and a test holds the two to the same poses. Both take and
return plain float64 arrays so that either can serve :mod:`mkflight.scanmatch.icp` and
:mod:`mkflight.scanmatch.geometry` unchanged.

**Line fits** (:func:`fit_lines`): for each point and each candidate half-width ``w``
(smallest first) the points ``i-w .. i+w`` in scan order are fitted by principal
components, from cumulative sums (no loop over points). See
:func:`~mkflight.scanmatch.geometry.build_reference` for the rules a window must meet.

**ICP** (:func:`icp_solve`): Gauss-Newton on the point-to-line residuals of PL-ICP (Censi
2008). A moved point's correspondence is the nearest reference line centre within the
gate: here by a KD-tree query (scipy), in the compiled kernel by a walk along the
reference's sorted bearings that stops once no closer centre can follow (the search of
CSM's "tricks"); both find the same, exact nearest centre. Each step solves the
Cauchy-weighted normal equations in the observable eigen-directions only
(:mod:`mkflight.scanmatch.icp` explains the degeneracy test).
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: Neighbours (in the reference's bearing order) tried each side of a point's bisection
#: index: ``j - SEARCH_HALF_WIDTH .. j + SEARCH_HALF_WIDTH``.
SEARCH_HALF_WIDTH: Final = 5
#: Once a step is below both of these, the correspondence gate shrinks by
#: :data:`GATE_SHRINK` per iteration, down to ``min_correspondence_m``: late iterations
#: ignore the far outliers that the wide first gate let in.
GATE_SHRINK_BELOW_M: Final = 0.01
GATE_SHRINK_BELOW_RAD: Final = 0.01
GATE_SHRINK: Final = 0.7
#: Eigenvalues of the scaled information matrix below this are not inverted.
MIN_EIGENVALUE: Final = 1e-9
#: A mean squared lever arm below this (m^2: points at the origin) leaves rotation unscaled.
MIN_LEVER2_M2: Final = 1e-12

# Indices into the ``params`` array of icp_solve (one float64 array: a compiled kernel
# takes it without boxing a config object). The compiled kernel's cache is keyed on its own
# file only: these indices are its interface -- change them, and touch kernel_numba.py.
P_MAX_ITERATIONS: Final = 0
P_GATE_M: Final = 1
P_MIN_GATE_M: Final = 2
P_KEEP_FRACTION: Final = 3
P_ROBUST_SCALE_M: Final = 4
P_STEP_TOL_M: Final = 5
P_STEP_TOL_RAD: Final = 6
P_MIN_MATCHES: Final = 7
P_NOISE_FLOOR: Final = 8
P_DEGENERACY_THRESHOLD: Final = 9
P_SHRINK_BELOW_M: Final = 10
P_SHRINK_BELOW_RAD: Final = 11
P_SHRINK: Final = 12
P_MIN_EIGENVALUE: Final = 13
P_MIN_LEVER2_M2: Final = 14
N_PARAMS: Final = 15
#: The module's constants in the ``params`` array (P_SHRINK_BELOW_M onwards): passed at
#: every call, so that a compiled kernel's on-disk cache never holds a stale value.
CONSTANT_PARAMS: Final = (
    GATE_SHRINK_BELOW_M,
    GATE_SHRINK_BELOW_RAD,
    GATE_SHRINK,
    MIN_EIGENVALUE,
    MIN_LEVER2_M2,
)

# Indices into the result array of icp_solve.
R_X: Final = 0
R_Y: Final = 1
R_TH: Final = 2
R_ITERATIONS: Final = 3
R_CONVERGED: Final = 4
R_RMS: Final = 5
R_MIN_INFORMATION: Final = 6
R_INLIERS: Final = 7
R_FAILED: Final = 8
N_RESULTS: Final = 9

# The compiled kernel's ``track_step`` (one call per scan: the keyframe matcher's step,
# :meth:`~mkflight.scanmatch.keyframe.KeyframeMatcher.update`) reads the keyframe policy and
# the line-fit tuning from the same ``params`` array, after the ICP tuning.
P_MIN_MATCHED_FRACTION: Final = 15
P_MAX_RMS_M: Final = 16
P_KEYFRAME_DISTANCE_M: Final = 17
P_KEYFRAME_ANGLE_RAD: Final = 18
P_DEGENERATE_DISTANCE_FACTOR: Final = 19
P_MAX_PREDICTION_DT_S: Final = 20
P_MIN_CHORD_M: Final = 21
P_MAX_GAP_M: Final = 22
P_MAX_LINE_RMS_M: Final = 23
N_TRACK_PARAMS: Final = 24

# Indices into the tracker's state array (updated in place by ``track_step``): the pose,
# the keyframe's pose, the last increment and the velocity (per second; valid when
# S_HAS_VELOCITY is 1).
S_X: Final = 0
S_KF_X: Final = 3
S_INCREMENT_X: Final = 6
S_VELOCITY_X: Final = 9
S_HAS_VELOCITY: Final = 12
N_STATE: Final = 13

# Indices into ``track_step``'s output array: the world pose, then the MatchResult's fields.
T_X: Final = 0
T_MATCH_X: Final = 3
T_VALID: Final = 6
T_DEGENERATE: Final = 7
T_RMS: Final = 8
T_MATCHED_FRACTION: Final = 9
T_ITERATIONS: Final = 10
T_CONVERGED: Final = 11
T_MIN_INFORMATION: Final = 12
T_N_POINTS: Final = 13
T_NEW_KEYFRAME: Final = 14
T_HANDLED: Final = 15
N_TRACK_OUT: Final = 16

# The compiled ``kernel_scan.scan_geometry`` (a URG scan's hat height and level points in
# one call; its numpy reference is mkflight.urg.hat.hat_height and
# mkflight.flight.laser_pipeline.level_points). Indices into its ``params`` array (constant
# for a pipeline: the hat's thresholds, the range window, and the constants of those two
# modules, passed at every call for the same reason as CONSTANT_PARAMS):
G_HAT_MIN_RANGE_M: Final = 0
G_HAT_MAX_RANGE_M: Final = 1
G_HAT_MIN_BEAMS: Final = 2
G_HAT_MIN_INLIER_FRACTION: Final = 3
G_HAT_INLIER_GATE_M: Final = 4
G_HAT_MAX_SPREAD_M: Final = 5
G_HAT_MIN_HEIGHT_M: Final = 6
G_HAT_OFFSET_M: Final = 7  # the hat's eq 26 offset
G_FLOOR_OFFSET_M: Final = 8  # laser.hat_offset_m: height + it = the sensor above the floor
G_FLOOR_FRACTION: Final = 9
G_MIN_RANGE_M: Final = 10  # the scan beams' valid range window
G_MAX_RANGE_M: Final = 11
G_MAD_TO_SIGMA: Final = 12
N_GEOMETRY_PARAMS: Final = 13
# Indices into its ``hat_out`` array: the outcome (H_CODE: HAT_SKIPPED when no height was
# asked for, else one of mkflight.urg.hat's HAT_* outcomes), the valid and the used
# beams, the spread and the height.
H_CODE: Final = 0
H_VALID_BEAMS: Final = 1
H_USED_BEAMS: Final = 2
H_SPREAD_M: Final = 3
H_HEIGHT_M: Final = 4
N_HAT_OUT: Final = 5
HAT_SKIPPED: Final = -1


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


# ----- line fits ---------------------------------------------------------------------------


def _window_lines(
    sums: tuple[FloatArray, ...], x: FloatArray, y: FloatArray, w: int, chord_m: float
) -> tuple[IntArray, npt.NDArray[np.bool_], FloatArray, FloatArray, FloatArray]:
    """``(mid, ok, mx, my, phi)`` of every window of half-width ``w`` (chord < 0: none)."""
    cx, cy, cxx, cxy, cyy, cbig, max_rms_m = sums
    n = int(x.shape[0])
    m = 2 * w + 1
    lo = np.arange(0, n - 2 * w)
    hi = lo + m
    mid = lo + w
    mx = (cx[hi] - cx[lo]) / m
    my = (cy[hi] - cy[lo]) / m
    sxx = (cxx[hi] - cxx[lo]) / m - mx * mx
    sxy = (cxy[hi] - cxy[lo]) / m - mx * my
    syy = (cyy[hi] - cyy[lo]) / m - my * my
    half_tr = 0.5 * (sxx + syy)
    disc = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
    ok = ((cbig[hi - 1] - cbig[lo]) == 0) & (half_tr - disc <= max_rms_m[0] * max_rms_m[0])
    if chord_m >= 0.0:
        ok &= np.hypot(x[hi - 1] - x[lo], y[hi - 1] - y[lo]) >= chord_m
    # Direction of the largest principal axis; the normal is perpendicular to it.
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    # The window's own centre point must lie on the line too (not so at a corner).
    off = np.abs(np.cos(phi) * (y[mid] - my) - np.sin(phi) * (x[mid] - mx))
    ok &= off <= max_rms_m[0]
    return mid, ok, mx, my, phi


def fit_lines(
    x: FloatArray,
    y: FloatArray,
    half_windows: IntArray,
    min_chord_m: float,
    max_gap_m: float,
    max_rms_m: float,
) -> FloatArray:
    """A local line through every point that has one: ``(n, 5)`` rows, NaN where none.

    Row ``i`` is ``(centre x, centre y, normal x, normal y, 1)`` of the first qualifying
    window around point ``i`` (the smallest half-width in ``half_windows`` whose chord
    reaches ``min_chord_m``; the widest needs no chord), all NaN when no window qualifies.
    """
    n = int(x.shape[0])
    out = np.full((n, 5), np.nan)
    zero = np.zeros(1)
    gaps = np.hypot(np.diff(x), np.diff(y))
    sums = (
        np.concatenate((zero, np.cumsum(x))),
        np.concatenate((zero, np.cumsum(y))),
        np.concatenate((zero, np.cumsum(x * x))),
        np.concatenate((zero, np.cumsum(x * y))),
        np.concatenate((zero, np.cumsum(y * y))),
        np.concatenate((zero, np.cumsum(gaps > max_gap_m, dtype=np.float64))),
        np.array([max_rms_m]),
    )
    chosen = np.zeros(n, dtype=bool)
    last = int(half_windows[-1])
    for w_ in half_windows:
        w = int(w_)
        if 2 * w + 1 > n:
            break
        mid, ok, mx, my, phi = _window_lines(sums, x, y, w, min_chord_m if w != last else -1.0)
        ok &= ~chosen[mid]
        if ok.any():
            sel = mid[ok]
            p = phi[ok]
            out[sel, 0] = mx[ok]
            out[sel, 1] = my[ok]
            out[sel, 2] = -np.sin(p)
            out[sel, 3] = np.cos(p)
            out[sel, 4] = 1.0
            chosen[sel] = True
    return out


def reference_rows(
    pts: FloatArray,
    half_windows: IntArray,
    min_chord_m: float,
    max_gap_m: float,
    max_rms_m: float,
) -> FloatArray:
    """The (7, M) rows of a reference (:class:`~mkflight.scanmatch.geometry.ReferenceScan`).

    The lines of the (N, 2) C-contiguous points ``pts`` (:func:`fit_lines`), those that
    have one, sorted by the bearing of their centre (stable sort): bearing, centre x, y,
    normal x, y, cos and sin of the bearing.
    """
    lines = fit_lines(pts[:, 0], pts[:, 1], half_windows, min_chord_m, max_gap_m, max_rms_m)
    fitted = lines[lines[:, 4] == 1.0]
    bearing = np.arctan2(fitted[:, 1], fitted[:, 0])
    order = np.argsort(bearing, kind="stable")
    rows = np.empty((7, order.shape[0]))
    rows[0] = bearing[order]
    rows[1:5] = fitted[order, :4].T
    rows[5] = np.cos(rows[0])
    rows[6] = np.sin(rows[0])
    return rows


# ----- ICP -------------------------------------------------------------------------------


def _pairs(
    px: FloatArray,
    py: FloatArray,
    ref: FloatArray,
    tree: Any,
    pose: tuple[float, float, float],
    gate_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(r, nx, ny, mx, my)``: moved points paired with their nearest line centre in the gate."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    qx = c * px - s * py + x
    qy = s * px + c * py + y
    _, k = tree.query(np.stack((qx, qy), axis=1), k=1, distance_upper_bound=gate_m, workers=1)
    hit = k < ref.shape[1]
    k = k[hit]
    mx = qx[hit]
    my = qy[hit]
    nx = ref[3][k]
    ny = ref[4][k]
    r = nx * (mx - ref[1][k]) + ny * (my - ref[2][k])
    return r, nx, ny, mx, my


def _solve_step(
    pairs: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray], params: FloatArray
) -> tuple[float, float, float, float, float]:
    """``(dx, dy, dth, rms, min_information)`` of one step in the observable directions."""
    r, nx, ny, mx, my = pairs
    n_in = int(r.shape[0])
    jac = np.stack((nx, ny, ny * mx - nx * my))
    c = params[P_ROBUST_SCALE_M]
    jw = jac * (1.0 / (1.0 + (r * (1.0 / c)) ** 2)) if c > 0.0 else jac
    h = jw @ jac.T
    g = jw @ r
    rms = math.sqrt(float(r @ r) / n_in)
    lever2 = float(mx @ mx + my @ my) / n_in
    lever = math.sqrt(lever2) if lever2 > params[P_MIN_LEVER2_M2] else 1.0
    scale = np.array([1.0, 1.0, 1.0 / lever])
    evals, evecs = np.linalg.eigh(h * np.outer(scale, scale) / n_in)
    proj_rows = (evecs.T * scale) @ jac
    strong = np.abs(proj_rows) > params[P_NOISE_FLOOR]
    sinfo = np.einsum("ij,ij->i", proj_rows * strong, proj_rows) / n_in
    proj = evecs.T @ (g * scale / n_in)
    good = (sinfo > params[P_DEGENERACY_THRESHOLD]) & (evals > params[P_MIN_EIGENVALUE])
    u = evecs[:, good] @ (-proj[good] / evals[good])
    return float(u[0]), float(u[1]), float(u[2] / lever), rms, float(sinfo.min())


def _trim(
    arrays: tuple[FloatArray, ...], keep_fraction: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Keep the ``keep_fraction`` of the pairs with the smallest residuals (CSM's trimming)."""
    r, nx, ny, mx, my = arrays
    k = int(r.shape[0])
    keep = int(k * keep_fraction)
    if keep >= k or keep < 1:
        return r, nx, ny, mx, my
    a = np.abs(r)
    inl = a <= np.partition(a, keep - 1)[keep - 1]
    return r[inl], nx[inl], ny[inl], mx[inl], my[inl]


def icp_solve(
    pts: FloatArray, ref: FloatArray, guess: FloatArray, params: FloatArray
) -> FloatArray:
    """Gauss-Newton iterations from ``guess``; the result array (``R_*`` indices).

    Args:
        pts: (N, 2) C-contiguous points of the current scan (its own frame), m.
        ref: (7, M) reference rows (:class:`~mkflight.scanmatch.geometry.ReferenceScan`).
        guess: (3,) initial pose ``x, y, theta``.
        params: (N_PARAMS,) tuning, ``P_*`` indices.
    """
    out = np.zeros(N_RESULTS)
    out[R_RMS] = math.nan
    # The numpy path only: importing scipy costs the flight 0.8 s of start-up.
    from scipy.spatial import cKDTree

    tree = cKDTree(ref[1:3].T, balanced_tree=False, compact_nodes=False)
    pose = (float(guess[0]), float(guess[1]), float(guess[2]))
    gate_m = params[P_GATE_M]
    for _ in range(int(params[P_MAX_ITERATIONS])):
        out[R_ITERATIONS] += 1.0
        pairs = _pairs(pts[:, 0], pts[:, 1], ref, tree, pose, gate_m)
        if pairs[0].shape[0] < params[P_MIN_MATCHES]:
            out[R_FAILED] = 1.0
            return out
        inliers = _trim(pairs, params[P_KEEP_FRACTION])
        dx, dy, dth, rms, info = _solve_step(inliers, params)
        out[R_RMS], out[R_MIN_INFORMATION], out[R_INLIERS] = rms, info, inliers[0].shape[0]
        c, s = math.cos(dth), math.sin(dth)
        pose = (
            dx + c * pose[0] - s * pose[1],
            dy + s * pose[0] + c * pose[1],
            wrap_angle(dth + pose[2]),
        )
        step_m = math.hypot(dx, dy)
        if step_m < params[P_STEP_TOL_M] and abs(dth) < params[P_STEP_TOL_RAD]:
            out[R_CONVERGED] = 1.0
            break
        if step_m < params[P_SHRINK_BELOW_M] and abs(dth) < params[P_SHRINK_BELOW_RAD]:
            gate_m = max(params[P_MIN_GATE_M], params[P_SHRINK] * gate_m)
    out[R_X], out[R_Y], out[R_TH] = pose
    return out
