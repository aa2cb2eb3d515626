"""One laser scan in, one world pose, hat height and degeneracy flag out (SPEC §1-3).

:class:`LaserPipeline` is the pure core between the URG driver's :class:`~mkflight.msgs.Scan`
records (10 Hz) and :meth:`mkflight.flight.step.FlightCore.laser_step`; the shell decides
where it runs (in-process, or in a worker process: :mod:`mkflight.flight.matcher_worker`).

Per scan:

* **Height** from the hat steps (``laser.hat_steps``) by
  :func:`~mkflight.urg.hat.hat_height` (eq 26 of the 2011 QUT CyPhy MikroKopter
  documentation, with the pitch and roll at the scan's time), or ``None`` with the reason.
  An unknown attitude (the FC sends NaN) is taken as level: then the flight step lands on
  the hat alone, level, and a 0.1 rad tilt would read only 0.5 % high.
* **Points** from the scan steps (``laser.scan_steps``): step ``s`` is at body angle
  ``b = -(s - 384)·2π/1024`` (right positive, SPEC §2). Each beam is rotated into the level
  (heading) frame by ``R_y(θ) R_x(φ)`` -- the rotation of SPEC §3 -- and its horizontal
  part is kept, so a tilted vehicle sees its vertical walls where they are (a 0.15 rad tilt
  would otherwise stretch a 3 m wall by 3.4 cm). With a valid hat height, a beam that
  drops below ``FLOOR_FRACTION`` of the sensor's height above the floor hit the floor, not
  a wall, and is dropped.
* **Pose** from :class:`~mkflight.scanmatch.keyframe.KeyframeMatcher` (PL-ICP against
  keyframes), ``dt_s`` from consecutive scans' ``t_ns``.

With the matcher's compiled kernel (``scanmatch.kernel``, numba) the height and the points
are one call (:func:`~mkflight.scanmatch.kernel_scan.scan_geometry`) and the pose another
(``track_step``); :func:`~mkflight.urg.hat.hat_height` and :func:`level_points` are the
reference and the path without it, with the same numbers to the last bit.

Frames: the matcher works in standard 2-D math (x forward, y LEFT, θ counter-clockwise);
mkflight's world frame W (SPEC §1) is x forward, y RIGHT, ψ clockwise. The two differ by a
mirror of the y axis, which maps rigid motions to rigid motions, so the conversion at this
edge is exact and per component: ``(x, y, ψ)_W = (x, -y, -θ)_math``, both ways, for poses
and for motion increments alike. W is the matcher's frame at the first scan that gives a
reference (the first *valid* scan of the flight): that scan's pose is (0, 0, 0).

Nothing raises on a bad scan (all NaN, wrong length, a 2-D array, NaN attitude, time going
backwards): the result says ``pose=None`` / ``height_m=None`` and why.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mkflight.config import Config, LaserConfig
from mkflight.conversions import NS_PER_S
from mkflight.msgs import Pose2D, Scan
from mkflight.scanmatch.geometry import FloatArray, Pose, wrap_angle
from mkflight.scanmatch.icp import MatchResult
from mkflight.scanmatch.kernel_numpy import (
    G_FLOOR_FRACTION,
    G_FLOOR_OFFSET_M,
    G_HAT_INLIER_GATE_M,
    G_HAT_MAX_RANGE_M,
    G_HAT_MAX_SPREAD_M,
    G_HAT_MIN_BEAMS,
    G_HAT_MIN_HEIGHT_M,
    G_HAT_MIN_INLIER_FRACTION,
    G_HAT_MIN_RANGE_M,
    G_HAT_OFFSET_M,
    G_MAD_TO_SIGMA,
    G_MAX_RANGE_M,
    G_MIN_RANGE_M,
    H_CODE,
    H_HEIGHT_M,
    H_SPREAD_M,
    H_USED_BEAMS,
    H_VALID_BEAMS,
    N_GEOMETRY_PARAMS,
    N_HAT_OUT,
)
from mkflight.scanmatch.kernels import load_kernel
from mkflight.scanmatch.keyframe import KeyframeMatcher
from mkflight.urg.hat import (
    MAD_TO_SIGMA,
    TILT_TOO_LARGE,
    HatSettings,
    hat_height,
    hat_result,
    min_valid_beams,
)
from mkflight.urg.units import URG_04LX

#: The URG-04LX's front step and step angle (SPEC §2: step 384 ahead, 2π/1024 per step).
FRONT_STEP = URG_04LX.afront_step
STEP_RAD = URG_04LX.step_angle_rad
#: A beam whose drop below the sensor exceeds this fraction of the sensor's height above
#: the floor (hat height + ``laser.hat_offset_m``) is taken as a floor hit and not matched.
FLOOR_FRACTION = 0.8
#: Scan intervals outside this window (s) are not used for the matcher's velocity: a
#: duplicate or backward stamp, or a 1 ns gap, would turn one scan's motion into an absurd
#: velocity and the next prediction into a jump (the URG scans every 0.1 s).
MIN_DT_S = 0.01
MAX_DT_S = 1.0
#: A motion prior beyond these is not a motion between two scans: it is ignored.
MAX_PRIOR_STEP_M = 2.0
MAX_PRIOR_TURN_RAD = math.pi

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class LaserResult:
    """What one scan gave: the inputs of ``FlightCore.laser_step`` plus how they were found.

    Attributes:
        scan_t_ns: the scan's ``t_ns`` (host time of the front step): stamp the pose with it.
        seq: the scan's sequence number.
        pose: the scan's pose in the world frame W (SPEC §1: x forward, y right, ψ
            clockwise, W fixed at the first valid scan), stamped ``scan_t_ns``; None when
            the match failed (``pose_reason`` says why).
        pose_reason: "" when ``pose`` is set, else why not.
        height_m: hat height above the floor (eq 26), positive up; None when invalid.
        height_reason: "" when ``height_m`` is set, else why not.
        degenerate: an axis of the match is unobservable (a corridor): the pose's
            component along it is the prediction's (SPEC §5: fail safe on it).
        match_valid: the registration converged on enough good correspondences (True for
            the first, reference-defining scan).
        matched_fraction: inliers / points of the scan (0..1).
        new_keyframe: this scan became the matcher's reference.
        n_points: scan points handed to the matcher.
        compute_s: thread CPU time of :meth:`LaserPipeline.process` (``time.thread_time``).
        elapsed_s: wall time of the same call (``time.perf_counter``): a caller in another
            process subtracts it from its round trip to get the IPC overhead.
    """

    scan_t_ns: int
    seq: int
    pose: Pose2D | None
    pose_reason: str
    height_m: float | None
    height_reason: str
    degenerate: bool
    match_valid: bool
    matched_fraction: float
    new_keyframe: bool
    n_points: int
    compute_s: float
    elapsed_s: float


def pose_to_math(pose_w: Pose) -> Pose:
    """A pose or increment in SPEC §1's (x fwd, y right, ψ cw) as the matcher's math frame.

    The matcher's frame is (x forward, y left, θ counter-clockwise): y and the angle flip.
    """
    return (pose_w[0], -pose_w[1], -pose_w[2])


def pose_from_math(pose: Pose) -> Pose:
    """The matcher's (x, y left, θ ccw) as SPEC §1's (x fwd, y right, ψ cw), ψ in (-π, π]."""
    return (pose[0], 0.0 - pose[1], 0.0 - wrap_angle(pose[2]))  # 0.0 - v: never -0.0


def beam_directions(steps: IntArray) -> tuple[FloatArray, FloatArray]:
    """``(cos b, sin b)`` of each step's body angle ``b = -(s - 384)·2π/1024`` (SPEC §2).

    They depend on the steps only: :class:`LaserPipeline` computes them once per scan
    layout and hands them to :func:`level_points`.
    """
    b = -(steps.astype(np.float64) - FRONT_STEP) * STEP_RAD
    return np.cos(b), np.sin(b)


def level_points(
    ranges_m: FloatArray,
    steps: IntArray,
    pitch_rad: float,
    roll_rad: float,
    *,
    min_range_m: float,
    max_range_m: float,
    floor_depth_m: float | None = None,
    directions: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """The valid beams as level-frame points in the matcher's math frame (x fwd, y left).

    The beam of step ``s`` leaves along ``(cos b, sin b, 0)`` in the body frame (FRD,
    ``b = -(s - 384)·2π/1024``); ``R_y(θ) R_x(φ)`` (SPEC §3) turns it into the level frame
    ``(lx, ly, lz)`` (z down), and the hit point's horizontal part ``r·(lx, ly)`` is what a
    vertical wall's 2-D map shows. Non-finite attitude counts as level.

    Args:
        ranges_m: (N,) ranges, NaN = invalid.
        steps: (N,) URG step of each range, ascending (scan order is kept).
        pitch_rad: pitch θ at the scan's time (SPEC §1, nose up positive).
        roll_rad: roll φ at the scan's time (right side down positive).
        min_range_m: smallest valid range (inclusive).
        max_range_m: largest valid range (inclusive: DMAX is a distance).
        floor_depth_m: the sensor's height above the floor when known: beams that drop
            below ``FLOOR_FRACTION`` of it are floor hits and are left out.
        directions: :func:`beam_directions` of ``steps`` when the caller keeps them.

    Returns:
        (M, 2) points ``(x forward, y left)`` in metres, M <= N, in step order.
    """
    if not (math.isfinite(pitch_rad) and math.isfinite(roll_rad)):
        pitch_rad = roll_rad = 0.0
    cb, sb = directions if directions is not None else beam_directions(steps)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    with np.errstate(invalid="ignore"):
        ok = (ranges_m >= min_range_m) & (ranges_m <= max_range_m)
        if not (math.isfinite(min_range_m) and math.isfinite(max_range_m)):
            ok &= np.isfinite(ranges_m)  # finite bounds already leave out NaN and inf
        if floor_depth_m is not None and math.isfinite(floor_depth_m):
            lz = -sp * cb + cp * sr * sb
            ok &= ranges_m * lz < FLOOR_FRACTION * floor_depth_m
    # the kept beams only: element by element the same products as over the whole scan;
    # y = -(r * cr * sb) as r * (-cr * sb), the same number (a sign flip rounds alike)
    r, cb, sb = ranges_m[ok], cb[ok], sb[ok]
    lx = cp * cb + sp * sr * sb
    minus_ly = -cr * sb
    points = np.empty((r.shape[0], 2))  # the products written in place: no stack copy
    np.multiply(r, lx, out=points[:, 0])
    np.multiply(r, minus_ly, out=points[:, 1])
    return points


@dataclass(frozen=True, slots=True)
class ScanLayout:
    """Where the hat and the scan steps lie in a scan of ``n`` beams from ``first_step``.

    The same for every scan of a stream, so built once (:meth:`LaserPipeline._layout`):
    the hat and scan beams as slices (views, no mask per scan), the scan steps and their
    :func:`beam_directions`.
    """

    hat: slice
    scan: slice
    scan_steps: IntArray
    directions: tuple[FloatArray, FloatArray]

    @classmethod
    def build(cls, first_step: int, n: int, laser: LaserConfig) -> ScanLayout:
        """The layout of steps ``first_step .. first_step + n - 1`` for ``laser``'s steps."""
        steps = np.arange(first_step, first_step + n, dtype=np.int64)
        scan = _within(first_step, n, laser.scan_steps)
        scan_steps = steps[scan]
        return cls(
            _within(first_step, n, laser.hat_steps), scan, scan_steps, beam_directions(scan_steps)
        )


