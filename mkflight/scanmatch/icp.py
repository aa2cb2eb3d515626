"""Point-to-line ICP of one scan against a reference scan (the loops: ``scanmatch.kernel``).

The metric is that of PL-ICP (Censi 2008, "An ICP variant using a point-to-line metric",
the matcher of CSM, which the 2011 QUT CyPhy MikroKopter documentation's system ran through
ROS laser_scan_matcher): the error of a point is its distance to the line of its
corresponding reference point, so the matcher converges in a few Gauss-Newton steps where
point-to-point ICP needs tens. As in CSM's defaults there is a correspondence gate
(``max_correspondence_m``), trimming of the worst residuals (``keep_fraction``) and a stop
on a small step; the tuning is the ``scanmatch`` config section
(:class:`~mkflight.config.ScanmatchConfig`). Three things differ from CSM:

* Correspondences are found along the scan order, as CSM's "tricks" do: a moved point's
  bearing picks, by bisection, the reference's line pieces (fitted once per reference
  scan, :func:`~mkflight.scanmatch.geometry.build_reference`) seen in that direction, and
  the nearest of a few neighbours within the gate is its partner; each iteration is one
  linearised least-squares solve (3x3), not CSM's exact quartic. The iterations run in a
  compiled kernel or in numpy (:mod:`mkflight.scanmatch.kernels`), with the same poses.
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
    is_finite_pose,
)
from mkflight.scanmatch.kernel_numpy import (
    CONSTANT_PARAMS,
    N_TRACK_PARAMS,
    R_CONVERGED,
    R_FAILED,
    R_INLIERS,
    R_ITERATIONS,
    R_MIN_INFORMATION,
    R_RMS,
    R_TH,
    R_X,
    R_Y,
)
from mkflight.scanmatch.kernels import load_kernel

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
    if not math.isfinite(float(pts.sum())):  # one call; a NaN or inf anywhere shows
        pts = pts[np.isfinite(pts).all(axis=1)]
    return _thin(pts, max_points)


@dataclass(frozen=True, slots=True)
class _Track:
    """Where the iterations ended: the pose and the last step's statistics."""

    pose: Pose
    iterations: int
    converged: bool
    rms_m: float = math.nan
    min_information: float = 0.0
    n_inliers: int = 0


#: The last config's params array, by identity: hashing a config costs more than a match's
#: bookkeeping, and a flight or a log uses one config throughout.
_last_params: list[tuple[ScanmatchConfig, FloatArray]] = []


def _icp_params(cfg: ScanmatchConfig) -> list[float]:
    """The ICP tuning in ``kernel_numpy.P_*`` order (up to ``N_PARAMS``)."""
    return [
        cfg.max_iterations,
        cfg.max_correspondence_m,
        cfg.min_correspondence_m,
        cfg.keep_fraction,
        cfg.robust_scale_m,
        cfg.step_tolerance_m,
        cfg.step_tolerance_rad,
        cfg.min_matches,
        cfg.noise_floor,
        cfg.degeneracy_threshold,
        *CONSTANT_PARAMS,
    ]


def _params(cfg: ScanmatchConfig) -> FloatArray:
    """The tuning as the kernels' ``params`` array, in ``kernel_numpy.P_*`` order.

    One array per config, shared: the kernels only read it (a read-only flag would make
    numba compile a second variant of each function).
    """
    if _last_params and _last_params[0][0] is cfg:
        return _last_params[0][1]
    params = np.array(_icp_params(cfg), dtype=np.float64)
    _last_params[:] = [(cfg, params)]
    return params


def track_params(cfg: ScanmatchConfig, keyframe_args: tuple[float, ...]) -> FloatArray:
    """The compiled ``track_step``'s ``params``: the ICP tuning, then the keyframe policy.

    ``keyframe_args``: the degenerate distance factor, the longest prediction gap (s),
    the line fits' shortest chord, largest gap and largest RMS (m), in ``P_*`` order.
    """
    params = np.array(
        [
            *_icp_params(cfg),
            cfg.min_matched_fraction,
            cfg.max_rms_m,
            cfg.keyframe_distance_m,
            cfg.keyframe_angle_rad,
            *keyframe_args,
        ],
        dtype=np.float64,
    )
    assert params.shape == (N_TRACK_PARAMS,)
    return params


def _iterate(
    reference: ReferenceScan, pts: FloatArray, guess: Pose, cfg: ScanmatchConfig
) -> _Track | None:
    """Gauss-Newton iterations from ``guess``; None when a step finds too few pairs."""
    out = load_kernel(cfg.kernel).icp_solve(
        np.ascontiguousarray(pts), reference.rows, np.array(guess, dtype=np.float64), _params(cfg)
    )
    if out[R_FAILED]:
        return None
    return _Track(
        pose=(float(out[R_X]), float(out[R_Y]), float(out[R_TH])),
        iterations=int(out[R_ITERATIONS]),
        converged=bool(out[R_CONVERGED]),
        rms_m=float(out[R_RMS]),
        min_information=float(out[R_MIN_INFORMATION]),
        n_inliers=int(out[R_INLIERS]),
    )


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
