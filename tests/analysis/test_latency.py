"""The response lag (seed §F, Fig 8): synthetic known lags and simulated vehicles."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mkflight.analysis.latency import (
    WEAK_PEAK_R,
    Latency,
    acceleration_from_velocity,
    estimate_latency,
    lagged_correlation,
    peak_lag,
    refine_peak,
    resample_nearest,
)
from mkflight.analysis.precision import AnalysisInputError
from mkflight.config import Config, load_config
from mkflight.logs.events import read_events
from mkflight.logs.schema import Scan, Step
from mkflight.logs.table3 import read_table3
from mkflight.logs.table4 import read_table4
from mkflight.sim.hover import run_hover


def _command(n: int, seed: int) -> np.ndarray:
    """A smoothed random command (like stick/controller output), in counts."""
    rng = np.random.default_rng(seed)
    raw = rng.normal(0, 20, n)
    return np.convolve(raw, np.ones(3) / 3, mode="same")


@pytest.mark.parametrize("k", [0, 1, 4, 7, 13, 20])
def test_recovers_known_lag(k: int) -> None:
    cmd = _command(600, seed=k)
    rng = np.random.default_rng(100 + k)
    vel = np.roll(cmd, k) * 0.01 + rng.normal(0, 0.05, len(cmd))
    vel[:k] = np.nan  # nothing before the shift
    curve = lagged_correlation(cmd, vel, 20)
    assert abs(peak_lag(curve) - k) <= 1
    assert peak_lag(curve) == k
    assert curve[k] > 0.3


def test_refine_peak_finds_the_vertex() -> None:
    lags = np.arange(10, dtype=np.float64)
    curve = 1.0 - 0.1 * (lags - 4.3) ** 2
    assert refine_peak(curve, peak_lag(curve)) == pytest.approx(4.3)
    assert refine_peak(curve, 0) == 0.0  # no left neighbour
    assert refine_peak(np.array([0.0, 1.0, np.nan]), 1) == 1.0


def test_acceleration_from_velocity_belongs_one_scan_earlier() -> None:
    """Laser velocities of a constant-acceleration flight (a = 2): the difference of two
    pose differences, dated one scan period before the later row; a skipped scan drops
    that pair."""
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.5, 0.6])
    v_mid = 2.0 * (t - 0.05)  # each row's velocity is the one half a scan earlier
    t_acc, acc = acceleration_from_velocity(t, v_mid, 0.1)
    assert acc == pytest.approx([2.0, 2.0, 2.0, 2.0])
    assert t_acc == pytest.approx([0.0, 0.1, 0.2, 0.5])


def _attitude_flight(
    n: int, delay_steps: int, tau_steps: float, seed: int
) -> dict[str, np.ndarray]:
    """A smooth random command through delay + first-order lag, flown to laser rows.

    50 ms steps. The lag is discrete, tilt += a (target - tilt) with a = 1/(1 + τ): its
    mean delay (1 - a)/a is τ steps exactly, so the tilt follows a slow command by d + τ.
    Acceleration = tilt, velocity and position integrated (trapezoids: a rectangle rule
    would move each integral half a step earlier); a laser row every 100 ms
    carries the pose difference over the last 100 ms (like the estimator).
    """
    rng = np.random.default_rng(seed)
    cmd = np.convolve(rng.normal(0, 20, n), np.hanning(15) / np.hanning(15).sum(), mode="same")
    alpha = 1.0 / (1.0 + tau_steps)
    tilt = np.zeros(n)
    for i in range(1, n):
        target = cmd[i - delay_steps] if i >= delay_steps else 0.0
        tilt[i] = tilt[i - 1] + alpha * (target - tilt[i - 1])
    t = np.arange(n) * 0.05
    vel = np.concatenate([[0.0], np.cumsum(0.5 * (tilt[1:] + tilt[:-1]))]) * 0.05  # trapezoids
    pos = np.concatenate([[0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]))]) * 0.05
    rows = np.arange(2, n, 2)
    v_laser = (pos[rows] - pos[rows - 2]) / 0.1 + rng.normal(0, 1e-4, len(rows))
    return {"t4": t, "cmd": cmd, "tilt": tilt, "t3": t[rows], "vel": v_laser}


@pytest.mark.parametrize(("delay", "tau"), [(0, 2.0), (2, 2.0), (4, 1.0), (6, 3.0)])
def test_recovers_delay_plus_lag_through_tables(delay: int, tau: float) -> None:
    """TABLE IV commands, TABLE III velocities: the lag d + τ within one step; the roll sign
    (the y drive is -ControlRoll) and the attitude curve too."""
    f = _attitude_flight(2400, delay, tau, seed=delay)
    zeros3 = np.zeros(len(f["t3"]))
    lat = estimate_latency(
        t4_s=f["t4"],
        control_pitch_counts=f["cmd"],
        control_roll_counts=-f["cmd"],
        angle_pitch_rad=-f["tilt"] / 100,
        angle_roll_rad=f["tilt"] / 100,  # φ* = -ControlRoll/k = +cmd/k
        t3_s=f["t3"],
        b_vel_x_mps=f["vel"],
        b_vel_y_mps=zeros3,
    )
    known = delay + tau
    assert abs(lat.acceleration.lag_fine_steps - known) <= 1.0
    assert lat.lag_s == pytest.approx(lat.acceleration.lag_fine_steps * 0.05)
    assert lat.acceleration.lag_y_steps is None  # no variance on y
    assert lat.peak_r > 0.5
    assert lat.attitude is not None
    assert abs(lat.attitude.lag_fine_steps - known) <= 1.0
    assert lat.attitude.peak_r > 0.9
    # The seed's Fig 8 curve (velocity) peaks later: it adds the integration.
    assert lat.velocity is not None
    assert lat.velocity.lag_steps > lat.lag_steps + 1


def test_roll_sign_is_negated() -> None:
    """Roll: the y acceleration follows -ControlRoll (SPEC §1): a positive peak."""
    f = _attitude_flight(1200, 2, 2.0, seed=9)
    lat = estimate_latency(
        t4_s=f["t4"],
        control_pitch_counts=np.zeros(len(f["t4"])),
        control_roll_counts=-f["cmd"],
        t3_s=f["t3"],
        b_vel_x_mps=np.zeros(len(f["t3"])),
        b_vel_y_mps=f["vel"],
    )
    assert lat.acceleration.lag_x_steps is None
    assert abs(lat.lag_steps - 4) <= 1
    assert lat.peak_r > 0.5
    assert lat.attitude is None  # no angles given


def test_no_variance_is_an_error() -> None:
    curve = lagged_correlation(np.zeros(50), np.zeros(50), 20)
    assert np.all(np.isnan(curve))
    with pytest.raises(AnalysisInputError, match="no correlation"):
        peak_lag(curve)


def test_bad_shapes() -> None:
    with pytest.raises(ValueError, match="one length"):
        lagged_correlation(np.zeros(5), np.zeros(6), 2)
    with pytest.raises(ValueError, match="max_lag"):
        lagged_correlation(np.zeros(5), np.zeros(5), -1)


def test_resample_nearest_tolerance() -> None:
    t_from = np.array([0.0, 0.1, 0.2, 1.0])
    out = resample_nearest(t_from, np.array([1.0, 2.0, 3.0, 4.0]), np.array([0.04, 0.16, 0.6]), 0.1)
    assert out[0] == 1.0
    assert out[1] == 3.0
    assert math.isnan(out[2])


def _sim_latency(folder: Path) -> Latency:
    t4 = read_table4(folder / "imu_50ms.log").rows
    t3 = read_table3(folder / "laser_100ms.log").rows
    events = read_events(folder / "events.jsonl").events
    t4_s = np.array([e.t_ns for e in events if isinstance(e, Step)]) / 1e9
    t3_s = np.array([e.t_ns for e in events if isinstance(e, Scan) and e.index is not None]) / 1e9
    assert len(t4_s) == len(t4)
    assert len(t3_s) == len(t3)
    return estimate_latency(
        t4_s=t4_s,
        control_pitch_counts=t4["ControlPitch"].astype(float),
        control_roll_counts=t4["ControlRoll"].astype(float),
        angle_pitch_rad=t4["AnglePitch"].astype(float),
        angle_roll_rad=t4["AngleRoll"].astype(float),
        t3_s=t3_s,
        b_vel_x_mps=t3["B_Vel.x"].astype(float),
        b_vel_y_mps=t3["B_Vel.y"].astype(float),
    )


@pytest.mark.parametrize(("delay_s", "tau_s"), [(0.05, 0.1), (0.1, 0.1), (0.2, 0.1), (0.3, 0.05)])
def test_sim_flight_recovers_the_vehicles_known_lag(
    tmp_path: Path, delay_s: float, tau_s: float
) -> None:
    """Issue 7: a simulated vehicle whose attitude delay d and lag τ are known, flown with a
    set-point square wave: the response lag is d + τ within one 50 ms step."""
    cfg = load_config(
        None, [f"sim.vehicle.attitude_delay_s={delay_s}", f"sim.vehicle.attitude_tau_s={tau_s}"]
    )
    result = run_hover(cfg, duration_s=60, seed=4, log_dir=tmp_path, excite_m=0.2)
    assert result.landed
    lat = _sim_latency(tmp_path)
    assert abs(lat.lag_s - (delay_s + tau_s)) <= 0.05
    assert lat.peak_r > WEAK_PEAK_R
    assert lat.attitude is not None
    assert abs(lat.attitude.lag_fine_steps * lat.period_s - (delay_s + tau_s)) <= 0.05


def test_calm_hover_is_weak(tmp_path: Path) -> None:
    """Without excitation the closed loop barely moves: the peak is flagged as weak."""
    run_hover(Config(), duration_s=20, seed=2, log_dir=tmp_path)
    lat = _sim_latency(tmp_path)
    assert 0 <= lat.lag_steps <= 20
    assert len(lat.acceleration.curve) == 21
    assert lat.peak_r < 0.5
