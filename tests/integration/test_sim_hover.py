"""``mkflight sim hover``: a short simulated flight takes off, holds, lands and logs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mkflight.config import Config
from mkflight.logs.flight_json import read_flight_json
from mkflight.sim.hover import run_hover

from .test_cli_mk_info import error_lines, run_cli


def test_a_short_flight_lands_and_leaves_readable_tables(tmp_path: Path) -> None:
    result = run_hover(Config(), duration_s=15.0, seed=3, log_dir=tmp_path / "f")
    assert result.landed
    assert result.hold_s > 5.0
    # Loose bounds: this checks the loop holds the vehicle, not the tuning targets.
    assert result.rms_x_m < 0.2
    assert result.rms_y_m < 0.2
    assert result.rms_z_m < 0.1
    assert result.realtime_factor > 10  # lock-step, far faster than real time
    t3 = np.loadtxt(tmp_path / "f" / "laser_100ms.log", skiprows=1)
    t4 = np.loadtxt(tmp_path / "f" / "imu_50ms.log", skiprows=1)
    assert t3.shape[1] == 10
    assert t4.shape[1] == 14
    assert len(t4) == pytest.approx(2 * len(t3), rel=0.2)
    assert np.all(np.abs(t4[:, 6:9]) <= 127)  # commands within the MK's limits
    truth = np.loadtxt(tmp_path / "f" / "truth.txt", skiprows=1)
    assert truth[:, 3].max() == pytest.approx(0.6, abs=0.15)  # flew at 0.6 m (overshoot: untuned)
    assert truth[-1, 3] < 0.05  # and landed
    info = read_flight_json(tmp_path / "f")
    assert info.summary is not None
    assert info.summary["landed"] is True


async def test_cli_json_and_the_same_seed_gives_the_same_flight(tmp_path: Path) -> None:
    runs = []
    for name in ("a", "b"):
        code, out, err, _ = await run_cli(
            "sim",
            "hover",
            "--duration",
            "8",
            "--seed",
            "5",
            "--json",
            "--log-dir",
            str(tmp_path / name),
        )
        assert code == 0, err
        runs.append(json.loads(out))
    for key in ("std_x_m", "std_y_m", "std_z_m", "rms_x_m", "rms_y_m", "rms_z_m"):
        assert runs[0][key] == runs[1][key]
    assert {"realtime_factor", "log_dir"} <= set(runs[0])


async def test_a_used_log_dir_is_refused(tmp_path: Path) -> None:
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "laser_100ms.log").write_text("old")
    code, _, err, _ = await run_cli("sim", "hover", "--log-dir", str(tmp_path / "x"))
    assert code == 2
    (line,) = error_lines(err)
    assert "is not empty" in line
