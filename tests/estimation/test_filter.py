"""The complementary filter (seed eq 15-17), laser velocity (eq 19) and prediction (eq 18-20).

Also the seed's MATLAB appendix (Appendix A, steps 1-3 and 5) re-implemented literally and
compared with our code on a synthetic input. The appendix's conventions, against ours:
its world and body y axes point left (the laser scan matcher's frame), its ``Yaw`` is
clockwise like our psi, ``MK_PITCH``/``MK_ROLL`` are the MK's AngleNick/AngleRoll
(``-theta``, ``-phi``) and ``ACC_X``/``ACC_Y`` the MK's AccNick/AccRoll in m/s^2 (``-f_x``,
``+f_y``; SPEC §1 table). So its ``b_v_hat_x`` is our forward velocity and its
``b_v_hat_y`` the negation of our rightward one. Its ddotX/ddotY are eq 10/12, one axis at
a time: the synthetic input tilts about one axis per sample and keeps the level vertical
acceleration zero, the seed's hover assumption, under which they are exact.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mkflight.config import EstimationConfig
from mkflight.estimation import (
    Estimator,
    complementary_step,
    laser_velocity,
    predict_pose,
    rate_of_change,
)
from mkflight.frames import level_acceleration, world_to_body
from mkflight.msgs import ImuSample, Pose2D

from .test_frames_level import G, specific_force_from_level

T = 0.05
K = 0.5
KP = 30.0
T_NS = 50_000_000


def test_step_is_eq15() -> None:
    assert complementary_step(0.2, 1.0, 0.3, 0.05, 0.5) == 0.2 + 0.05 * (0.5 * (1.0 - 0.2) + 0.3)
    assert complementary_step(0.2, None, 0.3, 0.05, 0.5) == pytest.approx(0.2 + 0.05 * 0.3)


def test_converges_to_laser_velocity_without_acceleration() -> None:
    v = 0.0
    for n in range(1, 400):
        v = complementary_step(v, 0.8, 0.0, T, K)
        assert v == pytest.approx(0.8 * (1 - (1 - K * T) ** n), abs=1e-12)
    assert v == pytest.approx(0.8, abs=1e-3)


def test_follows_a_ramp_with_bounded_lag() -> None:
    """Constant acceleration; the laser velocity lags by tau (its interval's midpoint)."""
    a, tau = 0.5, 0.05
    v_hat, errors = 0.0, []
    for n in range(2000):
        t = n * T
        v_hat = complementary_step(v_hat, a * (t - tau), a, T, K)
        errors.append(v_hat - a * (t + T))
    assert max(abs(e) for e in errors) <= a * tau + 1e-9  # never worse than the laser's lag
    assert errors[-1] == pytest.approx(-a * tau, abs=1e-6)  # the lag, not a growing error
    v_hat = 0.0  # a laser velocity without lag: the ramp is followed exactly
    for n in range(200):
        v_hat = complementary_step(v_hat, a * n * T, a, T, K)
        assert v_hat == pytest.approx(a * (n + 1) * T, abs=1e-12)


def test_laser_velocity_uses_timestamps() -> None:
    prev = Pose2D(0, 1.0, 2.0, 3.0)
    cur = Pose2D(80_000_000, 1.08, 1.96, -3.1)
    vel = laser_velocity(prev, cur)
    assert vel is not None
    assert (vel.vx_w_mps, vel.vy_w_mps) == pytest.approx((1.0, -0.5))
    assert vel.yaw_rate_radps == pytest.approx((2 * math.pi - 6.1) / 0.08)  # across +-pi
    assert vel.in_body(math.pi / 2) == pytest.approx((-0.5, -1.0))
    assert laser_velocity(cur, prev) is None
    assert laser_velocity(cur, cur) is None


def test_one_sample_prediction_is_eq20() -> None:
    prev, cur = Pose2D(0, 1.0, -2.0, 0.1), Pose2D(100_000_000, 1.3, -2.5, 0.2)
    p = predict_pose(prev, cur)
    assert (p.x_m, p.y_m, p.yaw_rad) == pytest.approx((2 * 1.3 - 1.0, 2 * -2.5 + 2.0, 0.3))
    assert p.t_ns == 200_000_000
    assert predict_pose(prev, cur, 0.05).x_m == pytest.approx(1.45)
    assert predict_pose(cur, cur) == cur


def test_rate_of_change() -> None:
    assert rate_of_change(0, 0.5, 100_000_000, 0.6) == pytest.approx(1.0)
    assert rate_of_change(5, 0.5, 5, 0.6) is None


def _synthetic(n: int, yaw_varies: bool) -> dict[str, np.ndarray]:
    """Positions (ours, m), yaw (rad), attitude and specific force (ours, FRD)."""
    rng = np.random.default_rng(6)
    t = np.arange(n) * T
    x = 0.3 * np.sin(0.7 * t) + 0.01 * rng.standard_normal(n)
    y = -0.2 * np.cos(0.5 * t) + 0.01 * rng.standard_normal(n)
    yaw = 0.4 + (0.3 * np.sin(0.4 * t) if yaw_varies else 0.0 * t)
    pitch = np.where(np.arange(n) % 2 == 0, 0.1 * np.sin(1.3 * t), 0.0)
    roll = np.where(np.arange(n) % 2 == 1, 0.08 * np.cos(0.9 * t), 0.0)
    a_fwd, a_right = 0.4 * np.sin(1.1 * t), 0.3 * np.cos(0.8 * t)
    f = np.array(
        [
            specific_force_from_level((a_fwd[i], a_right[i], 0.0), pitch[i], roll[i])
            for i in range(n)
        ]
    )
    return {"x": x, "y": y, "yaw": yaw, "pitch": pitch, "roll": roll, "f": f}


def _matlab(d: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Appendix A steps 1, 2, 3 and 5, line by line (0-based), in the seed's conventions."""
    num = len(d["x"])
    w_x, w_y, yaw = d["x"], -d["y"], d["yaw"]  # the seed's world y points left
    acc_x, acc_y = -d["f"][:, 0], d["f"][:, 1]  # AccNick, AccRoll in m/s^2
    mk_pitch, mk_roll = -d["pitch"], -d["roll"]  # AngleNick, AngleRoll
    w_x_v, w_y_v = np.diff(w_x) / T, np.diff(w_y) / T  # step 1
    b_x_v, b_y_v = np.zeros(num), np.zeros(num)
    for n in range(num - 1):  # step 2
        b_x_v[n] = math.cos(yaw[n]) * w_x_v[n] - math.sin(yaw[n]) * w_y_v[n]
        b_y_v[n] = math.sin(yaw[n]) * w_x_v[n] + math.cos(yaw[n]) * w_y_v[n]
    b_v_hat_x, b_v_hat_y = np.zeros(num), np.zeros(num)
    for n in range(num - 1):  # step 3
        ddot_x = -(acc_x[n] - G * math.sin(mk_pitch[n])) / math.cos(mk_pitch[n])
        ddot_y = -(acc_y[n] - G * math.sin(mk_roll[n])) / math.cos(mk_roll[n])
        b_v_hat_x[n + 1] = b_v_hat_x[n] + T * (K * (b_x_v[n] - b_v_hat_x[n]) + ddot_x)
        b_v_hat_y[n + 1] = b_v_hat_y[n] + T * (K * (b_y_v[n] - b_v_hat_y[n]) + ddot_y)
    pitch_cmd, roll_cmd = np.zeros(num), np.zeros(num)
    for n in range(1, num):  # step 5
        pitch_cmd[n] = KP * (0.0 - b_v_hat_x[n])
        roll_cmd[n] = KP * (0.0 - b_v_hat_y[n])
    return b_v_hat_x, b_v_hat_y, pitch_cmd, roll_cmd


def test_matlab_appendix_equals_our_functions() -> None:
    """Same procedure from our pure functions (yaw varying: the appendix filters in body)."""
    d = _synthetic(120, yaw_varies=True)
    mx, my, mpitch, mroll = _matlab(d)
    num = len(d["x"])
    poses = [Pose2D(i * T_NS, d["x"][i], d["y"][i], d["yaw"][i]) for i in range(num)]
    vx, vy = np.zeros(num), np.zeros(num)
    for n in range(num - 1):
        vel = laser_velocity(poses[n], poses[n + 1])
        assert vel is not None
        bx, by = vel.in_body(d["yaw"][n])
        f = d["f"][n]
        ax, ay, _ = level_acceleration(f[0], f[1], f[2], d["pitch"][n], d["roll"][n], G)
        vx[n + 1] = complementary_step(vx[n], bx, ax, T, K)
        vy[n + 1] = complementary_step(vy[n], by, ay, T, K)
    np.testing.assert_allclose(vx, mx, rtol=0, atol=1e-9)
    np.testing.assert_allclose(vy, -my, rtol=0, atol=1e-9)
    np.testing.assert_allclose(KP * (0.0 - vx[1:]), mpitch[1:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(KP * (0.0 - vy[1:]), -mroll[1:], rtol=0, atol=1e-9)


def test_matlab_appendix_equals_the_estimator() -> None:
    """The Estimator without latency compensation on the same input (constant yaw).

    The appendix's ``diff`` is non-causal: it gives sample n the velocity from x(n) to
    x(n+1). Our estimator is causal, so pose n+1 is handed over just before sample n+1's
    IMU step; the MK's gyro yaw is offset from the laser's to show the offset is removed.
    """
    d = _synthetic(120, yaw_varies=False)
    mx, my, _, _ = _matlab(d)
    num = len(d["x"])
    cfg = EstimationConfig(
        filter="complementary",
        tilt_acceleration=False,
        filter_period_s=T,
        filter_gain_per_s=K,
        latency_compensation=False,
    )
    est = Estimator(cfg, G)
    mk_yaw = d["yaw"][0] + 1.0
    est.on_pose(Pose2D(-T_NS, d["x"][0], d["y"][0], d["yaw"][0]))
    vx, vy = np.zeros(num), np.zeros(num)
    for n in range(num):
        f = d["f"][n]
        imu = ImuSample(n * T_NS, d["pitch"][n], d["roll"][n], mk_yaw, f[0], f[1], f[2], 12.0)
        e = est.on_imu(imu)
        assert e.yaw_rad == pytest.approx(d["yaw"][0], abs=1e-12)
        vx[n], vy[n] = world_to_body(e.vx_mps, e.vy_mps, e.yaw_rad)
        if n + 1 < num:
            est.on_pose(Pose2D(n * T_NS, d["x"][n + 1], d["y"][n + 1], d["yaw"][n + 1]))
    np.testing.assert_allclose(vx, mx, rtol=0, atol=1e-9)
    np.testing.assert_allclose(vy, -my, rtol=0, atol=1e-9)
