"""The command-to-velocity lag (seed §F, Fig 8): synthetic known lags and a sim flight."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mkflight.analysis.latency import (
    estimate_latency,
    lagged_correlation,
    peak_lag,
    resample_nearest,
)
from mkflight.analysis.precision import AnalysisInputError
from mkflight.config import Config
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


def test_recovers_lag_through_tables_within_one_step() -> None:
    """TABLE IV commands and TABLE III velocities (100 ms, resampled): lag 4 ± 1 step."""
    n4, k = 800, 4
    cmd = _command(n4, seed=3)
    rng = np.random.default_rng(7)
    index4 = np.arange(1, n4 + 1, dtype=np.float64)  # t = index x 50 ms
    vel_at_50 = np.full(n4, np.nan)
    vel_at_50[k:] = cmd[:-k] * 0.01  # velocity x follows +ControlPitch k steps later
    index3 = np.arange(1, n4 // 2 + 1, dtype=np.float64)  # t = (index - 1) x 100 ms
    vx = vel_at_50[np.clip((index3 - 1).astype(int) * 2 - 1, 0, n4 - 1)]
    vx = vx + rng.normal(0, 0.02, len(vx))
    lat = estimate_latency(
        index4=index4,
        control_pitch_counts=cmd,
        control_roll_counts=np.zeros(n4),
        index3=index3,
        b_vel_x_mps=vx,
        b_vel_y_mps=np.zeros(len(index3)),
    )
    assert abs(lat.lag_steps - k) <= 1
    assert lat.lag_x_steps is not None
    assert abs(lat.lag_x_steps - k) <= 1
    assert lat.lag_y_steps is None  # no variance on y
    assert lat.lag_s == pytest.approx(lat.lag_steps * 0.05)


def test_roll_sign_is_negated() -> None:
    """Roll: the y velocity follows -ControlRoll (SPEC §1): a positive peak."""
    n = 400
    cmd = _command(n, seed=5)
    vy = np.full(n, np.nan)
    vy[2:] = -cmd[:-2] * 0.01
    lat = estimate_latency(
        index4=np.arange(1, n + 1, dtype=np.float64),
        control_pitch_counts=np.zeros(n),
        control_roll_counts=cmd,
        index3=np.arange(1, n + 1, dtype=np.float64) * 0.5 + 1.0,  # t = index4 x 50 ms
        b_vel_x_mps=np.zeros(n),
        b_vel_y_mps=vy,
    )
    assert lat.lag_steps == 2
    assert lat.peak_r > 0.9


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


def test_sim_hover_gives_a_finite_lag(tmp_path: Path) -> None:
    """A real simulated flight: a lag in 0..20 (a calm hover has little excitation)."""
    run_hover(Config(), duration_s=12, seed=2, log_dir=tmp_path)
    t4 = read_table4(tmp_path / "imu_50ms.log").rows
    t3 = read_table3(tmp_path / "laser_100ms.log").rows
    lat = estimate_latency(
        index4=t4["index"].astype(float),
        control_pitch_counts=t4["ControlPitch"].astype(float),
        control_roll_counts=t4["ControlRoll"].astype(float),
        index3=t3["index"].astype(float),
        b_vel_x_mps=t3["B_Vel.x"].astype(float),
        b_vel_y_mps=t3["B_Vel.y"].astype(float),
    )
    assert 0 <= lat.lag_steps <= 20
    assert math.isfinite(lat.lag_s)
    assert len(lat.curve) == 21
    assert math.isfinite(lat.peak_r)
