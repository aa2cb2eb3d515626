"""The estimator's Kalman filter: the algebra against NumPy, and what it must estimate."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import EstimationConfig
from mkflight.estimation import Estimator
from mkflight.estimation.kalman import (
    JUMP_M,
    MIN_GATE_MPS2,
    AxisNoise,
    AxisState,
    is_jump,
    predict,
    update_acceleration,
    update_position,
)
from mkflight.msgs import ImuSample, Pose2D

from .test_frames_level import G, specific_force_from_level

T_S = 0.05
T_NS = 50_000_000
NOISE = AxisNoise(disturbance_std=0.25, disturbance_tau_s=0.3, model_std=0.3, acc_std=0.4)


def cov(s: AxisState) -> np.ndarray:
    return np.array([[s.pp, s.pv, s.pd], [s.pv, s.vv, s.vd], [s.pd, s.vd, s.dd]])


def vec(s: AxisState) -> np.ndarray:
    return np.array([s.p, s.v, s.d])


finite = st.floats(-10, 10, allow_nan=False)
stds = st.floats(1e-3, 2.0)


@st.composite
def states(draw: st.DrawFn) -> AxisState:
    """A state with a random positive definite covariance."""
    m = np.array([[draw(st.floats(-1, 1)) for _ in range(3)] for _ in range(3)])
    p = m @ m.T + np.eye(3) * draw(st.floats(1e-4, 1.0))
    return AxisState(
        draw(finite), draw(finite), draw(finite),
        p[0, 0], p[0, 1], p[0, 2], p[1, 1], p[1, 2], p[2, 2],
    )  # fmt: skip


@given(states(), finite, st.floats(1e-3, 0.5), stds, stds)
def test_predict_is_f_p_ft_plus_q(
    s: AxisState, a: float, dt: float, model: float, dist: float
) -> None:
    noise = AxisNoise(disturbance_std=dist, disturbance_tau_s=0.3, model_std=model, acc_std=0.3)
    out = predict(s, a, dt, noise)
    h = dt * dt / 2
    f = np.array([[1, dt, h], [0, 1, dt], [0, 0, 1]])
    g = np.array([h, dt, 0.0])  # white acceleration held over the interval
    q = model**2 * np.outer(g, g)
    q[2, 2] += dist**2 * (1 - math.exp(-2 * dt / 0.3))
    np.testing.assert_allclose(cov(out), f @ cov(s) @ f.T + q, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(vec(out), f @ vec(s) + g * a, rtol=1e-12, atol=1e-12)


@given(states(), finite, stds)
def test_position_update_is_the_kalman_update(s: AxisState, z: float, std: float) -> None:
    if is_jump(z - s.p, s.pp + std * std):
        z = s.p + 0.01  # within the gate
    out = update_position(s, z, std)
    p, hrow = cov(s), np.array([[1.0, 0.0, 0.0]])
    k = p @ hrow.T / (p[0, 0] + std * std)
    np.testing.assert_allclose(vec(out), vec(s) + (k * (z - s.p)).ravel(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(cov(out), (np.eye(3) - k @ hrow) @ p, rtol=1e-9, atol=1e-12)


@given(states(), st.floats(-20, 20), st.floats(1e-4, 2.0))
def test_position_update_resets_exactly_on_a_jump(s: AxisState, z: float, std: float) -> None:
    """update_position applies is_jump's rule (written out there), on both sides of it."""
    out = update_position(s, z, std)
    reset = AxisState(z, s.v, s.d, std * std, 0.0, 0.0, s.vv, s.vd, s.dd)
    assert (out == reset) is is_jump(z - s.p, s.pp + std * std)


