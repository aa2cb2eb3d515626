"""The keyframe matcher over a recorded laser log: one pose per laser record.

:func:`track_records` runs :class:`~mkflight.scanmatch.keyframe.KeyframeMatcher` over a
log's records in file order and gives each scan's pose in the log's own frame: x forward,
y left, theta counter-clockwise, starting at the first scan's logged pose -- the laser
pose of a ``FLASER`` line, the robot pose of a ``ROBOTLASER1`` line (the laser's mounting
offset on the robot, taken from the first record, is applied both ways).

Beams used:

* URG logs (a ``ROBOTLASER1`` whose beams are URG-04LX steps: resolution 2*pi/1024 and a
  start angle on a step) use only the scan steps (``laser.scan_steps``, default 150..725),
  so the laser hat (44..127) and the mirror edge (128..149) never enter the matcher; their
  line fits use the URG chord (``min_line_length_m`` 0.12 m: dense beams, 1 cm noise).
* Any other log (SICK ``FLASER``: 180 or 360 beams over 180 degrees) uses all valid
  beams, with the shortest line windows (``min_line_length_m`` 0: sparse beams).

A flight's own ``laser.raw`` (:func:`records_from_scans`) becomes URG records too: each
scan's beams in step order, stamped with the time its front step was measured, from the
pose 0 0 0. Its points are made as the flight's laser pipeline made them
(:func:`level_scan_points`): the scan steps levelled by the attitude at the scan's time
(the FC's DebugOut from ``mk.raw``) and the floor hits left out by the hat's height, so
the matcher sees what it saw in flight. Its poses are wanted in the flight's frame W (x
forward, y right, psi clockwise, SPEC §1), the matcher's is the math frame (y left, theta
counter-clockwise): :func:`poses_in_w` and :func:`odom_in_math` cross between them as the
pipeline does (:func:`~mkflight.flight.laser_pipeline.pose_from_math`).

Motion prior: given an odometry trajectory (:mod:`mkflight.scanmatch.trajectory`), the
increment ``odom(t_prev)^-1 (+) odom(t)`` between consecutive scans' timestamps is the
prior, each time matched to the nearest odometry sample within 1 ms; a scan without such
a sample falls back to the matcher's constant-velocity prediction, as every scan does
without odometry.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from mkflight.config import LaserConfig, ScanmatchConfig
from mkflight.conversions import NS_PER_S
from mkflight.flight.laser_pipeline import level_points, pose_from_math, pose_to_math
from mkflight.scanmatch.carmen import LaserRecord
from mkflight.scanmatch.geometry import Pose, between, compose, inverse, scan_to_points
from mkflight.scanmatch.icp import MatchResult
from mkflight.scanmatch.kernel_numpy import BoolArray, FloatArray
from mkflight.scanmatch.kernels import load_kernel
from mkflight.scanmatch.keyframe import KeyframeMatcher
from mkflight.urg.hat import HatSettings, hat_height

if TYPE_CHECKING:
    from mkflight.logs.scans import ScanLog

#: URG-04LX geometry (SPEC §2): 1024 steps per turn, step 384 straight ahead.
URG_STEP_RAD = 2.0 * math.pi / 1024.0
URG_FRONT_STEP = 384
#: Timestamp tolerance when looking up odometry for a scan.
ODOM_TOLERANCE_S = 1e-3
#: Line-fit chord for URG logs and for other (sparser) lasers.
URG_MIN_LINE_LENGTH_M = 0.12
SPARSE_MIN_LINE_LENGTH_M = 0.0
#: The ``kind`` of the records of a flight's ``laser.raw`` (:func:`records_from_scans`).
RAW_KIND: Final = "laser.raw"
_URG_KINDS: Final = frozenset(("ROBOTLASER1", RAW_KIND))


@dataclass(frozen=True, slots=True)
class TrackedScan:
    """One output pose and how it was obtained.

    Attributes:
        t_s: the scan's timestamp.
        pose: the pose in the log's frame (x forward, y left, theta CCW).
        result: the registration against the keyframe.
        elapsed_s: wall time spent on this scan (points, line fits when a keyframe is
            taken, registration), for benchmarks.
        used_odom: the odometry prior was available for this scan.
    """

    t_s: float
    pose: Pose
    result: MatchResult
    elapsed_s: float
    used_odom: bool


def urg_first_step(record: LaserRecord) -> int | None:
    """The URG step of beam 0 when the record's beams are URG steps, else None."""
    if record.kind not in _URG_KINDS or record.angles_rad.shape[0] < 2:
        return None
    res = float(record.angles_rad[1] - record.angles_rad[0])
    if abs(res - URG_STEP_RAD) > 1e-5:
        return None
    steps = float(record.angles_rad[0]) / URG_STEP_RAD
    if abs(steps - round(steps)) > 0.01:
        return None
    return round(steps) + URG_FRONT_STEP


