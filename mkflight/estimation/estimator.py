"""The estimator (SPEC §3, §H): IMU prediction, laser correction, latency compensation.

§ and eq are those of the 2011 QUT CyPhy MikroKopter documentation. A pure, stateful core:
the flight step calls :meth:`Estimator.on_imu` for each DebugOut (~50 ms),
:meth:`Estimator.on_pose` for each scan-matched pose (100 ms, stamped with the time the scan
was *taken*, ~100 ms before it arrives) and :meth:`Estimator.on_height` for each hat height.
No clock is read: every time comes in as ``t_ns``.

How it works (the complementary filter). The history is a list of *knots*
(:mod:`mkflight.estimation.knots`): each IMU sample is one, holding its level-frame
acceleration (held until the next knot, the ``a(t)`` of eq 15-17), the MK's
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
current (the original system's behaviour, §H).

The filter (``estimation.filter``). By default a Kalman filter per axis
(:mod:`mkflight.estimation.kalman`): position, velocity and the disturbance the model
misses; the model's acceleration (the attitude's horizontally, the thrust model's
vertically in flight: ``estimation.tilt_acceleration``) is its input, the accelerometers'
residual and the laser's position (or the hat height) its measurements, with the
vibration measured in flight as the residual's noise. Each knot then holds the filter's
state and covariance after its own measurements, and a pose at ``t_scan`` re-filters the
knots since with it: the same estimate as if it had arrived in time. ``complementary`` is
eq 15-17 as described above; with ``tilt_acceleration`` the acceleration it integrates is
the attitude's plus the accelerometers' view of what it misses
(:mod:`mkflight.estimation.tilt_accel`), which keeps the motors' vibration out of the
velocity; without, it is the original system's filter (eq 15-17).

Non-finite or implausible input is rejected and counted: NaN never enters the state.
"""

from __future__ import annotations

import bisect
import math
import operator
from typing import Final

import msgspec

from mkflight.config import EstimationConfig
from mkflight.conversions import NS_PER_S
from mkflight.estimation.filter import (
    LaserVelocity,
    laser_velocity,
    rate_of_change,
)
from mkflight.estimation.kalman import (
    AxisNoise,
    AxisState,
    update_position,
)
from mkflight.estimation.knots import (
    Knot,
    Vec2,
    Vec3,
    complementary_knot,
    copy_knot,
    finite,
    kalman_knot,
    knot_finite,
)
from mkflight.estimation.records import EstimatorCounters, LaserStep
from mkflight.estimation.tilt_accel import (
    DEFAULT_NOISE_MPS2,
    DISTURBANCE_STD_MPS2,
    DISTURBANCE_TAU_S,
    DISTURBANCE_Z_STD_MPS2,
    LASTING_TAU_S,
    MIN_NOISE_MPS2,
    TiltAcceleration,
    tilt_acceleration,
)
from mkflight.frames import body_to_world, level_acceleration, world_to_body, wrap_pi
from mkflight.msgs import Estimate, ImuSample, Pose2D

START_V_STD_MPS: Final = 0.5
"""The Kalman filter's first velocity is 0, known to this (a vehicle on the floor)."""
_T_NS: Final = operator.attrgetter("t_ns")  # a knot's time, for bisect (no list of times)
MISS_V_STD_MPS: Final = 0.1
"""A pose older than the history is carried to now with the velocity estimated then; its
noise grows by this much per second of age."""