@given(states(), st.floats(-0.5, 0.5), stds)
def test_acceleration_update_is_the_kalman_update(s: AxisState, dr: float, std: float) -> None:
    """Within the gate (a residual near the expectation) it is the textbook update."""
    noise = AxisNoise(disturbance_std=0.25, disturbance_tau_s=0.3, model_std=0.3, acc_std=std)
    out = update_acceleration(s, s.d + dr, noise)
    p, hrow = cov(s), np.array([[0.0, 0.0, 1.0]])
    k = p @ hrow.T / (p[2, 2] + std * std)
    np.testing.assert_allclose(vec(out), vec(s) + (k * dr).ravel(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(cov(out), (np.eye(3) - k @ hrow) @ p, rtol=1e-9, atol=1e-12)


def test_a_jolt_counts_only_to_the_gate() -> None:
    s = AxisState.start(0.0, 0.01, 0.0, 0.1, 0.1)
    spike = update_acceleration(s, 50.0, NOISE)  # a landing gear's jolt, 5 g
    limit = max(NOISE.gate_sigmas * math.hypot(0.1, NOISE.acc_std), MIN_GATE_MPS2)
    at_gate = update_acceleration(s, limit, NOISE)
    assert spike.d == pytest.approx(at_gate.d)
    assert spike.d < limit


@settings(max_examples=50)
@given(st.integers(0, 2**32 - 1))
def test_covariance_stays_symmetric_positive(seed: int) -> None:
    rng = random.Random(seed)
    s = AxisState.start(0.0, 0.01, 0.0, 0.5, 0.25)
    for _ in range(200):
        s = predict(s, rng.uniform(-3, 3), rng.uniform(0.001, 0.3), NOISE)
        if rng.random() < 0.8:
            s = update_acceleration(s, rng.gauss(0, 1), NOISE)
        if rng.random() < 0.3:
            s = update_position(s, rng.gauss(0, 1), rng.uniform(0.0005, 0.05))
    assert s.finite()
    assert np.linalg.eigvalsh(cov(s)).min() > -1e-12


def track(acc_std: float, told_std: float, *, seed: int = 1) -> tuple[float, float]:
    """Filter a vehicle flying a sine under turbulence; RMS velocity and disturbance error.

    Positions (2 mm) every 100 ms, residuals every 50 ms with white noise ``acc_std``;
    the filter is told ``told_std``.
    """
    rng = np.random.default_rng(seed)
    noise = AxisNoise(disturbance_std=0.25, disturbance_tau_s=0.3, model_std=0.05, acc_std=told_std)
    s = AxisState.start(0.0, 0.002, 0.0, 0.5, 0.25)
    p = v = d = 0.0
    phi = math.exp(-T_S / 0.3)
    ev, ed = [], []
    for i in range(2000):
        t = i * T_S
        a_model = 0.5 * math.sin(2.0 * t)
        s = predict(s, a_model, T_S, noise)
        p, v = p + v * T_S + 0.5 * (a_model + d) * T_S**2, v + (a_model + d) * T_S
        d = phi * d + 0.25 * math.sqrt(1 - phi * phi) * rng.normal()
        s = update_acceleration(s, d + acc_std * rng.normal(), noise)
        if i % 2 == 0:
            s = update_position(s, p + 0.002 * rng.normal(), 0.002)
        if i > 200:
            ev.append(s.v - v)
            ed.append(s.d - d)
    return float(np.sqrt(np.mean(np.square(ev)))), float(np.sqrt(np.mean(np.square(ed))))


def test_it_tracks_velocity_and_turbulence() -> None:
    v_err, d_err = track(0.1, 0.1)
    assert v_err < 0.02  # m/s, against a 0.25 m/s sine
    assert d_err < 0.1  # m/s^2, against 0.25 m/s^2 of turbulence


def test_the_measured_vibration_is_the_right_trust() -> None:
    """A worn prop (0.5 m/s^2 of vibration): told so, the filter does better than when it
    believes the accelerometers are quiet, and as well as when it ignores them."""
    right, _ = track(0.5, 0.5)
    wrong, _ = track(0.5, 0.05)
    assert right < 0.8 * wrong


# ------------------------------------------------------------------ in the estimator


def imu_at(t_ns: int, a_l: tuple[float, float, float], pitch: float = 0.0) -> ImuSample:
    f = specific_force_from_level(a_l, pitch, 0.0)
    return ImuSample(t_ns, pitch, 0.0, 0.0, f[0], f[1], f[2], 12.0)


def fly(late_ns: int) -> tuple[float, float]:
    """A pitching vehicle (the attitude's acceleration, vibrating accelerometers), poses
    delivered ``late_ns`` after their scan; the final x and vx once all have arrived."""
    est = Estimator(EstimationConfig(), G)
    rng = np.random.default_rng(3)
    queue: list[Pose2D] = []
    x = v = 0.0
    for i in range(80):
        t_ns = i * T_NS
        pitch = 0.05 * math.sin(i / 5)
        a = -G * math.tan(pitch)
        est.on_imu(imu_at(t_ns, (a + 0.3 * rng.normal(), 0.0, 0.0), pitch))
        if i % 2 == 1:  # scanned between two samples
            queue.append(Pose2D(t_ns - T_NS // 2, x + 0.002 * rng.normal(), 0.0, 0.0))
        while queue and queue[0].t_ns <= t_ns - late_ns:
            est.on_pose(queue.pop(0))
        x, v = x + v * 0.05 + 0.5 * a * 0.05**2, v + a * 0.05
    for pose in queue:
        est.on_pose(pose)
    e = est.estimate()
    return e.x_m, e.vx_mps


def test_a_late_pose_gives_the_estimate_it_would_have_given_in_time() -> None:
    """Latency compensation is exact: the history is filtered again with each pose at
    its scan time, so poses 100 ms late end in the estimate of poses on time."""
    on_time, late = fly(0), fly(100_000_000)
    assert late == pytest.approx(on_time, abs=1e-9)
    assert on_time[1] != 0.0


def test_history_miss_carries_the_pose_with_the_velocity_estimated() -> None:
    est = Estimator(EstimationConfig(imu_history_s=0.2), G)
    for i in range(20):
        est.on_imu(imu_at(i * T_NS, (0.0, 0.0, 0.0)))
    est.on_pose(Pose2D(0, 0.3, 0.0, 0.0))  # 0.95 s old: no history there
    assert est.counters.history_misses == 1
    assert est.estimate().x_m == pytest.approx(0.3)  # started there, at rest


def test_the_disturbance_is_the_unexplained_acceleration() -> None:
    """Level attitude, the accelerometers feel a steady push: the filter integrates it."""
    est = Estimator(EstimationConfig(), G)
    est.on_imu(imu_at(0, (0.0, 0.0, 0.0)))
    est.on_pose(Pose2D(0, 0.0, 0.0, 0.0))
    est.set_acc_noise((0.05, 0.05, 0.05))
    for i in range(1, 11):
        e = est.on_imu(imu_at(i * T_NS, (0.4, 0.0, 0.0)))
    assert e.vx_mps == pytest.approx(0.4 * 0.5, rel=0.25)
    level = est.last_acc_level
    assert level is not None
    assert level[0] == pytest.approx(0.4, rel=0.1)


def test_a_jump_resets_the_position_and_keeps_the_velocity() -> None:
    """The hat over a table's edge: 0.6 m at once, 0.5 mm noise. Weighed, it would be a
    velocity of metres per second; taken as a jump, the position moves alone."""
    s = AxisState.start(0.0, 0.0005, 0.1, 0.01, 0.1)
    s = predict(s, 0.0, 0.1, NOISE)
    out = update_position(s, 0.6, 0.0005)
    assert out.p == 0.6
    assert out.v == s.v
    assert out.pp == pytest.approx(0.0005**2)
    small = update_position(s, s.p + 0.5 * JUMP_M, 0.0005)  # a centimetre or two: weighed
    assert small.v != s.v