def beam_mask(record: LaserRecord, scan_steps: tuple[int, int]) -> npt.NDArray[np.bool_]:
    """Valid beams to match: for URG logs only those inside ``scan_steps`` (inclusive)."""
    first = urg_first_step(record)
    mask = record.valid.copy()
    if first is not None:
        steps = first + np.arange(mask.shape[0])
        mask &= (steps >= scan_steps[0]) & (steps <= scan_steps[1])
    return mask


def records_from_scans(
    scans: ScanLog, *, min_range_m: float, max_range_m: float
) -> list[LaserRecord]:
    """One URG record per scan of a flight's ``laser.raw`` (:class:`~mkflight.logs.scans.ScanLog`).

    Beams in step order at ``(s - 384) * 2*pi/1024`` counter-clockwise (the log's math
    frame); valid: finite and ``min_range_m <= r < max_range_m``; ``t_s``: when the
    front step was measured (the ``scan`` event's time), on the log's ``t0_ns``; the
    pose 0 0 0.
    """
    angles = -scans.angles_rad[::-1]
    zero = (0.0, 0.0, 0.0)
    out: list[LaserRecord] = []
    for i, stamp_ns in enumerate(scans.stamp_t_ns.tolist()):
        ranges = scans.ranges_m[i, ::-1]
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(ranges) & (ranges >= min_range_m) & (ranges < max_range_m)
        out.append(
            LaserRecord(
                kind=RAW_KIND,
                line_no=i + 1,
                t_s=(stamp_ns - scans.t0_ns) / NS_PER_S,
                angles_rad=angles,
                ranges_m=ranges,
                valid=valid,
                max_range_m=max_range_m,
                laser_pose=zero,
                robot_pose=zero,
            )
        )
    return out


def level_scan_points(
    scans: ScanLog,
    pitch_rad: npt.NDArray[np.float64],
    roll_rad: npt.NDArray[np.float64],
    laser: LaserConfig,
) -> list[npt.NDArray[np.float64]]:
    """Each scan's matcher points as the flight's laser pipeline makes them (math frame).

    The scan steps (``laser.scan_steps``) levelled by the scan's pitch and roll
    (:func:`~mkflight.flight.laser_pipeline.level_points`), the beams that hit the floor
    left out by the hat's height (eq 26, :func:`~mkflight.urg.hat.hat_height`) plus the
    hat's offset; ``pitch_rad``/``roll_rad``: (n,) one per scan, NaN = level.
    """
    steps = scans.beam_steps[::-1].astype(np.int64)  # step order, as the driver's scan
    in_scan = (steps >= laser.scan_steps[0]) & (steps <= laser.scan_steps[1])
    in_hat = (steps >= laser.hat_steps[0]) & (steps <= laser.hat_steps[1])
    hat_settings = HatSettings.from_config(laser)
    out: list[npt.NDArray[np.float64]] = []
    for i in range(len(scans)):
        ranges = scans.ranges_m[i, ::-1]
        pitch, roll = float(pitch_rad[i]), float(roll_rad[i])
        if not (math.isfinite(pitch) and math.isfinite(roll)):
            pitch = roll = 0.0
        hat = hat_height(ranges[in_hat], pitch, roll, hat_settings)
        out.append(
            level_points(
                ranges[in_scan],
                steps[in_scan],
                pitch,
                roll,
                min_range_m=laser.min_range_m,
                max_range_m=laser.max_range_m,
                floor_depth_m=hat.height_m + laser.hat_offset_m if hat.valid else None,
            )
        )
    return out