def _within(first_step: int, n: int, bounds: tuple[int, int]) -> slice:
    """The beams of steps within ``bounds`` (inclusive) in a scan of ``n`` from ``first_step``."""
    start = min(max(bounds[0] - first_step, 0), n)
    return slice(start, max(min(bounds[1] - first_step + 1, n), start))


def geometry_params(hat: HatSettings, laser: LaserConfig) -> FloatArray:
    """The ``params`` of the compiled :func:`~mkflight.scanmatch.kernel_scan.scan_geometry`."""
    params = np.empty(N_GEOMETRY_PARAMS)
    params[G_HAT_MIN_RANGE_M] = hat.min_range_m
    params[G_HAT_MAX_RANGE_M] = hat.max_range_m
    params[G_HAT_MIN_BEAMS] = hat.min_beams
    params[G_HAT_MIN_INLIER_FRACTION] = hat.min_inlier_fraction
    params[G_HAT_INLIER_GATE_M] = hat.inlier_gate_m
    params[G_HAT_MAX_SPREAD_M] = hat.max_spread_m
    params[G_HAT_MIN_HEIGHT_M] = hat.min_height_m
    params[G_HAT_OFFSET_M] = hat.offset_m
    params[G_FLOOR_OFFSET_M] = laser.hat_offset_m
    params[G_FLOOR_FRACTION] = FLOOR_FRACTION
    params[G_MIN_RANGE_M] = laser.min_range_m
    params[G_MAX_RANGE_M] = laser.max_range_m
    params[G_MAD_TO_SIGMA] = MAD_TO_SIGMA
    return params


