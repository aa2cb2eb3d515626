"""Scan-to-keyframe tracking: the stateful wrapper around :func:`~mkflight.scanmatch.icp.match`.

As ROS laser_scan_matcher does with CSM, each scan is matched against a *keyframe* (an
earlier scan) rather than against the previous scan, and a new keyframe is taken only after
the motion since the current one exceeds ``scanmatch.keyframe_distance_m`` or
``keyframe_angle_rad`` (laser_scan_matcher's ``kf_dist_linear`` / ``kf_dist_angular``). At
hover the vehicle stays near one keyframe for many scans, so the pose error does not grow
with the number of scans (scan-to-scan matching integrates one registration error per
scan), and the keyframe's line model is built once for all those scans.

The guess handed to ICP is keyframe -> current as predicted: keyframe -> previous estimate,
composed with the motion prior of the caller (odometry increment) or, without one, the
constant-velocity prediction from the last two estimates.

The class is pure: points in, pose out; the caller owns time, I/O and config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from mkflight.config import ScanmatchConfig
from mkflight.scanmatch.geometry import (
    IDENTITY,
    LINE_HALF_WINDOWS,
    MAX_LINE_GAP_M,
    MAX_LINE_RMS_M,
    MIN_LINE_LENGTH_M,
    FloatArray,
    Pose,
    ReferenceScan,
    between,
    build_reference,
    compose,
    is_finite_pose,
)
from mkflight.scanmatch.icp import MatchResult, invalid_result, match, track_params
from mkflight.scanmatch.kernel_numpy import (
    N_STATE,
    N_TRACK_OUT,
    S_HAS_VELOCITY,
    S_INCREMENT_X,
    S_KF_X,
    S_VELOCITY_X,
    S_X,
    T_CONVERGED,
    T_DEGENERATE,
    T_HANDLED,
    T_ITERATIONS,
    T_MATCH_X,
    T_MATCHED_FRACTION,
    T_MIN_INFORMATION,
    T_N_POINTS,
    T_NEW_KEYFRAME,
    T_RMS,
    T_VALID,
    T_X,
)
from mkflight.scanmatch.kernels import load_kernel

#: Keyframe distance multiplier while the match is degenerate (see :meth:`update`).
DEGENERATE_DISTANCE_FACTOR = 3.0
#: Longest gap between scans over which the constant-velocity prediction is extrapolated.
MAX_PREDICTION_DT_S = 1.0
_NAN_POSE: Final = (math.nan, math.nan, math.nan)


@dataclass(frozen=True, slots=True)
class TrackUpdate:
    """The outcome of one :meth:`KeyframeMatcher.update`.

    Attributes:
        pose: the scan's pose in the world frame (the first scan's frame composed with the
            start pose). When ``result.valid`` is False it is the prediction.
        result: the registration against the keyframe (its ``pose`` is keyframe-relative).
        new_keyframe: this scan became the new keyframe.
    """

    pose: Pose
    result: MatchResult
    new_keyframe: bool


class KeyframeMatcher:
    """Track a sensor's pose over a sequence of scans by PL-ICP against keyframes.

    With the compiled kernel a scan is one kernel call (``track_step``: prediction,
    match, keyframe policy, line fits of a new keyframe, state update) and the Python
    around it only packs the result; scans it does not take (non-finite points, thinning
    by ``max_points``, the first scan) and the numpy kernel go through the same steps in
    Python (:meth:`_update_python`), with the same poses.

    Args:
        config: the ``scanmatch`` config section: the ICP tuning and the keyframe policy
            (``keyframe_distance_m``, ``keyframe_angle_rad``); its defaults when None.
        start_pose: world pose of the first scan [(0, 0, 0)].
        min_line_length_m: shortest chord of a reference line fit (0 suits sparse
            0.5-1 degree SICK scans; see :func:`~mkflight.scanmatch.geometry.build_reference`).
        max_gap_m: jump-edge gap inside a reference line window.
        max_line_rms_m: largest RMS residual of a reference line fit.
        half_windows: window half-widths tried for line fits.
    """

    def __init__(
        self,
        config: ScanmatchConfig | None = None,
        *,
        start_pose: Pose = IDENTITY,
        min_line_length_m: float = MIN_LINE_LENGTH_M,
        max_gap_m: float = MAX_LINE_GAP_M,
        max_line_rms_m: float = MAX_LINE_RMS_M,
        half_windows: tuple[int, ...] = LINE_HALF_WINDOWS,
    ) -> None:
        self.config = config if config is not None else ScanmatchConfig()
        self._line_args = (min_line_length_m, max_gap_m, max_line_rms_m)
        self._half_windows = half_windows
        self._windows = np.asarray(half_windows, dtype=np.int64)
        self._params = track_params(
            self.config,
            (DEGENERATE_DISTANCE_FACTOR, MAX_PREDICTION_DT_S, *self._line_args),
        )
        self._state = np.zeros(N_STATE)
        self._state[S_X : S_X + 3] = start_pose if is_finite_pose(start_pose) else IDENTITY
        self._state[S_KF_X : S_KF_X + 3] = self._state[S_X : S_X + 3]
        self._out = np.zeros(N_TRACK_OUT)
        self._kf: ReferenceScan | None = None
        self._started = False
        # Thinning is the Python path's (the compiled step matches every point).
        self._compiled = (
            load_kernel(self.config.kernel).track_step if self.config.max_points <= 0 else None
        )

    @property
    def keyframe_distance_m(self) -> float:
        """Distance from the keyframe beyond which a scan becomes the new keyframe."""
        return self.config.keyframe_distance_m

    @property
    def keyframe_angle_rad(self) -> float:
        """Turn from the keyframe beyond which a scan becomes the new keyframe."""
        return self.config.keyframe_angle_rad

    @property
    def pose(self) -> Pose:
        """The latest world pose estimate."""
        x, y, th = self._state[S_X : S_X + 3].tolist()
        return (x, y, th)

    def update(
        self,
        points_xy: FloatArray,
        *,
        motion_prior: Pose | None = None,
        dt_s: float | None = None,
    ) -> TrackUpdate:
        """Match one scan and advance the track.

        Args:
            points_xy: (N, 2) valid points of the scan in the sensor frame (scan order).
            motion_prior: the sensor's motion since the previous scan, in the previous
                scan's frame (e.g. an odometry increment); None = constant velocity.
            dt_s: time since the previous scan, for the constant-velocity prediction and
                the velocity estimate; None = scans are evenly spaced.

        Returns:
            The world pose and the match result; never raises on bad scans.
        """
        kf = self._kf
        step = self._compiled
        if (
            step is not None
            and kf is not None
            and type(points_xy) is np.ndarray
            and points_xy.dtype == np.float64
            and points_xy.shape[1:] == (2,)
            and points_xy.flags.c_contiguous
            and points_xy.flags.writeable  # (numba types a read-only array apart: a compile)
        ):
            prior = _NAN_POSE if motion_prior is None else _floats(motion_prior)
            # NaN: no dt (evenly spaced scans); a NaN dt given is out of range (-1).
            dt = math.nan if dt_s is None else float(dt_s) if dt_s == dt_s else -1.0
            rows = step(
                points_xy, kf.rows, self._state, self._params, self._windows, self._out, prior, dt
            )
            if self._out[T_HANDLED] == 1.0:
                return self._packed(rows)
        return self._update_python(points_xy, motion_prior, dt_s)

    def _packed(self, rows: FloatArray) -> TrackUpdate:
        """The :class:`TrackUpdate` of a compiled step from its output array."""
        o = self._out.tolist()
        result = MatchResult(
            pose=(o[T_MATCH_X], o[T_MATCH_X + 1], o[T_MATCH_X + 2]),
            valid=o[T_VALID] == 1.0,
            degenerate=o[T_DEGENERATE] == 1.0,
            rms_m=o[T_RMS],
            matched_fraction=o[T_MATCHED_FRACTION],
            iterations=int(o[T_ITERATIONS]),
            converged=o[T_CONVERGED] == 1.0,
            min_information=o[T_MIN_INFORMATION],
            n_points=int(o[T_N_POINTS]),
        )
        new_kf = o[T_NEW_KEYFRAME] == 1.0
        if new_kf:
            self._kf = ReferenceScan(rows=rows, n_points=result.n_points)
        return TrackUpdate((o[T_X], o[T_X + 1], o[T_X + 2]), result, new_keyframe=new_kf)

    def _reference(self, points_xy: FloatArray) -> ReferenceScan | None:
        length, gap, rms = self._line_args
        return build_reference(
            points_xy,
            min_line_length_m=length,
            max_gap_m=gap,
            max_line_rms_m=rms,
            half_windows=self._half_windows,
            kernel=self.config.kernel,
        )

    def _predict(self, dt_s: float | None) -> Pose:
        """Constant-velocity increment over ``dt_s`` (the last increment when dt unknown)."""
        s = self._state
        if dt_s is None:
            return _pose_at(s, S_INCREMENT_X)
        if s[S_HAS_VELOCITY] == 0.0 or not (0.0 < dt_s <= MAX_PREDICTION_DT_S):
            return IDENTITY
        vx, vy, vth = _pose_at(s, S_VELOCITY_X)
        return (vx * dt_s, vy * dt_s, vth * dt_s)

    def _update_python(
        self, points_xy: FloatArray, motion_prior: Pose | None, dt_s: float | None
    ) -> TrackUpdate:
        """:meth:`update` step by step in Python (the numpy kernel's path, and the fallback)."""
        if motion_prior is not None and is_finite_pose(motion_prior):
            increment = motion_prior
        else:
            increment = self._predict(dt_s)
        previous = _pose_at(self._state, S_X)
        predicted = compose(previous, increment)

        if not self._started or self._kf is None:
            return self._first(points_xy, previous, predicted)

        kf_pose = _pose_at(self._state, S_KF_X)
        guess = between(kf_pose, predicted)
        result = match(self._kf, points_xy, guess, self.config)
        pose = compose(kf_pose, result.pose) if result.valid else predicted
        rel = result.pose
        # In a degenerate scene the motion along the unobservable axis is the prior's:
        # a new keyframe cannot improve it, and every switch adds a registration error,
        # so the distance limit is relaxed (x DEGENERATE_DISTANCE_FACTOR) there.
        limit_m = self.keyframe_distance_m * (
            DEGENERATE_DISTANCE_FACTOR if result.degenerate else 1.0
        )
        far = math.hypot(rel[0], rel[1]) > limit_m or abs(rel[2]) > self.keyframe_angle_rad
        new_kf = False
        if far or not result.valid:
            ref = self._reference(points_xy)
            if ref is not None:
                self._kf, new_kf = ref, True
                self._state[S_KF_X : S_KF_X + 3] = pose
        step = between(previous, pose)
        self._state[S_INCREMENT_X : S_INCREMENT_X + 3] = step
        if dt_s is not None and 0.0 < dt_s <= MAX_PREDICTION_DT_S:
            self._state[S_VELOCITY_X : S_VELOCITY_X + 3] = (
                step[0] / dt_s,
                step[1] / dt_s,
                step[2] / dt_s,
            )
            self._state[S_HAS_VELOCITY] = 1.0
        else:
            self._state[S_HAS_VELOCITY] = 0.0
        self._state[S_X : S_X + 3] = pose
        return TrackUpdate(pose, result, new_keyframe=new_kf)

    def _first(self, points_xy: FloatArray, previous: Pose, predicted: Pose) -> TrackUpdate:
        """The first scan with lines: the first keyframe (before it, the prediction)."""
        ref = self._reference(points_xy)
        pose = predicted if self._started else previous
        self._state[S_X : S_X + 3] = pose
        if ref is None:
            return TrackUpdate(pose, invalid_result(IDENTITY), new_keyframe=False)
        self._started = True
        self._kf = ref
        self._state[S_KF_X : S_KF_X + 3] = pose
        first = MatchResult(pose=IDENTITY, valid=True, matched_fraction=1.0, n_points=ref.n_points)
        return TrackUpdate(pose, first, new_keyframe=True)


def _pose_at(state: FloatArray, i: int) -> Pose:
    """The pose at ``state[i : i + 3]``, as floats."""
    x, y, th = state[i : i + 3].tolist()
    return (x, y, th)


def _floats(p: Pose) -> Pose:
    """A pose as three Python floats (the compiled step takes one tuple type only)."""
    return (float(p[0]), float(p[1]), float(p[2]))