def poses_in_w(tracked: Sequence[TrackedScan]) -> list[TrackedScan]:
    """The tracked poses in SPEC §1's W (x forward, y right, psi clockwise in (-pi, pi])."""
    return [
        TrackedScan(s.t_s, pose_from_math(s.pose), s.result, s.elapsed_s, s.used_odom)
        for s in tracked
    ]


def odom_in_math(
    odom: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """A ``t x y theta`` odometry given in W, as the matcher's math frame (y and angle flip)."""
    t, poses = odom
    flipped = np.array([pose_to_math((p[0], p[1], p[2])) for p in poses.tolist()])
    return t, flipped.reshape(-1, 3)


def _lookup(ts: npt.NDArray[np.float64], t: float) -> int:
    """Index of the sample nearest to ``t`` within :data:`ODOM_TOLERANCE_S`, else -1."""
    if ts.shape[0] == 0:
        return -1
    return _nearest_sample(ts.tolist(), int(np.searchsorted(ts, t)), t)


def _nearest_sample(ts: list[float], i: int, t: float) -> int:
    """:func:`_lookup` given ``i``, the sorted position of ``t`` in ``ts`` (ties: the later)."""
    best = -1
    best_d = ODOM_TOLERANCE_S
    for j in (i - 1, i):
        if 0 <= j < len(ts):
            d = abs(ts[j] - t)
            if d <= best_d:
                best, best_d = j, d
    return best


class _OdomPriors:
    """The odometry increment between consecutive scans as the motion prior (module doc).

    The odometry as Python floats and every scan's sorted position in its timestamps are
    taken once (one ``searchsorted`` for all scans); per scan there remain the nearest
    sample and three compositions.
    """

    def __init__(
        self,
        odom: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
        times_s: list[float],
        mount: Pose,
    ) -> None:
        self._ts: list[float] = odom[0].tolist()
        self._poses: list[Pose] = [(p[0], p[1], p[2]) for p in odom[1].tolist()]
        self._positions: list[int] = np.searchsorted(odom[0], times_s).tolist()
        self._mount, self._mount_inv = mount, inverse(mount)
        self._prev = -1

    def prior(self, i: int, t_s: float) -> Pose | None:
        """Scan ``i``'s prior (the scans are asked for in order); None: no sample."""
        cur = _nearest_sample(self._ts, self._positions[i], t_s)
        prev, self._prev = self._prev, cur
        if prev < 0 or cur < 0:
            return None
        inc_robot = between(self._poses[prev], self._poses[cur])
        return compose(compose(self._mount_inv, inc_robot), self._mount)


class _BeamPoints:
    """Each record's points to match: :func:`beam_mask`'s beams by :func:`scan_to_points`.

    The same points to the bit, cheaper: the beams' directions (cos, sin) and the step
    mask are computed once per beam layout (a log has one), so a scan costs one call of
    the compiled kernel's ``beam_points`` (or four numpy calls without it) instead of
    some twenty numpy calls. ``valid`` is finite and in range (:class:`LaserRecord`).
    """

    def __init__(
        self,
        scan_steps: tuple[int, int],
        compiled: Callable[[FloatArray, BoolArray, FloatArray], FloatArray] | None = None,
    ) -> None:
        self._scan_steps = scan_steps
        self._compiled = compiled
        self._angles: npt.NDArray[np.float64] | None = None
        self._key: tuple[bool, bytes] = (False, b"")
        self._keep: npt.NDArray[np.bool_] | None = None
        self._directions: npt.NDArray[np.float64] = np.empty((0, 2))

    def __call__(self, rec: LaserRecord) -> npt.NDArray[np.float64]:
        if rec.angles_rad is not self._angles:
            self._layout(rec)
        n = self._directions.shape[0]
        if rec.valid.shape != (n,) or rec.ranges_m.shape != (n,):
            mask = beam_mask(rec, self._scan_steps)
            return scan_to_points(rec.ranges_m[mask], rec.angles_rad[mask], -math.inf, math.inf)
        mask = rec.valid if self._keep is None else rec.valid & self._keep
        compiled, ranges = self._compiled, rec.ranges_m
        if (
            compiled is not None
            and ranges.dtype == np.float64
            and ranges.flags.c_contiguous
            and mask.dtype == np.bool_
            and mask.flags.c_contiguous
            and ranges.flags.writeable  # (numba types read-only arrays apart: a compile)
            and mask.flags.writeable
        ):
            return compiled(ranges, mask, self._directions)
        ranges = np.asarray(ranges[mask], dtype=np.float64)
        out: npt.NDArray[np.float64] = ranges[:, None] * self._directions[mask]
        return out

    def _layout(self, rec: LaserRecord) -> None:
        """The directions and the step mask of ``rec``'s layout (kept when unchanged)."""
        self._angles = rec.angles_rad
        key = (rec.kind in _URG_KINDS, rec.angles_rad.tobytes())
        if key == self._key:
            return
        self._key = key
        a = np.asarray(rec.angles_rad, dtype=np.float64).ravel()
        keep = np.isfinite(a) & beam_mask(
            replace(rec, valid=np.ones(a.shape[0], dtype=np.bool_)), self._scan_steps
        )
        self._keep = None if bool(keep.all()) else keep
        with np.errstate(invalid="ignore"):
            self._directions = np.stack((np.cos(a), np.sin(a)), axis=1)


def track_records(
    records: Sequence[LaserRecord],
    *,
    scan_steps: tuple[int, int] = LaserConfig().scan_steps,
    odom: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None,
    config: ScanmatchConfig | None = None,
    on_scan: Callable[[], None] | None = None,
    points: Sequence[npt.NDArray[np.float64]] | None = None,
) -> list[TrackedScan]:
    """Run the keyframe matcher over the records (pure apart from the clock read for timing).

    Args:
        records: the log's laser records in file order.
        scan_steps: URG steps to use (inclusive) when the log is a URG log.
        odom: ``(t, poses)`` of an odometry trajectory for the motion prior, or None.
        config: the ``scanmatch`` section (ICP tuning, keyframe policy); defaults when None.
        on_scan: called once per scan (progress).
        points: each record's points to match (math frame, :func:`level_scan_points`)
            instead of its valid beams; None: the beams.

    Returns:
        One :class:`TrackedScan` per record, in the same order.
    """
    if not records:
        return []
    first = records[0]
    urg = urg_first_step(first) is not None
    mount: Pose = (
        between(first.robot_pose, first.laser_pose)
        if first.kind == "ROBOTLASER1"
        else (0.0, 0.0, 0.0)
    )
    mount_inv = inverse(mount)
    matcher = KeyframeMatcher(
        config,
        start_pose=first.laser_pose,
        min_line_length_m=URG_MIN_LINE_LENGTH_M if urg else SPARSE_MIN_LINE_LENGTH_M,
    )
    kernel = load_kernel((config if config is not None else ScanmatchConfig()).kernel)
    beam_points = _BeamPoints(scan_steps, kernel.beam_points)
    priors = None if odom is None else _OdomPriors(odom, [r.t_s for r in records], mount)
    out: list[TrackedScan] = []
    prev_t: float | None = None
    for i, rec in enumerate(records):
        t0 = time.perf_counter()
        pts = points[i] if points is not None else beam_points(rec)
        prior = None if priors is None else priors.prior(i, rec.t_s)
        dt = None if prev_t is None else rec.t_s - prev_t
        update = matcher.update(pts, motion_prior=prior, dt_s=dt)
        pose = compose(update.pose, mount_inv) if rec.kind == "ROBOTLASER1" else update.pose
        elapsed = time.perf_counter() - t0
        out.append(TrackedScan(rec.t_s, pose, update.result, elapsed, prior is not None))
        prev_t = rec.t_s
        if on_scan is not None:
            on_scan()
    return out