class Estimator:
    """World-frame position, velocity, yaw and height (SPEC §3; eq 15-20, 26).

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
        self._history_ns = round(cfg.imu_history_s * NS_PER_S)
        self._max_abs_acc_mps2 = max_abs_acc_mps2
        self._max_abs_position_m = max_abs_position_m
        self._knots: list[Knot] = []
        self._yaw_offset_rad: float | None = None  # W yaw = MK yaw + offset; None: no pose yet
        self._height_started = False
        self._last_pose: Pose2D | None = None
        self._last_height: tuple[int, float] | None = None
        self._pending_pose: tuple[Pose2D, LaserVelocity | None] | None = None
        self._pending_height: tuple[int, float, float | None, int] | None = None
        self._laser_step: LaserStep | None = None
        self._counts: dict[str, int] = dict.fromkeys(EstimatorCounters.__struct_fields__, 0)
        self._bias_l: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._k_xy = cfg.filter_gain_per_s
        self._k_z = cfg.filter_gain_z_per_s
        self._kalman = cfg.filter == "kalman"
        use_tilt = cfg.tilt_acceleration and not self._kalman
        self._tilt = TiltAcceleration(g_mps2) if use_tilt else None
        self._raw_acc_l: tuple[float, float, float] | None = None
        noise = DEFAULT_NOISE_MPS2
        self._noise_xy = self._axis_noise(noise, DISTURBANCE_STD_MPS2)
        self._noise_z = self._axis_noise(noise, DISTURBANCE_Z_STD_MPS2)
        self._lasting_w = (0.0, 0.0)  # the Kalman disturbance's lasting part (W)
        self._lasting_s = 0.0

    # ----------------------------------------------------------------- public API

    @property
    def counters(self) -> EstimatorCounters:
        """How many inputs were rejected, out of order, or had no history to go back to."""
        return EstimatorCounters(**self._counts)

    @property
    def poses_rejected(self) -> int:
        """How many poses were rejected so far (``counters.pose_rejected``, without the copy)."""
        return self._counts["pose_rejected"]

    @property
    def last_acc_level(self) -> tuple[float, float, float] | None:
        """The newest sample's level-frame acceleration (FRD, no bias removed), or None.

        Whose mean over a hover is the bias :meth:`set_acc_bias` takes: the acceleration
        the complementary filter integrates, or the accelerometers' own for the Kalman
        filter (the bias is theirs: it is removed from their residual, not from the
        model, whose own offsets the disturbance takes up).
        """
        if not self._knots:
            return None
        return self._raw_acc_l if self._kalman else self._knots[-1].acc_l

    @property
    def last_acc_residual(self) -> tuple[float, float, float | None] | None:
        """The newest sample's accelerations less what the models explain, or None.

        Level frame; z None without the thrust model; None without the model-aided
        acceleration (``estimation.tilt_acceleration``).
        """
        if self._kalman:
            return self._knots[-1].res_l if self._knots else None
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
    def acc_noise_used(self) -> tuple[float, float]:
        """The Kalman filter's accelerometer noise ``(x and y, z)`` in use, m/s^2."""
        return self._noise_xy.acc_std, self._noise_z.acc_std

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
        """The accelerometers' measured noise (x, y, z), for the model-aided acceleration.

        The Kalman filter takes the mean variance of x and y for both world axes (the
        heading turns them into each other); non-finite values are kept as they were.
        """
        if self._tilt is not None:
            self._tilt.set_noise(*noise_mps2)
        nx, ny, nz = noise_mps2
        if math.isfinite(nx) and math.isfinite(ny):
            xy = math.sqrt(0.5 * (max(nx, MIN_NOISE_MPS2) ** 2 + max(ny, MIN_NOISE_MPS2) ** 2))
            self._noise_xy = self._axis_noise(xy, DISTURBANCE_STD_MPS2)
        if math.isfinite(nz):
            self._noise_z = self._axis_noise(max(nz, MIN_NOISE_MPS2), DISTURBANCE_Z_STD_MPS2)

    def _axis_noise(self, acc_std: float, disturbance_std: float) -> AxisNoise:
        return AxisNoise(
            disturbance_std=disturbance_std,
            disturbance_tau_s=DISTURBANCE_TAU_S,
            model_std=self._cfg.model_noise_mps2,
            acc_std=acc_std,
        )

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
        if (
            not finite(imu.pitch_rad, imu.roll_rad, imu.yaw_rad, *f)
            or abs(f[0]) > self._max_abs_acc_mps2
            or abs(f[1]) > self._max_abs_acc_mps2
            or abs(f[2]) > self._max_abs_acc_mps2
        ):
            self._counts["imu_rejected"] += 1
            return self.estimate()
        acc_l = level_acceleration(*f, imu.pitch_rad, imu.roll_rad, self._g_mps2)
        self._raw_acc_l = acc_l
        yaw = wrap_pi(imu.yaw_rad)
        if self._kalman:
            new = self._model_knot(imu, acc_l, yaw, thrust_up_mps2)
        else:
            if self._tilt is not None and (not self._knots or imu.t_ns > self._knots[-1].t_ns):
                acc_l = self._tilt.blend(
                    imu.t_ns, acc_l, imu.pitch_rad, imu.roll_rad, thrust_up_mps2=thrust_up_mps2
                )
            new = Knot(imu.t_ns, acc_l, yaw)
        if not self._knots:
            self._knots.append(new)
            self._apply_pending()
            return self.estimate()
        last = self._knots[-1]
        if imu.t_ns <= last.t_ns:
            self._counts["out_of_order"] += 1
            return self.estimate()
        if imu.t_ns - last.t_ns > self._max_imu_gap_ns:
            self._counts["imu_gaps"] += 1
        knot = self._propagate(last, new)
        if not knot_finite(knot):
            self._counts["imu_rejected"] += 1
            return self.estimate()
        self._knots.append(knot)
        self._trim()
        if self._kalman:
            self._track_lasting(knot, (knot.t_ns - last.t_ns) / NS_PER_S)
        return self.estimate()

    def _model_knot(
        self, imu: ImuSample, acc_l: Vec3, yaw: float, thrust_up_mps2: float | None
    ) -> Knot:
        """The Kalman filter's knot: the model's acceleration and the residual measured.

        x, y: the attitude's (``estimation.tilt_acceleration``; else the accelerometers'
        as the model, no residual); z: the thrust model's when the flight step gives it.
        """
        if not self._cfg.tilt_acceleration:
            return Knot(imu.t_ns, acc_l, yaw)
        ax, ay = tilt_acceleration(imu.pitch_rad, imu.roll_rad, self._g_mps2)
        if thrust_up_mps2 is not None and math.isfinite(thrust_up_mps2):
            mz: float = -thrust_up_mps2  # FRD: down positive
            res = (acc_l[0] - ax, acc_l[1] - ay, acc_l[2] - mz)
            return Knot(imu.t_ns, (ax, ay, mz), yaw, res_l=res, z_model=True)
        return Knot(imu.t_ns, (ax, ay, acc_l[2]), yaw, res_l=(acc_l[0] - ax, acc_l[1] - ay, None))

    def _track_lasting(self, k: Knot, dt_s: float) -> None:
        """The disturbance's lasting part (its mean over ``LASTING_TAU_S``), for ``ax_ext``."""
        if k.kx is None or k.ky is None or not dt_s > 0.0:
            return
        span = self._lasting_s + dt_s
        early, lasting = dt_s / span, dt_s / LASTING_TAU_S
        w = lasting if lasting > early else early  # max(early, lasting)
        lx, ly = self._lasting_w
        self._lasting_w = (lx + w * (k.kx.d - lx), ly + w * (k.ky.d - ly))
        self._lasting_s = span

    def on_pose(self, pose: Pose2D) -> None:
        """Correct with a laser pose stamped at its scan time (eq 15-16, 18-20)."""
        if not finite(pose.x_m, pose.y_m, pose.yaw_rad) or (
            abs(pose.x_m) > self._max_abs_position_m or abs(pose.y_m) > self._max_abs_position_m
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
        if not finite(height_m) or abs(height_m) > self._max_abs_position_m:
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

    def on_scan(self, pose: Pose2D | None, t_ns: int, height_m: float | None) -> None:
        """A scan's pose (None: none) and hat height, both taken at ``t_ns``.

        The same as :meth:`on_pose` then :meth:`on_height`, bit for bit, with one replay
        of the knots since the scan instead of two where the Kalman filter allows it: its
        horizontal and vertical channels are independent, so the pose's replay is the
        height's horizontally, and the height's replay recomputes every vertical value
        the pose's replay made. Where that does not hold (the complementary filter, the
        filter's first fix, a scan older than the history, a rejected input, a state that
        is not finite) it is :meth:`on_pose` then :meth:`on_height`.
        """
        if pose is None:
            self.on_height(t_ns, height_m)
            return
        joint = None if height_m is None else self._joint_scan(pose, t_ns, height_m)
        if height_m is None or joint is None:
            self.on_pose(pose)
            self.on_height(t_ns, height_m)
            return
        ks = self._knots
        saved = list(ks)
        a, bare = joint
        if bare:  # the replay computes its state from its predecessor
            ks.insert(a, _between(saved[a - 1], saved[a], t_ns))
        before = (self._yaw_offset_rad, self._last_pose, self._last_height)
        prev, prev_h = self._last_pose, self._last_height
        vel = None
        if prev is not None and t_ns - prev.t_ns <= self._max_meas_gap_ns:
            vel = laser_velocity(prev, pose)
        self._last_pose = pose
        rate = None
        if prev_h is not None and t_ns - prev_h[0] <= self._max_meas_gap_ns:
            rate = rate_of_change(prev_h[0], prev_h[1], t_ns, height_m)
        self._last_height = (t_ns, height_m)
        # _set_pose_fix then _set_height_fix on an anchor in the history, in one knot
        k = ks[a]
        self._yaw_offset_rad = wrap_pi(pose.yaw_rad - k.mk_yaw_rad)
        ks[a] = Knot(
            k.t_ns, k.acc_l, k.mk_yaw_rad, k.x_m, k.y_m, k.vx_mps, k.vy_mps, height_m,
            k.vz_up_mps, k.meas_w, rate, (pose.x_m, pose.y_m), height_m, k.res_l, k.z_model,
            k.kx, k.ky, k.kz, self._cfg.pose_noise_m,
        )  # fmt: skip
        for m in range(a + 1, len(ks)):  # this newer scan supersedes later predictions
            k = ks[m]
            if k.fix_xy is not None or k.fix_h is not None:
                ks[m] = msgspec.structs.replace(k, fix_xy=None, fix_h=None)
        if not self._refilter(a):  # _kalman_fix's case of a started filter, then the replay
            self._knots = saved  # restored: judged input by input
            self._yaw_offset_rad, self._last_pose, self._last_height = before
            self.on_pose(pose)
            self.on_height(t_ns, height_m)
            return
        self._laser_step = self._laser_row(pose, vel, self._cfg.latency_compensation)

    def _joint_scan(self, pose: Pose2D, t_ns: int, height_m: float) -> tuple[int, bool] | None:
        """Where :meth:`on_scan` may replay once: the scan's knot's index, and whether it is new.

        None: it may not. The index is the one :meth:`_anchor` finds (after the new knot,
        if any, is inserted there).

        Once: both inputs accepted, on one knot whose predecessor's filter runs in both
        channels (the case of :meth:`_kalman_fix` that recomputes the knot from its
        predecessor, which makes a new knot's own state unused: it is inserted bare).
        """
        ks = self._knots
        if not (self._kalman and ks and self._height_started and pose.t_ns == t_ns):
            return None
        lim = self._max_abs_position_m
        x, y = pose.x_m, pose.y_m
        # finite(x, y, yaw, height): a sum of finite numbers below the limit cannot overflow
        if not math.isfinite(x + y + pose.yaw_rad + height_m) or (
            abs(x) > lim or abs(y) > lim or abs(height_m) > lim
        ):
            return None
        prev, prev_h = self._last_pose, self._last_height
        if (prev is not None and t_ns <= prev.t_ns) or (prev_h is not None and t_ns <= prev_h[0]):
            return None
        j = len(ks) - 1
        if self._cfg.latency_compensation and t_ns < ks[j].t_ns:
            if t_ns < ks[0].t_ns:
                return None
            j -= 1  # bisect_right - 1 from the end: a scan is a few knots old
            while ks[j].t_ns > t_ns:
                j -= 1
            if ks[j].t_ns != t_ns:  # between two knots: a new one after ks[j]
                k = ks[j]
                return None if k.kx is None or k.kz is None else (j + 1, True)
        if j == 0 or ks[j].kx is None or ks[j].kz is None:  # the anchor is ks[j]
            return None
        k = ks[j - 1]  # its predecessor
        return None if k.kx is None or k.kz is None else (j, False)

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
        elif self._kalman and self._cfg.tilt_acceleration and k.kx is not None and k.ky is not None:
            ax_ext, ay_ext = k.kx.d - self._lasting_w[0], k.ky.d - self._lasting_w[1]
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

    def _acc_w(self, k: Knot) -> tuple[float, float, float]:
        """The knot's held acceleration in W, bias removed: x, y (needs the yaw offset), z up."""
        b = self._bias_l
        yaw = k.mk_yaw_rad + (self._yaw_offset_rad or 0.0)
        ax, ay = body_to_world(k.acc_l[0] - b[0], k.acc_l[1] - b[1], yaw)
        return ax, ay, b[2] - k.acc_l[2]

    def _model_w(self, k: Knot) -> Vec3:
        """The Kalman filter's input at ``k`` in W (z up).

        The model's acceleration as it is, or the accelerometers' less their bias where
        there is no model.
        """
        b = self._bias_l
        bx, by = (0.0, 0.0) if self._cfg.tilt_acceleration else (b[0], b[1])
        yaw = k.mk_yaw_rad + (self._yaw_offset_rad or 0.0)
        ax, ay = body_to_world(k.acc_l[0] - bx, k.acc_l[1] - by, yaw)
        return ax, ay, (0.0 if k.z_model else b[2]) - k.acc_l[2]

    def _kalman_inputs(self, k: Knot) -> tuple[Vec3, tuple[float, float, float | None] | None]:
        """The Kalman filter's input at ``k`` in W (:meth:`_model_w`) and its residual there.

        The residual: the accelerometers less their bias, less the model (W, z up); None
        where none was measured. Both turned by one rotation: the same floats as two.
        """
        b = self._bias_l
        bx, by = (0.0, 0.0) if self._cfg.tilt_acceleration else (b[0], b[1])
        yaw = k.mk_yaw_rad + (self._yaw_offset_rad or 0.0)
        c, s = math.cos(yaw), math.sin(yaw)  # frames.body_to_world, twice
        acc_l, res_l = k.acc_l, k.res_l
        xb, yb = acc_l[0] - bx, acc_l[1] - by
        acc_w = (c * xb - s * yb, s * xb + c * yb, (0.0 if k.z_model else b[2]) - acc_l[2])
        if res_l is None:
            return acc_w, None
        xb, yb = res_l[0] - b[0], res_l[1] - b[1]
        rz = res_l[2]
        return acc_w, (c * xb - s * yb, s * xb + c * yb, None if rz is None else b[2] - rz)

    def _propagate(self, k: Knot, nxt: Knot) -> Knot:
        """``nxt`` with its state stepped from ``k`` by the configured filter."""
        dt = self._dt_s(k.t_ns, nxt.t_ns)
        horizontal = self._yaw_offset_rad is not None
        if self._kalman:
            next_acc_w, res_w = self._kalman_inputs(nxt)
            return kalman_knot(
                k, nxt, self._model_w(k), next_acc_w, res_w, dt,
                noise_xy=self._noise_xy, noise_z=self._noise_z,
                height_noise_m=self._cfg.height_noise_m,
                horizontal=horizontal, vertical=self._height_started,
            )  # fmt: skip
        return complementary_knot(
            k, nxt, self._acc_w(k), self._acc_w(nxt) if self._tilt is not None else None, dt,
            k_xy=self._k_xy, k_z=self._k_z, carry=self._cfg.latency_compensation,
            horizontal=horizontal, vertical=self._height_started,
        )  # fmt: skip

    def _refilter(self, first: int) -> bool:
        """Recompute every knot from ``first`` on from its predecessor (:meth:`_propagate`).

        False at the first knot that is not finite: the caller restores the history. The
        Kalman filter's input at a knot is turned into W once, not once as the step's end
        and again as the next step's start.
        """
        ks = self._knots
        if not self._kalman:
            for m in range(first, len(ks)):
                ks[m] = knot = self._propagate(ks[m - 1], ks[m])
                if not knot_finite(knot):
                    return False
            return True
        horizontal, vertical = self._yaw_offset_rad is not None, self._height_started
        noise_xy, noise_z, height_noise_m = self._noise_xy, self._noise_z, self._cfg.height_noise_m
        max_gap_ns, period_s = self._max_imu_gap_ns, self._cfg.filter_period_s
        knot = ks[first - 1]
        acc_w = self._model_w(knot)
        for m in range(first, len(ks)):
            nxt = ks[m]
            next_acc_w, res_w = self._kalman_inputs(nxt)
            gap_ns = nxt.t_ns - knot.t_ns
            dt = period_s if gap_ns > max_gap_ns else gap_ns / NS_PER_S  # _dt_s
            ks[m] = knot = kalman_knot(
                knot, nxt, acc_w, next_acc_w, res_w, dt,
                noise_xy=noise_xy, noise_z=noise_z, height_noise_m=height_noise_m,
                horizontal=horizontal, vertical=vertical,
            )  # fmt: skip
            if not knot_finite(knot):
                return False
            acc_w = next_acc_w
        return True

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
        j = bisect.bisect_right(ks, t_ns, key=_T_NS) - 1
        if ks[j].t_ns == t_ns:
            return j
        ks.insert(j + 1, self._propagate(ks[j], _between(ks[j], ks[j + 1], t_ns)))
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

    def _replay(self, start: int, saved: list[Knot]) -> bool:
        """Recompute every knot after ``start``; restore ``saved`` if anything is not finite."""
        if knot_finite(self._knots[start]) and self._refilter(start + 1):
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
        a, compensated = self._set_pose_fix(pose, vel)
        if self._kalman:
            a = self._kalman_fix(a, horizontal=True)
        if not self._replay(a, saved):
            self._yaw_offset_rad = saved_offset
            self._counts["pose_rejected"] += 1
            return
        self._laser_step = self._laser_row(pose, vel, compensated)

    def _set_pose_fix(self, pose: Pose2D, vel: LaserVelocity | None) -> tuple[int, bool]:
        """Anchor ``pose`` on its knot and set the yaw offset; the knot's index, compensated.

        The knots after it are not recomputed (the caller replays them).
        """
        a = self._anchor(pose.t_ns)
        ks = self._knots
        x, y, yaw = pose.x_m, pose.y_m, pose.yaw_rad
        compensated = self._cfg.latency_compensation
        std = self._cfg.pose_noise_m
        if a is None:  # the history does not reach back: eq 18-20's prediction to now
            self._counts["history_misses"] += 1
            compensated, a = False, len(ks) - 1
            age_s = (ks[a].t_ns - pose.t_ns) / NS_PER_S
            if vel is not None:
                yaw += vel.yaw_rate_radps * age_s
                if not self._kalman:
                    x, y = x + vel.vx_w_mps * age_s, y + vel.vy_w_mps * age_s
            if self._kalman:  # carried with the velocity estimated now, less trusted
                x, y = x + ks[a].vx_mps * age_s, y + ks[a].vy_mps * age_s
                std = math.hypot(std, MISS_V_STD_MPS * age_s)
        self._yaw_offset_rad = wrap_pi(yaw - ks[a].mk_yaw_rad)
        if self._kalman:
            k = copy_knot(ks[a])
            k.fix_xy, k.fix_std_m = (x, y), std
            ks[a] = k
        else:
            meas: Vec2 | None = None
            if vel is not None:
                meas = (vel.vx_w_mps, vel.vy_w_mps)
                if self._cfg.latency_compensation:  # the average is valid mid-interval
                    t_mid = pose.t_ns - round(vel.dt_s * NS_PER_S / 2)
                    dvx, dvy, _ = self._acc_integral_w(t_mid, ks[a].t_ns)
                    meas = (meas[0] + dvx, meas[1] + dvy)
            ks[a] = msgspec.structs.replace(ks[a], x_m=x, y_m=y, fix_xy=(x, y), meas_w=meas)
        for m in range(a + 1, len(ks)):  # this newer pose supersedes later predictions
            if ks[m].fix_xy is not None:
                ks[m] = msgspec.structs.replace(ks[m], fix_xy=None)
        return a, compensated

    def _laser_row(self, pose: Pose2D, vel: LaserVelocity | None, compensated: bool) -> LaserStep:
        """The TABLE III values of ``pose`` against the estimate after it."""
        k = self._knots[-1]  # the estimate's velocity and yaw (:meth:`estimate`)
        yaw = wrap_pi(k.mk_yaw_rad + (self._yaw_offset_rad or 0.0))
        w_vx, w_vy = (math.nan, math.nan) if vel is None else (vel.vx_w_mps, vel.vy_w_mps)
        b_vx, b_vy = world_to_body(w_vx, w_vy, pose.yaw_rad)
        e_vx, e_vy = world_to_body(k.vx_mps, k.vy_mps, yaw)
        return LaserStep(
            pose.t_ns, w_vx, w_vy, b_vx, b_vy, e_vx, e_vy,
            pose.x_m, pose.y_m, pose.yaw_rad, compensated,
        )  # fmt: skip

    def _apply_height(self, t_ns: int, height_m: float, rate: float | None, span_ns: int) -> None:
        saved, saved_started = list(self._knots), self._height_started
        a = self._set_height_fix(t_ns, height_m, rate, span_ns)
        if self._kalman:
            a = self._kalman_fix(a, horizontal=False)
        if not self._replay(a, saved):
            self._height_started = saved_started
            self._counts["height_rejected"] += 1

    def _set_height_fix(self, t_ns: int, height_m: float, rate: float | None, span_ns: int) -> int:
        """Anchor the height on its knot; the knot's index (the caller replays the rest)."""
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
        if rate is not None and self._cfg.latency_compensation and not self._kalman:
            t_mid = t_ns - span_ns // 2  # the rate is valid mid-interval
            meas = rate + self._acc_integral_w(t_mid, ks[a].t_ns)[2]
        k = copy_knot(ks[a])
        k.h_m, k.fix_h, k.meas_z = h, h, meas
        ks[a] = k
        for m in range(a + 1, len(ks)):
            if ks[m].fix_h is not None:
                ks[m] = msgspec.structs.replace(ks[m], fix_h=None)
        return a

    def _kalman_fix(self, a: int, *, horizontal: bool) -> int:
        """Apply the fix just set on knot ``a``; the index to replay the history from.

        The first fix starts the filter there; a later one recomputes the knot from its
        predecessor (prediction, residual, then the fix), or corrects it in place when
        the filter started on this knot.
        """
        ks = self._knots
        k = ks[a]
        started = k.kx is not None if horizontal else k.kz is not None
        before = a > 0 and (ks[a - 1].kx if horizontal else ks[a - 1].kz) is not None
        if not started:
            if horizontal and k.fix_xy is not None:
                ks[a] = msgspec.structs.replace(
                    k, kx=self._start(k.fix_xy[0], k.fix_std_m, DISTURBANCE_STD_MPS2),
                    ky=self._start(k.fix_xy[1], k.fix_std_m, DISTURBANCE_STD_MPS2),
                    x_m=k.fix_xy[0], y_m=k.fix_xy[1], vx_mps=0.0, vy_mps=0.0,
                )  # fmt: skip
            elif not horizontal and k.fix_h is not None:
                kz = self._start(k.fix_h, self._cfg.height_noise_m, DISTURBANCE_Z_STD_MPS2)
                ks[a] = msgspec.structs.replace(k, kz=kz, h_m=k.fix_h, vz_up_mps=0.0)
            return a
        if before:
            ks[a] = self._propagate(ks[a - 1], k)
            return a
        if horizontal and k.fix_xy is not None and k.kx is not None and k.ky is not None:
            kx = update_position(k.kx, k.fix_xy[0], k.fix_std_m)
            ky = update_position(k.ky, k.fix_xy[1], k.fix_std_m)
            ks[a] = msgspec.structs.replace(
                k, kx=kx, ky=ky, x_m=kx.p, y_m=ky.p, vx_mps=kx.v, vy_mps=ky.v
            )
        elif not horizontal and k.fix_h is not None and k.kz is not None:
            kz = update_position(k.kz, k.fix_h, self._cfg.height_noise_m)
            ks[a] = msgspec.structs.replace(k, kz=kz, h_m=kz.p, vz_up_mps=kz.v)
        return a

    @staticmethod
    def _start(p: float, p_std: float, d_std: float) -> AxisState:
        return AxisState.start(p, p_std, 0.0, START_V_STD_MPS, d_std)

    def _trim(self) -> None:
        """Drop knots older than ``imu_history_s``, keeping one at or before the cut."""
        cut = self._knots[-1].t_ns - self._history_ns
        i = bisect.bisect_left(self._knots, cut, key=_T_NS)
        if i > 1:
            del self._knots[: i - 1]


def _between(a: Knot, b: Knot, t_ns: int) -> Knot:
    """A knot's inputs at ``t_ns`` between ``a`` and ``b``, no state yet.

    ``a``'s acceleration held, the MK's yaw interpolated.
    """
    frac = (t_ns - a.t_ns) / (b.t_ns - a.t_ns)
    mk_yaw = wrap_pi(a.mk_yaw_rad + frac * wrap_pi(b.mk_yaw_rad - a.mk_yaw_rad))
    return Knot(t_ns, a.acc_l, mk_yaw, z_model=a.z_model)
