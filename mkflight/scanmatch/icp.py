"""Point-to-line ICP of one scan against a reference scan: pure numpy + scipy KD-tree.

The metric is that of PL-ICP (Censi 2008, "An ICP variant using a point-to-line metric",
the matcher of CSM, which the 2011 QUT CyPhy MikroKopter documentation's system ran through
ROS laser_scan_matcher): the error of a point is its distance to the line of its
corresponding reference point, so the matcher converges in a few Gauss-Newton steps where
point-to-point ICP needs tens. As in CSM's defaults there is a correspondence gate
(``max_correspondence_m``), trimming of the worst residuals (``keep_fraction``) and a stop
on a small step; the tuning is the ``scanmatch`` config section
(:class:`~mkflight.config.ScanmatchConfig`). Three things differ from CSM:

* Correspondences come from one k=1 KD-tree query per point against line pieces fitted
  once per reference scan (:func:`~mkflight.scanmatch.geometry.build_reference`), and each
  iteration is one linearised least-squares solve (3x3), not CSM's exact quartic.
* Degeneracy is handled explicitly: the 3x3 information matrix ``J^T J`` (translation in
  metres, rotation scaled by the RMS lever arm so all three axes are comparable) is
  eigen-decomposed at every step. For each eigen-direction the *structural information*
  is the mean squared projection of the Jacobian rows on it, counting only rows whose
  projection exceeds ``noise_floor`` (a wall normal tilted a few degrees by range noise
  is not evidence along the wall). Directions scoring below ``degeneracy_threshold`` are
  not updated ("solution remapping", Zhang, Kaess & Singh 2016): along an unobservable
  direction -- a corridor's axis -- the pose stays at the caller's prediction instead of
  drifting on noise, and the result is flagged degenerate so the flight code can fail
  safe (SPEC §5).
* Residuals get Cauchy weights (``robust_scale_m``) in addition to the gate and the
  optional trimming.

Nothing here allocates per point in Python or does I/O; a bad input (NaN, zeros, too few
points) yields an invalid :class:`MatchResult` with a finite pose, never an exception.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from mkflight.config import ScanmatchConfig
from mkflight.scanmatch.geometry import (
    IDENTITY,
    FloatArray,
    Pose,
    ReferenceScan,
    compose,
    is_finite_pose,
)

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
_DEFAULT_CONFIG: Final = ScanmatchConfig()


@dataclass(frozen=True, slots=True)
class MatchResult:
    """The outcome of one registration.

    Attributes:
        pose: the current scan's pose in the reference scan's frame (a transform taking
            current-scan points into the reference frame). Always finite: when
            ``valid`` is False it is the initial guess (or the identity).
        valid: the registration converged to enough good correspondences.
        degenerate: at least one direction is unobservable (``min_information`` below
            the threshold); that component of ``pose`` is the guess's.
        rms_m: RMS point-to-line residual of the inliers (NaN when none).
        matched_fraction: inliers / current-scan points.
        iterations: Gauss-Newton steps taken.
        converged: the last step was below the tolerances.
        min_information: smallest structural information over the three
            eigen-directions of ``J^T J`` (0 = unobservable; see the module doc).
        n_points: points of the current scan used.
    """

    pose: Pose
    valid: bool
    degenerate: bool = False
    rms_m: float = math.nan
    matched_fraction: float = 0.0
    iterations: int = 0
    converged: bool = False
    min_information: float = 0.0
    n_points: int = 0


def invalid_result(guess: Pose, n_points: int = 0) -> MatchResult:
    """An invalid result whose pose is ``guess`` when finite, else the identity."""
    return MatchResult(
        pose=guess if is_finite_pose(guess) else IDENTITY, valid=False, n_points=n_points
    )


def _thin(points_xy: FloatArray, max_points: int) -> FloatArray:
    """Keep at most ``max_points`` points, evenly spread over the scan order."""
    n = points_xy.shape[0]
    if max_points <= 0 or n <= max_points:
        return points_xy
    idx = np.linspace(0, n - 1, max_points).astype(np.intp)
    return points_xy[idx]


def _usable_points(points_xy: FloatArray, max_points: int) -> FloatArray | None:
    """The finite points of an (N, 2) array, thinned to ``max_points``; None: not (N>0, 2)."""
    pts = np.asarray(points_xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1:] != (2,) or pts.shape[0] == 0:
        return None
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        pts = pts[finite]
    return _thin(pts, max_points)


@dataclass(frozen=True, slots=True)
class _Pairs:
    """One iteration's correspondences: each point's residual to its reference line.

    Attributes:
        r: signed point-to-line distances, m.
        nx: x components of the lines' unit normals.
        ny: y components of the lines' unit normals.
        mx: x of the points moved by the current pose (reference frame), m.
        my: y of the same, m.
    """

    r: FloatArray
    nx: FloatArray
    ny: FloatArray
    mx: FloatArray
    my: FloatArray

    @property
    def count(self) -> int:
        """Number of correspondences."""
        return int(self.r.shape[0])


class _Scan:
    """The current scan's points as contiguous columns, and a buffer for moved points."""

    def __init__(self, pts: FloatArray) -> None:
        self.px = np.ascontiguousarray(pts[:, 0])
        self.py = np.ascontiguousarray(pts[:, 1])
        self.moved = np.empty((int(pts.shape[0]), 2))

    def pairs(self, reference: ReferenceScan, pose: Pose, gate_m: float) -> _Pairs:
        """Move the points by ``pose``; pair each with the nearest line centre within the gate."""
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        qx = c * self.px - s * self.py + x
        qy = s * self.px + c * self.py + y
        self.moved[:, 0] = qx
        self.moved[:, 1] = qy
        _, idx = reference.tree.query(self.moved, k=1, distance_upper_bound=gate_m, workers=1)
        hit = idx < reference.n_lines
        j = idx[hit]
        mx = qx[hit]
        my = qy[hit]
        centers = reference.centers_xy
        nx = reference.normals_xy[j, 0]
        ny = reference.normals_xy[j, 1]
        r = nx * (mx - centers[j, 0]) + ny * (my - centers[j, 1])
        return _Pairs(r, nx, ny, mx, my)


