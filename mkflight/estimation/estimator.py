"""The estimator (SPEC §3, seed §H): IMU prediction, laser correction, latency compensation.

A pure, stateful core: the flight step calls :meth:`Estimator.on_imu` for each DebugOut
(~50 ms), :meth:`Estimator.on_pose` for each scan-matched pose (100 ms, stamped with the
time the scan was *taken*, ~100 ms before it arrives) and :meth:`Estimator.on_height` for
each hat height. No clock is read: every time comes in as ``t_ns``.

How it works. The history is a list of *knots*: each IMU sample is one, holding its
level-frame acceleration (held until the next knot, the ``a(t)`` of eq 15-17), the MK's
gyro yaw and the state after it. A pose (or height) becomes an *anchor* at its scan time:
the knot there (inserted if it falls between two samples) takes the laser position as
its position and the laser velocity as the filter's measurement; every later knot is then
recomputed from its predecessor with the stored accelerations (eq 15-17). So the position
is the laser position at ``t_scan`` plus the integral of ``v_hat`` since, and the yaw is
the laser yaw at ``t_scan`` plus the MK gyro yaw's change since (the gyro drifts, but
smoothly). With latency compensation the laser velocity, an average over the last scan
interval, is carried forward to each knot with the measured acceleration, so the filter
compares like with like. A scan older than the history falls back on the one-sample
prediction of eq 18-20; ``latency_compensation: false`` uses each pose as if it were
current (the seed's behaviour).

The horizontal acceleration integrated is, by default, the attitude's with the
accelerometers' view of what it misses (:mod:`mkflight.estimation.tilt_accel`:
``estimation.tilt_acceleration``), which keeps the motors' vibration out of the velocity.

Non-finite or implausible input is rejected and counted: NaN never enters the state.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, replace

from mkflight.clock import NS_PER_S
from mkflight.config import EstimationConfig
from mkflight.estimation.filter import (
    LaserVelocity,
    complementary_step,
    laser_velocity,
    rate_of_change,
)
from mkflight.estimation.records import EstimatorCounters, LaserStep
from mkflight.estimation.tilt_accel import TiltAcceleration
from mkflight.frames import body_to_world, level_acceleration, world_to_body, wrap_pi
from mkflight.msgs import Estimate, ImuSample, Pose2D

Vec2 = tuple[float, float]


@dataclass(frozen=True, slots=True)
class _Knot:
    """One point of the history: the state at ``t_ns`` and the inputs held from it."""

    t_ns: int
    acc_l: tuple[float, float, float]  # level frame FRD, m/s^2, held until the next knot
    mk_yaw_rad: float
    x_m: float = 0.0
    y_m: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    h_m: float = 0.0
    vz_up_mps: float = 0.0
    meas_w: Vec2 | None = None  # laser velocity (W) at this knot, the filter's measurement
    meas_z: float | None = None  # hat height rate (up), m/s
    fix_xy: Vec2 | None = None  # set: this knot is a pose anchor
    fix_h: float | None = None  # set: this knot is a height anchor


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _knot_finite(k: _Knot) -> bool:
    return _finite(k.x_m, k.y_m, k.vx_mps, k.vy_mps, k.h_m, k.vz_up_mps)


class Estimator:
    """World-frame position, velocity, yaw and height (SPEC §3; seed eq 15-20, 26).

    Args:
        cfg: filter period (default T), gains k, latency compensation, history length.
        g_mps2: gravity, m/s^2 (``MkConfig.g_mps2``).
        pose_stale_s: a pose older than this makes ``pose_valid`` False.
        height_stale_s: a height older than this makes ``height_valid`` False.
        max_meas_gap_s: two poses (heights) further apart give no velocity.
        max_imu_gap_s: a longer gap between IMU samples is integrated over T only.
        max_abs_acc_mps2: specific force components beyond this are rejected.
        max_abs_position_m: pose and height components beyond this are rejected.
    """

    def __init__(
        self,
        cfg: EstimationConfig,
        g_mps2: float,
        *,
        pose_stale_s: float = 0.3,
        height_stale_s: float = 0.3,
        max_meas_gap_s: float = 0.5,
        max_imu_gap_s: float = 0.25,
        max_abs_acc_mps2: float = 100.0,
        max_abs_position_m: float = 1.0e4,
    ) -> None:
        self._cfg = cfg
        self._g_mps2 = g_mps2
        self._pose_stale_ns = round(pose_stale_s * NS_PER_S)
        self._height_stale_ns = round(height_stale_s * NS_PER_S)
        self._max_meas_gap_ns = round(max_meas_gap_s * NS_PER_S)
        self._max_imu_gap_ns = round(max_imu_gap_s * NS_PER_S)
        self._max_abs_acc_mps2 = max_abs_acc_mps2
        self._max_abs_position_m = max_abs_position_m
        self._knots: list[_Knot] = []
        self._yaw_offset_rad: float | None = None  # W yaw = MK yaw + offset; None: no pose yet
        self._height_started = False
        self._last_pose: Pose2D | None = None
        self._last_height: tuple[int, float] | None = None
        self._pending_pose: tuple[Pose2D, LaserVelocity | None] | None = None
        self._pending_height: tuple[int, float, float | None, int] | None = None
        self._laser_step: LaserStep | None = None
        self._counts: dict[str, int] = dict.fromkeys(EstimatorCounters.__slots__, 0)
        self._bias_l: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._k_xy = cfg.filter_gain_per_s
        self._k_z = cfg.filter_gain_z_per_s
        self._tilt = TiltAcceleration(g_mps2) if cfg.tilt_acceleration else None
        self._raw_acc_l: tuple[float, float, float] | None = None

    # ----------------------------------------------------------------- public API

    @property
    def counters(self) -> EstimatorCounters:
        """How many inputs were rejected, out of order, or had no history to go back to."""
        return EstimatorCounters(**self._counts)

    @property
    def last_acc_level(self) -> tuple[float, float, float] | None:
        """The newest sample's level-frame acceleration (FRD, no bias removed), or None."""
        return self._knots[-1].acc_l if self._knots else None

    @property
    def last_acc_residual(self) -> tuple[float, float, float | None] | None:
        """The newest sample's accelerations less what the models explain, or None.

        Level frame; z None without the thrust model; None without the model-aided
        acceleration (``estimation.tilt_acceleration``).
        """
        return None if self._tilt is None else self._tilt.residual_mps2

    @property
    def last_raw_acc_level(self) -> tuple[float, float, float] | None:
        """The newest sample's level-frame acceleration from the accelerometers alone."""
        return self._raw_acc_l

    @property
    def acc_bias_level(self) -> tuple[float, float, float]:
        """The bias subtracted from every level-frame acceleration (FRD, m/s^2)."""
        return self._bias_l

    @property
    def filter_gains(self) -> tuple[float, float]:
        """The complementary filter's gains ``(k_xy, k_z)`` in use, 1/s."""
        return self._k_xy, self._k_z

    def set_acc_bias(self, bias_level_mps2: tuple[float, float, float]) -> None:
        """Subtract this level-frame bias (FRD) from every acceleration from now on.

        The history is re-propagated with it at the next pose or height (the knots keep
        the raw accelerations). Non-finite components are taken as 0.
        """
        bx, by, bz = (v if math.isfinite(v) else 0.0 for v in bias_level_mps2)
        self._bias_l = (bx, by, bz)

    def set_acc_noise(self, noise_mps2: tuple[float, float, float]) -> None:
        """The accelerometers' measured noise (x, y, z), for the model-aided acceleration."""
        if self._tilt is not None:
            self._tilt.set_noise(*noise_mps2)

    def set_filter_gains(self, k_xy_per_s: float, k_z_per_s: float) -> None:
        """Set the complementary filter's gains k (eq 15-17), 1/s; non-finite or < 0: kept."""
        if math.isfinite(k_xy_per_s) and k_xy_per_s >= 0.0:
            self._k_xy = k_xy_per_s
        if math.isfinite(k_z_per_s) and k_z_per_s >= 0.0:
            self._k_z = k_z_per_s

    @property
    def laser_step(self) -> LaserStep | None:
        """The TABLE III values of the last accepted pose (None before the first)."""
        return self._laser_step

    def on_imu(self, imu: ImuSample, thrust_up_mps2: float | None = None) -> Estimate:
        """Predict with one IMU sample (eq 9-17): level -> world acceleration, then v, x.

        The sample's acceleration is held until the next one (eq 15's ``a(t)``); the step
        from the previous sample uses the previous acceleration and the real ``dt``.
        ``thrust_up_mps2``: the thrust model's vertical acceleration for this sample (the
        flight step's, in flight), with ``estimation.tilt_acceleration``.
        """
        f = (imu.acc_x_mps2, imu.acc_y_mps2, imu.acc_z_mps2)
        if not _finite(imu.pitch_rad, imu.roll_rad, imu.yaw_rad, *f) or any(
            abs(v) > self._max_abs_acc_mps2 for v in f
        ):
            self._counts["imu_rejected"] += 1
            return self.estimate()
        acc_l = level_acceleration(*f, imu.pitch_rad, imu.roll_rad, self._g_mps2)
        self._raw_acc_l = acc_l
        if self._tilt is not None and (not self._knots or imu.t_ns > self._knots[-1].t_ns):
            acc_l = self._tilt.blend(
                imu.t_ns, acc_l, imu.pitch_rad, imu.roll_rad, thrust_up_mps2=thrust_up_mps2
            )
        yaw = wrap_pi(imu.yaw_rad)
        if not self._knots:
            self._knots.append(_Knot(imu.t_ns, acc_l, yaw))
            self._apply_pending()
            return self.estimate()
        last = self._knots[-1]
        if imu.t_ns <= last.t_ns:
            self._counts["out_of_order"] += 1
            return self.estimate()
        if imu.t_ns - last.t_ns > self._max_imu_gap_ns:
            self._counts["imu_gaps"] += 1
        knot = self._propagate(last, _Knot(imu.t_ns, acc_l, yaw))
        if not _knot_finite(knot):
            self._counts["imu_rejected"] += 1
            return self.estimate()
        self._knots.append(knot)
        self._trim()
        return self.estimate()

    def on_pose(self, pose: Pose2D) -> None:
        """Correct with a laser pose stamped at its scan time (eq 15-16, 18-20)."""
        if not _finite(pose.x_m, pose.y_m, pose.yaw_rad) or (
            max(abs(pose.x_m), abs(pose.y_m)) > self._max_abs_position_m
        ):
            self._counts["pose_rejected"] += 1
            return
        prev = self._last_pose
        if prev is not None and pose.t_ns <= prev.t_ns:
            self._counts["out_of_order"] += 1
            return
        vel = None
        if prev is not None and pose.t_ns - prev.t_ns <= self._max_meas_gap_ns:
            vel = laser_velocity(prev, pose)
        self._last_pose = pose
        if not self._knots:
            self._pending_pose = (pose, vel)
            return
        self._apply_pose(pose, vel)

    def on_height(self, t_ns: int, height_m: float | None) -> None:
        """Correct the vertical channel with a hat height (eq 17, 26), up positive, m.

        ``None`` means the hat gave no height for this scan: counted, nothing else.
        """
        if height_m is None:
            self._counts["height_missing"] += 1
            return
        if not _finite(height_m) or abs(height_m) > self._max_abs_position_m:
            self._counts["height_rejected"] += 1
            return
        prev = self._last_height
        if prev is not None and t_ns <= prev[0]:
            self._counts["out_of_order"] += 1
            return
        rate, span_ns = None, 0
        if prev is not None and t_ns - prev[0] <= self._max_meas_gap_ns:
            rate, span_ns = rate_of_change(prev[0], prev[1], t_ns, height_m), t_ns - prev[0]
        self._last_height = (t_ns, height_m)
        if not self._knots:
            self._pending_height = (t_ns, height_m, rate, span_ns)
            return
        self._apply_height(t_ns, height_m, rate, span_ns)

    def estimate(self, now_ns: int | None = None) -> Estimate:
        """The current estimate in W (SPEC §1); validity judged at ``now_ns`` (default: now)."""
        if not self._knots:
            t = now_ns if now_ns is not None else 0
            return Estimate(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, False)
        k = self._knots[-1]
        now = k.t_ns if now_ns is None else now_ns
        offset = self._yaw_offset_rad
        pose_valid = (
            offset is not None
            and self._last_pose is not None
            and now - self._last_pose.t_ns <= self._pose_stale_ns
        )
        height_valid = (
            self._height_started
            and self._last_height is not None
            and now - self._last_height[0] <= self._height_stale_ns
        )
        yaw = wrap_pi(k.mk_yaw_rad + (offset or 0.0))
        ax_ext = ay_ext = 0.0
        if self._tilt is not None and offset is not None:
            ax_ext, ay_ext = body_to_world(*self._tilt.turbulence_mps2, yaw)
        return Estimate(
            k.t_ns, k.x_m, k.y_m, yaw, k.h_m, k.vx_mps, k.vy_mps, k.vz_up_mps,
            pose_valid, height_valid, ax_ext, ay_ext,
        )  # fmt: skip

    # ------------------------------------------------------------------ internals

    def _dt_s(self, t0_ns: int, t1_ns: int) -> float:
        """T from timestamps; a gap beyond ``max_imu_gap_s`` counts as one configured T."""
        if t1_ns - t0_ns > self._max_imu_gap_ns:
            return self._cfg.filter_period_s
        return (t1_ns - t0_ns) / NS_PER_S

    def _acc_w(self, k: _Knot) -> tuple[float, float, float]:
        """The knot's held acceleration in W, bias removed: x, y (needs the yaw offset), z up."""
        b = self._bias_l
        yaw = k.mk_yaw_rad + (self._yaw_offset_rad or 0.0)
        ax, ay = body_to_world(k.acc_l[0] - b[0], k.acc_l[1] - b[1], yaw)
        return ax, ay, b[2] - k.acc_l[2]

    def _propagate(self, k: _Knot, nxt: _Knot) -> _Knot:
        """``nxt`` with its state stepped from ``k`` (eq 15-17; trapezoidal position).

        Eq 15 holds ``a(t)`` over the interval (forward Euler): the velocity then lags the
        truth by half a sample (26 ms), which at the loop's crossover is phase the
        attitude's own delay cannot spare. With ``estimation.tilt_acceleration`` the
        interval's acceleration is the mean of its two samples instead (trapezoidal).
        """
        dt = self._dt_s(k.t_ns, nxt.t_ns)
        ax, ay, az = self._acc_w(k)
        if self._tilt is not None:  # the mean of the interval's two samples: no half-step lag
            bx, by, bz = self._acc_w(nxt)
            ax, ay, az = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
        carry = self._cfg.latency_compensation
        x, y, vx, vy, meas_w = k.x_m, k.y_m, k.vx_mps, k.vy_mps, k.meas_w
        if self._yaw_offset_rad is not None:
            mx, my = (None, None) if meas_w is None else meas_w
            kxy = self._k_xy
            vx1 = complementary_step(vx, mx, ax, dt, kxy)
            vy1 = complementary_step(vy, my, ay, dt, kxy)
            x, y, vx, vy = x + 0.5 * (vx + vx1) * dt, y + 0.5 * (vy + vy1) * dt, vx1, vy1
            if meas_w is not None and carry:
                meas_w = (meas_w[0] + ax * dt, meas_w[1] + ay * dt)
        h, vz, meas_z = k.h_m, k.vz_up_mps, k.meas_z
        if self._height_started:
            vz1 = complementary_step(vz, meas_z, az, dt, self._k_z)
            h, vz = h + 0.5 * (vz + vz1) * dt, vz1
            if meas_z is not None and carry:
                meas_z += az * dt
        if nxt.fix_xy is not None:  # a pose anchor keeps its laser position and velocity
            x, y = nxt.fix_xy
            meas_w = nxt.meas_w
        if nxt.fix_h is not None:
            h, meas_z = nxt.fix_h, nxt.meas_z
        return replace(
            nxt, x_m=x, y_m=y, vx_mps=vx, vy_mps=vy, h_m=h, vz_up_mps=vz,
            meas_w=meas_w, meas_z=meas_z,
        )  # fmt: skip

    def _anchor(self, t_ns: int) -> int | None:
        """Index of the knot at ``t_ns`` (inserted between two samples if needed).

        None when the history does not reach back to ``t_ns``. Without latency
        compensation, or for a time at or after the last sample, the last knot.
        """
        ks = self._knots
        if not self._cfg.latency_compensation or t_ns >= ks[-1].t_ns:
            return len(ks) - 1
        if t_ns < ks[0].t_ns:
            return None
        j = bisect.bisect_right([k.t_ns for k in ks], t_ns) - 1
        if ks[j].t_ns == t_ns:
            return j
        a, b = ks[j], ks[j + 1]
        frac = (t_ns - a.t_ns) / (b.t_ns - a.t_ns)
        mk_yaw = wrap_pi(a.mk_yaw_rad + frac * wrap_pi(b.mk_yaw_rad - a.mk_yaw_rad))
        ks.insert(j + 1, self._propagate(a, _Knot(t_ns, a.acc_l, mk_yaw)))
        return j + 1

    def _acc_integral_w(self, t0_ns: int, t1_ns: int) -> tuple[float, float, float]:
        """Integral of the held W acceleration over [t0, t1] within the history, m/s."""
        sx = sy = sz = 0.0
        ks = self._knots
        for i, k in enumerate(ks):
            end = ks[i + 1].t_ns if i + 1 < len(ks) else t1_ns
            lo, hi = max(k.t_ns, t0_ns), min(end, t1_ns)
            if hi > lo:
                ax, ay, az = self._acc_w(k)
                dt = (hi - lo) / NS_PER_S
                sx, sy, sz = sx + ax * dt, sy + ay * dt, sz + az * dt
        return sx, sy, sz

    def _replay(self, start: int, saved: list[_Knot]) -> bool:
        """Recompute every knot after ``start``; restore ``saved`` if anything is not finite."""
        ks = self._knots
        for m in range(start + 1, len(ks)):
            ks[m] = self._propagate(ks[m - 1], ks[m])
        if all(_knot_finite(k) for k in ks[start:]):
            return True
        self._knots = saved
        return False

    def _apply_pending(self) -> None:
        if self._pending_pose is not None:
            self._apply_pose(*self._pending_pose)
            self._pending_pose = None
        if self._pending_height is not None:
            self._apply_height(*self._pending_height)
            self._pending_height = None

    def _apply_pose(self, pose: Pose2D, vel: LaserVelocity | None) -> None:
        saved, saved_offset = list(self._knots), self._yaw_offset_rad
        a = self._anchor(pose.t_ns)
        ks = self._knots
        x, y, yaw = pose.x_m, pose.y_m, pose.yaw_rad
        compensated = self._cfg.latency_compensation
        if a is None:  # the history does not reach back: eq 18-20's prediction to now
            self._counts["history_misses"] += 1
            compensated, a = False, len(ks) - 1
            if vel is not None:
                age_s = (ks[a].t_ns - pose.t_ns) / NS_PER_S
                x, y = x + vel.vx_w_mps * age_s, y + vel.vy_w_mps * age_s
                yaw += vel.yaw_rate_radps * age_s
        self._yaw_offset_rad = wrap_pi(yaw - ks[a].mk_yaw_rad)
        meas: Vec2 | None = None
        if vel is not None:
            meas = (vel.vx_w_mps, vel.vy_w_mps)
            if self._cfg.latency_compensation:  # the average is valid mid-interval
                t_mid = pose.t_ns - round(vel.dt_s * NS_PER_S / 2)
                dvx, dvy, _ = self._acc_integral_w(t_mid, ks[a].t_ns)
                meas = (meas[0] + dvx, meas[1] + dvy)
        ks[a] = replace(ks[a], x_m=x, y_m=y, fix_xy=(x, y), meas_w=meas)
        for m in range(a + 1, len(ks)):  # this newer pose supersedes later predictions
            if ks[m].fix_xy is not None:
                ks[m] = replace(ks[m], fix_xy=None)
        if not self._replay(a, saved):
            self._yaw_offset_rad = saved_offset
            self._counts["pose_rejected"] += 1
            return
        est = self.estimate()
        w_vx, w_vy = (math.nan, math.nan) if vel is None else (vel.vx_w_mps, vel.vy_w_mps)
        b_vx, b_vy = world_to_body(w_vx, w_vy, pose.yaw_rad)
        e_vx, e_vy = world_to_body(est.vx_mps, est.vy_mps, est.yaw_rad)
        self._laser_step = LaserStep(
            pose.t_ns, w_vx, w_vy, b_vx, b_vy, e_vx, e_vy,
            pose.x_m, pose.y_m, pose.yaw_rad, compensated,
        )  # fmt: skip

    def _apply_height(self, t_ns: int, height_m: float, rate: float | None, span_ns: int) -> None:
        saved, saved_started = list(self._knots), self._height_started
        self._height_started = True
        a = self._anchor(t_ns)
        ks = self._knots
        h = height_m
        if a is None:  # eq 18-20 on the height
            self._counts["history_misses"] += 1
            a = len(ks) - 1
            if rate is not None:
                h += rate * (ks[a].t_ns - t_ns) / NS_PER_S
        meas = rate
        if rate is not None and self._cfg.latency_compensation:  # valid mid-interval
            t_mid = t_ns - span_ns // 2
            meas = rate + self._acc_integral_w(t_mid, ks[a].t_ns)[2]
        ks[a] = replace(ks[a], h_m=h, fix_h=h, meas_z=meas)
        for m in range(a + 1, len(ks)):
            if ks[m].fix_h is not None:
                ks[m] = replace(ks[m], fix_h=None)
        if not self._replay(a, saved):
            self._height_started = saved_started
            self._counts["height_rejected"] += 1

    def _trim(self) -> None:
        """Drop knots older than ``imu_history_s``, keeping one at or before the cut."""
        cut = self._knots[-1].t_ns - round(self._cfg.imu_history_s * NS_PER_S)
        i = bisect.bisect_left([k.t_ns for k in self._knots], cut)
        if i > 1:
            del self._knots[: i - 1]