def _plain_array(ranges: FloatArray) -> bool:
    """A 1-D array the compiled call takes as it is typed (else numba would compile anew)."""
    flags = ranges.flags
    return bool(
        ranges.dtype == np.float64 and ranges.ndim == 1 and flags.c_contiguous and flags.writeable
    )


def _usable_prior(motion_prior: Pose | None) -> Pose | None:
    """The prior in the matcher's frame, or None when it cannot be a motion between scans."""
    if motion_prior is None:
        return None
    dx, dy, dyaw = motion_prior
    if not (math.hypot(dx, dy) <= MAX_PRIOR_STEP_M and abs(dyaw) <= MAX_PRIOR_TURN_RAD):
        return None  # also NaN / inf
    return pose_to_math(motion_prior)


class LaserPipeline:
    """Scans in, world poses and hat heights out; owns the keyframe matcher's state.

    Args:
        cfg: ``laser`` gives the hat and scan steps, the hat offset and the valid range
            window; ``scanmatch`` the ICP tuning and keyframe policy.
    """

    def __init__(self, cfg: Config) -> None:
        self._laser = cfg.laser
        self._scanmatch = cfg.scanmatch
        self._hat = HatSettings.from_config(cfg.laser)
        self._matcher = self._new_matcher()
        self._prev_t_ns: int | None = None
        self._have_reference = False
        self._last_layout: tuple[tuple[int, int], ScanLayout] | None = None
        #: the matcher's kernel (``scanmatch.kernel``): its compiled functions, if any
        self.kernel = load_kernel(cfg.scanmatch.kernel)
        self._geometry = self.kernel.scan_geometry
        self._geometry_params = geometry_params(self._hat, self._laser)
        self._hat_out = np.zeros(N_HAT_OUT)

    def _new_matcher(self) -> KeyframeMatcher:
        return KeyframeMatcher(self._scanmatch)

    def reset(self) -> None:
        """Forget every keyframe: the next valid scan defines a new world frame W (a new flight)."""
        self._matcher = self._new_matcher()
        self._prev_t_ns = None
        self._have_reference = False

    def process(
        self,
        scan: Scan,
        pitch_rad: float,
        roll_rad: float,
        motion_prior: Pose | None = None,
    ) -> LaserResult:
        """Height, points and pose of one scan (see the module docstring); never raises.

        Args:
            scan: the URG scan (``ranges_m[i]`` is step ``first_step + i``, NaN invalid).
            pitch_rad: pitch at ``scan.t_ns`` (SPEC §1; NaN or inf = unknown: the vehicle
                is taken as level, as a landing without the FC's samples commands it).
            roll_rad: roll at ``scan.t_ns``.
            motion_prior: the vehicle's motion since the previous scan, expressed in the
                previous scan's body frame with SPEC §1's signs (dx forward, dy right, dψ
                clockwise; e.g. the estimator's velocity times dt); None, non-finite or beyond
                ``MAX_PRIOR_STEP_M`` / ``MAX_PRIOR_TURN_RAD`` = the matcher's
                constant-velocity prediction (over ``dt_s`` from the scans' ``t_ns``, when
                within ``MIN_DT_S``..``MAX_DT_S``).

        Returns:
            The :class:`LaserResult` of this scan.
        """
        t0_cpu, t0 = time.thread_time(), time.perf_counter()
        arrays = self._arrays(scan)
        if isinstance(arrays, str):
            ranges: FloatArray = np.empty(0)
            layout = self._layout(0, 0)
            bad_scan = arrays
        else:
            (ranges, layout), bad_scan = arrays, ""

        if not (math.isfinite(pitch_rad) and math.isfinite(roll_rad)):
            # the FC's attitude is garbage: the vehicle flies level (as commanded then)
            pitch_rad = roll_rad = 0.0
        if self._geometry is not None and not bad_scan and _plain_array(ranges):
            height_m, height_reason, points = self._compiled(ranges, layout, pitch_rad, roll_rad)
        else:
            height_m, height_reason, points = self._geometry_numpy(
                ranges, layout, pitch_rad, roll_rad, bad_scan
            )
        dt_s = self._scan_interval_s(scan.t_ns)
        update = self._matcher.update(points, motion_prior=_usable_prior(motion_prior), dt_s=dt_s)
        result = update.result
        n_points = int(points.shape[0])
        if update.new_keyframe:
            self._have_reference = True
        pose, pose_reason = self._pose(scan.t_ns, update.pose, result, bad_scan, n_points)
        return LaserResult(
            scan_t_ns=scan.t_ns,
            seq=scan.seq,
            pose=pose,
            pose_reason=pose_reason,
            height_m=height_m,
            height_reason=height_reason,
            degenerate=bool(result.degenerate and result.valid),
            match_valid=bool(result.valid),
            matched_fraction=float(result.matched_fraction),
            new_keyframe=update.new_keyframe,
            n_points=n_points,
            compute_s=time.thread_time() - t0_cpu,
            elapsed_s=time.perf_counter() - t0,
        )

    def _arrays(self, scan: Scan) -> tuple[FloatArray, ScanLayout] | str:
        """The scan's ranges as a flat array and its layout, or why they cannot be had."""
        try:
            ranges = np.asarray(scan.ranges_m, dtype=np.float64)
            if ranges.ndim != 1:
                return f"bad scan: ranges have shape {ranges.shape}, expected one row"
            layout = self._layout(int(scan.first_step), ranges.shape[0])
        except (TypeError, ValueError, OverflowError) as err:
            return f"bad scan: {err}"
        return ranges, layout

    def _layout(self, first_step: int, n: int) -> ScanLayout:
        """The layout of this scan: the last one's when the steps are the same (they are)."""
        if self._last_layout is None or self._last_layout[0] != (first_step, n):
            self._last_layout = ((first_step, n), ScanLayout.build(first_step, n, self._laser))
        return self._last_layout[1]

    def _geometry_numpy(
        self,
        ranges: FloatArray,
        layout: ScanLayout,
        pitch_rad: float,
        roll_rad: float,
        bad_scan: str = "",
    ) -> tuple[float | None, str, FloatArray]:
        """The hat height (or None) and why not, and the level points, in numpy."""
        height_m, height_reason = self._height(ranges, layout, pitch_rad, roll_rad, bad_scan)
        floor = None if height_m is None else height_m + self._laser.hat_offset_m
        points = level_points(
            ranges[layout.scan],
            layout.scan_steps,
            pitch_rad,
            roll_rad,
            min_range_m=self._laser.min_range_m,
            max_range_m=self._laser.max_range_m,
            floor_depth_m=floor,
            directions=layout.directions,
        )
        return height_m, height_reason, points

    def _compiled(
        self, ranges: FloatArray, layout: ScanLayout, pitch_rad: float, roll_rad: float
    ) -> tuple[float | None, str, FloatArray]:
        """:meth:`_geometry_numpy` in one compiled call: the same numbers, the same reasons.

        The hat's check of the tilt and its reasons stay here (:func:`hat_result`). The
        attitude is finite (:meth:`process` levels an unknown one).
        """
        hat, hat_settings = layout.hat, self._hat
        n_hat = hat.stop - hat.start
        skip = ""
        if n_hat == 0:
            skip = f"no hat steps {self._laser.hat_steps} in the scan"
        elif (
            abs(pitch_rad) > hat_settings.max_tilt_rad or abs(roll_rad) > hat_settings.max_tilt_rad
        ):
            skip = TILT_TOO_LARGE
        cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
        cr, sr = math.cos(roll_rad), math.sin(roll_rad)
        cb, sb = layout.directions
        out = self._hat_out
        points = self._geometry(  # type: ignore[misc]  # checked not None by the caller
            ranges,
            hat.start,
            hat.start if skip else hat.stop,
            min_valid_beams(hat_settings, n_hat),
            layout.scan.start,
            layout.scan.stop,
            cb,
            sb,
            cp,
            sp,
            cr,
            sr,
            cp * cr,
            self._geometry_params,
            out,
        )
        if skip:
            return None, skip, points
        o = out.tolist()
        result = hat_result(
            int(o[H_CODE]),
            n_hat,
            int(o[H_VALID_BEAMS]),
            int(o[H_USED_BEAMS]),
            o[H_SPREAD_M],
            o[H_HEIGHT_M],
        )
        return (result.height_m if result.valid else None), result.reason, points

    def _height(
        self,
        ranges: FloatArray,
        layout: ScanLayout,
        pitch_rad: float,
        roll_rad: float,
        bad_scan: str,
    ) -> tuple[float | None, str]:
        """The hat height (eq 26) and "", or None and why not."""
        if bad_scan:
            return None, bad_scan
        if layout.hat.stop == layout.hat.start:
            return None, f"no hat steps {self._laser.hat_steps} in the scan"
        hat = hat_height(ranges[layout.hat], pitch_rad, roll_rad, self._hat)
        return (hat.height_m if hat.valid else None), hat.reason

    def _scan_interval_s(self, t_ns: int) -> float | None:
        """Seconds since the previous scan, None outside ``MIN_DT_S``..``MAX_DT_S``."""
        dt_s = None
        if self._prev_t_ns is not None:
            dt_s = (t_ns - self._prev_t_ns) / NS_PER_S
            dt_s = dt_s if MIN_DT_S <= dt_s <= MAX_DT_S else None
        self._prev_t_ns = t_ns
        return dt_s

    def _pose(
        self, t_ns: int, pose_math: Pose, result: MatchResult, bad_scan: str, n_points: int
    ) -> tuple[Pose2D | None, str]:
        """The match's pose in W stamped ``t_ns`` and "", or None and why not."""
        if result.valid and self._have_reference:
            x_m, y_m, yaw_rad = pose_from_math(pose_math)
            return Pose2D(t_ns, x_m, y_m, yaw_rad), ""
        if bad_scan:
            return None, bad_scan
        if not self._have_reference:
            return None, f"no reference scan yet ({n_points} usable points)"
        return None, (
            f"match failed: {n_points} points, {result.matched_fraction:.2f} matched, "
            f"rms {result.rms_m:.3f} m"
        )