def _trimmed(pairs: _Pairs, keep_fraction: float) -> _Pairs:
    """Keep the ``keep_fraction`` of the pairs with the smallest residuals (CSM's trimming)."""
    k = pairs.count
    keep = int(k * keep_fraction)
    if keep >= k:
        return pairs
    a = np.abs(pairs.r)
    cut = np.partition(a, keep - 1)[keep - 1]
    inl = a <= cut
    return _Pairs(pairs.r[inl], pairs.nx[inl], pairs.ny[inl], pairs.mx[inl], pairs.my[inl])


def _normal_equations(
    pairs: _Pairs, robust_scale_m: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(J, J^T W J, J^T W r)`` of the linearised residuals, W the Cauchy weights (or 1).

    Row i of ``J^T`` is the derivative of residual i w.r.t. a small ``(dx, dy, dtheta)``
    applied after the current pose, rotating about the reference origin:
    ``[nx, ny, nx * (-my) + ny * mx]``.
    """
    nx, ny, mx, my, r = pairs.nx, pairs.ny, pairs.mx, pairs.my, pairs.r
    jt = ny * mx - nx * my
    jac = np.stack((nx, ny, jt))
    if robust_scale_m > 0.0:
        wgt = 1.0 / (1.0 + (r * (1.0 / robust_scale_m)) ** 2)
        jw = jac * wgt
        return jac, jw @ jac.T, jw @ r
    return jac, jac @ jac.T, jac @ r


@dataclass(frozen=True, slots=True)
class _Step:
    """One Gauss-Newton step and the quality of the correspondences it came from."""

    dx_m: float
    dy_m: float
    dth_rad: float
    rms_m: float
    min_information: float
    n_inliers: int


def _gauss_newton_step(pairs: _Pairs, cfg: ScanmatchConfig) -> _Step:
    """Solve for the pose update in the observable eigen-directions only (module doc).

    The rotation axis is scaled by the RMS lever arm so that the three eigenvalues of the
    information matrix compare. A direction's structural information counts only the rows
    that constrain it clearly (``|projection| > noise_floor``), so a corridor's noisy wall
    normals do not make its axis look observable; directions at or below
    ``degeneracy_threshold`` keep the guess ("solution remapping").
    """
    n_in = pairs.count
    jac, h, g = _normal_equations(pairs, cfg.robust_scale_m)
    r, mx, my = pairs.r, pairs.mx, pairs.my
    rms = math.sqrt(float(r @ r) / n_in)
    lever2 = float(mx @ mx + my @ my) / n_in
    lever = math.sqrt(lever2) if lever2 > MIN_LEVER2_M2 else 1.0
    scale = np.array([1.0, 1.0, 1.0 / lever])
    hs = h * np.outer(scale, scale) / n_in
    evals, evecs = np.linalg.eigh(hs)
    proj_rows = (evecs.T * scale) @ jac
    strong = np.abs(proj_rows) > cfg.noise_floor
    sinfo = np.einsum("ij,ij->i", proj_rows * strong, proj_rows) / n_in
    gs = g * scale / n_in
    # Solve hs * u = -gs in the observable eigen-directions only, then unscale.
    proj = evecs.T @ gs
    good = (sinfo > cfg.degeneracy_threshold) & (evals > MIN_EIGENVALUE)
    u = evecs[:, good] @ (-proj[good] / evals[good])
    return _Step(
        dx_m=float(u[0]),
        dy_m=float(u[1]),
        dth_rad=float(u[2] / lever),
        rms_m=rms,
        min_information=float(sinfo.min()),
        n_inliers=n_in,
    )


@dataclass(frozen=True, slots=True)
class _Track:
    """Where the iterations ended: the pose and the last step's statistics."""

    pose: Pose
    iterations: int
    converged: bool
    rms_m: float = math.nan
    min_information: float = 0.0
    n_inliers: int = 0


def _iterate(
    reference: ReferenceScan, pts: FloatArray, guess: Pose, cfg: ScanmatchConfig
) -> _Track | None:
    """Gauss-Newton iterations from ``guess``; None when a step finds too few pairs."""
    scan = _Scan(pts)
    pose = guess
    gate_m = cfg.max_correspondence_m
    last: _Step | None = None
    iterations = 0
    converged = False
    for _ in range(cfg.max_iterations):
        iterations += 1
        pairs = scan.pairs(reference, pose, gate_m)
        if pairs.count < cfg.min_matches:
            return None
        last = _gauss_newton_step(_trimmed(pairs, cfg.keep_fraction), cfg)
        dx, dy, dth = last.dx_m, last.dy_m, last.dth_rad
        pose = compose((dx, dy, dth), pose)
        if math.hypot(dx, dy) < cfg.step_tolerance_m and abs(dth) < cfg.step_tolerance_rad:
            converged = True
            break
        if math.hypot(dx, dy) < GATE_SHRINK_BELOW_M and abs(dth) < GATE_SHRINK_BELOW_RAD:
            gate_m = max(cfg.min_correspondence_m, GATE_SHRINK * gate_m)
    if last is None:
        return _Track(pose, iterations, converged)
    return _Track(pose, iterations, converged, last.rms_m, last.min_information, last.n_inliers)


def _outcome(track: _Track, guess: Pose, n: int, cfg: ScanmatchConfig) -> MatchResult:
    """The :class:`MatchResult` of the iterations: valid when the thresholds are met."""
    frac = track.n_inliers / n
    rms = track.rms_m
    valid = (
        is_finite_pose(track.pose)
        and track.n_inliers >= cfg.min_matches
        and frac >= cfg.min_matched_fraction
        and math.isfinite(rms)
        and rms <= cfg.max_rms_m
    )
    return MatchResult(
        pose=track.pose if valid else guess,
        valid=valid,
        degenerate=valid and track.min_information < cfg.degeneracy_threshold,
        rms_m=rms,
        matched_fraction=frac,
        iterations=track.iterations,
        converged=track.converged,
        min_information=track.min_information,
        n_points=n,
    )


def match(
    reference: ReferenceScan,
    points_xy: FloatArray,
    guess: Pose = IDENTITY,
    config: ScanmatchConfig | None = None,
) -> MatchResult:
    """Register a scan against a reference by point-to-line ICP (Censi 2008's metric).

    Args:
        reference: the reference scan's line model (built once, reused for many scans).
        points_xy: (N, 2) valid points of the current scan in its own sensor frame.
        guess: initial pose of the current scan in the reference frame (the motion
            prediction); non-finite guesses are replaced by the identity.
        config: the ``scanmatch`` config section; its defaults when None.

    Returns:
        The :class:`MatchResult`; never raises on bad data.
    """
    cfg = config if config is not None else _DEFAULT_CONFIG
    if not is_finite_pose(guess):
        guess = IDENTITY
    pts = _usable_points(points_xy, cfg.max_points)
    if pts is None:
        return invalid_result(guess)
    n = int(pts.shape[0])
    if n < cfg.min_matches or reference.n_lines < 3:
        return invalid_result(guess, n)
    track = _iterate(reference, pts, guess, cfg)
    if track is None:
        return invalid_result(guess, n)
    return _outcome(track, guess, n, cfg)
