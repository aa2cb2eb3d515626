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
from mkflight.scanmatch.icp import MatchResult, invalid_result, match

#: Keyframe distance multiplier while the match is degenerate (see :meth:`update`).
DEGENERATE_DISTANCE_FACTOR = 3.0
#: Longest gap between scans over which the constant-velocity prediction is extrapolated.
MAX_PREDICTION_DT_S = 1.0


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
        self.keyframe_distance_m = self.config.keyframe_distance_m
        self.keyframe_angle_rad = self.config.keyframe_angle_rad
        self._line_args = (min_line_length_m, max_gap_m, max_line_rms_m)
        self._half_windows = half_windows
        self._pose: Pose = start_pose if is_finite_pose(start_pose) else IDENTITY
        self._velocity: Pose | None = None  # last increment divided by its dt (per second)
        self._last_increment: Pose = IDENTITY
        self._kf: ReferenceScan | None = None
        self._kf_pose: Pose = self._pose
        self._started = False

    @property
    def pose(self) -> Pose:
        """The latest world pose estimate."""
        return self._pose

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
        if dt_s is None:
            return self._last_increment
        if self._velocity is None or not (0.0 < dt_s <= MAX_PREDICTION_DT_S):
            return IDENTITY
        vx, vy, vth = self._velocity
        return (vx * dt_s, vy * dt_s, vth * dt_s)

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
        if motion_prior is not None and is_finite_pose(motion_prior):
            increment = motion_prior
        else:
            increment = self._predict(dt_s)
        previous = self._pose
        predicted = compose(previous, increment)

        if not self._started or self._kf is None:
            ref = self._reference(points_xy)
            if ref is None:
                self._pose = predicted if self._started else previous
                return TrackUpdate(self._pose, invalid_result(IDENTITY), new_keyframe=False)
            pose = predicted if self._started else previous
            self._started = True
            self._kf, self._kf_pose, self._pose = ref, pose, pose
            n = ref.n_points
            first = MatchResult(pose=IDENTITY, valid=True, matched_fraction=1.0, n_points=n)
            return TrackUpdate(pose, first, new_keyframe=True)

        guess = between(self._kf_pose, predicted)
        result = match(self._kf, points_xy, guess, self.config)
        pose = compose(self._kf_pose, result.pose) if result.valid else predicted
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
                self._kf, self._kf_pose, new_kf = ref, pose, True
        step = between(previous, pose)
        self._last_increment = step
        if dt_s is not None and 0.0 < dt_s <= MAX_PREDICTION_DT_S:
            self._velocity = (step[0] / dt_s, step[1] / dt_s, step[2] / dt_s)
        else:
            self._velocity = None
        self._pose = pose
        return TrackUpdate(pose, result, new_keyframe=new_kf)
