"""The Estimator (SPEC §3): latency compensation, yaw, height, validity, NaN rejection."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import EstimationConfig
from mkflight.estimation import Estimator
from mkflight.msgs import Estimate, ImuSample, Pose2D

from .test_frames_level import G, specific_force_from_level

T_NS = 50_000_000
LATE_NS = 100_000_000


def imu_at(t_ns: int, a_w: tuple[float, float, float], mk_yaw: float = 0.0) -> ImuSample:
    """An IMU sample at zero yaw offset for a world acceleration (x, y, z down), level."""
    f = specific_force_from_level(a_w, 0.0, 0.0)
    return ImuSample(t_ns, 0.0, 0.0, mk_yaw, f[0], f[1], f[2], 12.0)


def fly_constant_acceleration(compensate: bool) -> float:
    """RMS position error of a constant-acceleration flight, poses 100 ms late."""
    est = Estimator(EstimationConfig(tilt_acceleration=False, latency_compensation=compensate), G)
    a, v0 = (0.4, -0.3), (0.2, 0.1)
    queue: list[Pose2D] = []
    errors = []
    for i in range(200):
        t_ns = i * T_NS
        t = t_ns / 1e9
        x, y = v0[0] * t + 0.5 * a[0] * t * t, v0[1] * t + 0.5 * a[1] * t * t
        est.on_imu(imu_at(t_ns, (a[0], a[1], 0.0)))
        if i % 2 == 0:
            queue.append(Pose2D(t_ns, x, y, 0.0))
        while queue and queue[0].t_ns <= t_ns - LATE_NS:
            est.on_pose(queue.pop(0))
        e = est.estimate()
        if i >= 100:
            errors.append(math.hypot(e.x_m - x, e.y_m - y))
    return math.sqrt(sum(err * err for err in errors) / len(errors))


def test_latency_compensation_removes_most_of_the_error() -> None:
    compensated, late = fly_constant_acceleration(True), fly_constant_acceleration(False)
    assert late > 0.2  # ~v * 100 ms at v ~ 3 m/s
    assert compensated < 0.02 * late


def test_position_is_the_laser_position_plus_the_integral_since() -> None:
    """A pose from 100 ms ago at rest: x = x_scan + integral of v_hat since (here 0)."""
    est = Estimator(EstimationConfig(tilt_acceleration=False), G)
    for i in range(5):
        est.on_imu(imu_at(i * T_NS, (0.0, 0.0, 0.0)))
    est.on_pose(Pose2D(2 * T_NS, 1.0, -2.0, 0.5))
    e = est.estimate()
    assert (e.x_m, e.y_m, e.yaw_rad) == pytest.approx((1.0, -2.0, 0.5))
    assert e.pose_valid
    step = est.laser_step
    assert step is not None
    assert step.compensated
    assert math.isnan(step.w_vel_x_mps)


def test_yaw_is_laser_yaw_plus_gyro_change_since_the_scan() -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False), G)
    rate = 0.2  # rad/s of gyro yaw, offset 1.0 from the laser's
    for i in range(6):
        est.on_imu(imu_at(i * T_NS, (0.0, 0.0, 0.0), mk_yaw=1.0 + rate * i * 0.05))
    est.on_pose(Pose2D(3 * T_NS + T_NS // 2, 0.0, 0.0, 0.3))  # between two samples
    assert est.estimate().yaw_rad == pytest.approx(0.3 + rate * 0.075, abs=1e-12)


def test_laser_step_rotates_into_the_heading_frame() -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False, latency_compensation=False), G)
    est.on_imu(imu_at(0, (0.0, 0.0, 0.0)))
    est.on_pose(Pose2D(0, 0.0, 0.0, math.pi / 2))
    est.on_pose(Pose2D(100_000_000, 0.0, 0.1, math.pi / 2))  # moving +y, nose at +y
    step = est.laser_step
    assert step is not None
    assert (step.w_vel_x_mps, step.w_vel_y_mps) == pytest.approx((0.0, 1.0))
    assert (step.b_vel_x_mps, step.b_vel_y_mps) == pytest.approx((1.0, 0.0), abs=1e-12)


def test_without_compensation_the_pose_is_current() -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False, latency_compensation=False), G)
    for i in range(5):
        est.on_imu(imu_at(i * T_NS, (1.0, 0.0, 0.0)))
    est.on_pose(Pose2D(0, 0.5, 0.0, 0.0))
    assert est.estimate().x_m == 0.5


def test_history_miss_falls_back_on_eq18() -> None:
    cfg = EstimationConfig(filter="complementary", tilt_acceleration=False, imu_history_s=0.2)
    est = Estimator(cfg, G)
    for i in range(20):
        est.on_imu(imu_at(i * T_NS, (0.0, 0.0, 0.0)))
    est.on_pose(Pose2D(0, 0.0, 0.0, 0.0))
    est.on_pose(Pose2D(100_000_000, 0.1, 0.0, 0.0))  # 1 m/s, 0.85 s old
    assert est.counters.history_misses == 2
    assert est.estimate().x_m == pytest.approx(0.1 + 1.0 * 0.85)
    step = est.laser_step
    assert step is not None
    assert not step.compensated


def test_validity_and_staleness() -> None:
    est = Estimator(
        EstimationConfig(tilt_acceleration=False), G, pose_stale_s=0.3, height_stale_s=0.2
    )
    assert not est.estimate().pose_valid
    assert not est.estimate().height_valid
    est.on_imu(imu_at(0, (0.0, 0.0, 0.0)))
    assert not est.estimate().pose_valid
    est.on_pose(Pose2D(0, 0.0, 0.0, 0.0))
    est.on_height(0, 0.4)
    e = est.estimate()
    assert e.pose_valid
    assert e.height_valid
    assert e.height_m == pytest.approx(0.4)
    est.on_imu(imu_at(250_000_000, (0.0, 0.0, 0.0)))
    e = est.estimate()
    assert e.pose_valid
    assert not e.height_valid
    assert not est.estimate(now_ns=301_000_000).pose_valid
    est.on_height(300_000_000, None)
    assert est.counters.height_missing == 1


def test_climb_with_constant_acceleration() -> None:
    """Up is positive: a climb reads f_z = -(g + a_up) (a_z FRD is down)."""
    est = Estimator(EstimationConfig(tilt_acceleration=False), G)
    a_up = 0.5
    for i in range(100):
        t_ns = i * T_NS
        t = t_ns / 1e9
        est.on_imu(imu_at(t_ns, (0.0, 0.0, -a_up)))
        if i % 2 == 0 and i >= 2:
            ts = (t_ns - LATE_NS) / 1e9
            est.on_height(t_ns - LATE_NS, 0.1 + 0.5 * a_up * ts * ts)
    e = est.estimate()
    assert e.height_m == pytest.approx(0.1 + 0.5 * a_up * t * t, abs=0.01)
    assert e.vz_up_mps == pytest.approx(a_up * t, abs=0.02)


def test_tilted_imu_at_rest_keeps_still() -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False), G)
    est.on_pose(Pose2D(0, 0.2, 0.3, 0.0))
    for i in range(100):
        p, r = 0.2 * math.sin(i / 7), -0.15 * math.cos(i / 5)
        f = specific_force_from_level((0.0, 0.0, 0.0), p, r)
        e = est.on_imu(ImuSample(i * T_NS, p, r, 0.7, f[0], f[1], f[2], 12.0))
    assert (e.x_m, e.y_m, e.vx_mps, e.vy_mps) == pytest.approx((0.2, 0.3, 0.0, 0.0), abs=1e-9)


def test_out_of_order_and_nan_are_counted() -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False), G)
    est.on_imu(imu_at(T_NS, (0.0, 0.0, 0.0)))
    est.on_imu(imu_at(0, (0.0, 0.0, 0.0)))
    est.on_imu(ImuSample(2 * T_NS, math.nan, 0.0, 0.0, 0.0, 0.0, -G, 12.0))
    est.on_pose(Pose2D(T_NS, math.inf, 0.0, 0.0))
    est.on_height(T_NS, math.nan)
    c = est.counters
    assert (c.out_of_order, c.imu_rejected, c.pose_rejected, c.height_rejected) == (1, 1, 1, 1)


FLOATS = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, 1e308]
)
SMALL = st.floats(-3.0, 3.0)


@st.composite
def imu_samples(draw: st.DrawFn, t_ns: int) -> ImuSample:
    bad = draw(st.booleans())
    vals = [draw(FLOATS if bad else SMALL) for _ in range(6)]
    vals[5] = vals[5] - G if not bad else vals[5]
    p, r, y, fx, fy, fz = vals
    return ImuSample(t_ns, p, r, y, fx, fy, fz, draw(FLOATS))


def assert_finite(e: Estimate) -> None:
    assert all(math.isfinite(v) for v in msgspec.structs.astuple(e) if isinstance(v, float)), e


@settings(max_examples=150, deadline=None)
@given(st.data(), st.booleans())
def test_non_finite_input_never_reaches_the_estimate(data: st.DataObject, comp: bool) -> None:
    est = Estimator(EstimationConfig(tilt_acceleration=False, latency_compensation=comp), G)
    for i in range(data.draw(st.integers(1, 30))):
        t_ns = i * T_NS + data.draw(st.integers(0, 10_000_000))
        assert_finite(est.on_imu(data.draw(imu_samples(t_ns))))
        kind = data.draw(st.integers(0, 2))
        t_scan = t_ns - data.draw(st.integers(0, 300_000_000))
        if kind == 1:
            bad = data.draw(st.booleans())
            xs = [data.draw(FLOATS if bad else SMALL) for _ in range(3)]
            est.on_pose(Pose2D(t_scan, *xs))
        elif kind == 2:
            est.on_height(t_scan, data.draw(st.none() | FLOATS | SMALL))
        assert_finite(est.estimate())
        step = est.laser_step
        if step is not None:
            assert math.isfinite(step.b_esti_vel_x_mps)
            assert math.isfinite(step.x_m)
