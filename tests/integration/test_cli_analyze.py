"""``mkflight analyze precision|latency`` end to end on a simulated flight folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mkflight.analysis.latency import WEAK_PEAK_R
from mkflight.config import Config
from mkflight.sim.hover import run_hover

MKFLIGHT = [sys.executable, "-m", "mkflight"]


def run_cli(*args: str) -> tuple[int, str, str]:
    """Run ``python -m mkflight ARGS``; return (exit code, stdout, stderr)."""
    proc = subprocess.run(
        [*MKFLIGHT, *args], capture_output=True, text=True, timeout=60, check=False
    )
    return proc.returncode, proc.stdout, proc.stderr


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("flight")
    run_hover(Config(), duration_s=12, seed=2, log_dir=folder)
    return folder


def test_precision_table_and_json(flight: Path) -> None:
    code, out, err = run_cli(
        "analyze", "precision", str(flight), "--truth", str(flight / "truth.txt")
    )
    assert code == 0, err
    assert "position = truth" in out
    assert "GRASP" in out
    assert "0.0849" in out
    assert "QUT" in out
    code, out, err = run_cli("analyze", "precision", str(flight), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["source"] == "estimate"
    for stat in ("mean", "std", "rms", "max"):
        for axis in "xyz":
            assert f"{stat}_{axis}_m" in d
    assert d["samples"] > 0


def test_latency_json(flight: Path) -> None:
    """A calm hover: a lag, its curves, and the weak-peak warning when its peak is weak
    (a calm hover hardly excites the response: r near the threshold either way)."""
    code, out, err = run_cli("analyze", "latency", str(flight), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert 0 <= d["lag_steps"] <= 20
    for name in ("acceleration", "attitude", "velocity"):
        assert len(d[name]["curve"]) == 21
    assert d["lag_s"] == pytest.approx(d["acceleration"]["lag_s"])
    code, out, err = run_cli("analyze", "latency", str(flight))
    assert code == 0, err
    assert "<- peak" in out
    assert ("weak peak" in out) == (d["peak_r"] < WEAK_PEAK_R)


def test_excited_sim_flight_latency_is_the_vehicles(tmp_path: Path) -> None:
    """Issue 7 through the CLI: 'sim hover --excite' then 'analyze latency' reads the default
    vehicle's 0.1 s attitude delay + 0.1 s lag within one 50 ms step."""
    folder = tmp_path / "f"
    code, _, err = run_cli(
        "sim", "hover", "--duration", "40", "--excite", "0.2", "--seed", "5",
        "--log-dir", str(folder), "--json",
    )  # fmt: skip
    assert code == 0, err
    code, out, err = run_cli("analyze", "latency", str(folder), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert abs(d["lag_s"] - 0.2) <= 0.05
    assert d["peak_r"] > 0.3
    assert abs(d["attitude"]["lag_s"] - 0.2) <= 0.05
    code, _, err = run_cli("sim", "hover", "--excite", "nan", "--log-dir", str(tmp_path / "g"))
    assert code == 2
    assert "--excite" in err


def test_missing_and_empty_files(tmp_path: Path) -> None:
    code, _, err = run_cli("analyze", "precision", str(tmp_path / "nope"))
    assert code == 1
    assert err.startswith("error: ")
    assert "nope" in err
    assert "Traceback" not in err
    (tmp_path / "events.jsonl").write_text("")
    code, _, err = run_cli("analyze", "precision", str(tmp_path))
    assert code == 1
    assert "events.jsonl: empty log" in err
    code, _, err = run_cli("analyze", "latency", str(tmp_path))
    assert code == 1
    assert "imu_50ms.log: missing" in err


def test_malformed_truth_row_names_file_and_line(flight: Path, tmp_path: Path) -> None:
    bad = tmp_path / "truth.txt"
    bad.write_text("t x y z\n0.1 0 0 0.5\n0.2 0 zero 0.5\n")
    code, _, err = run_cli("analyze", "precision", str(flight), "--truth", str(bad))
    assert code == 1
    assert f"{bad}:3:" in err
    code, _, err = run_cli("analyze", "precision", str(flight), "--truth", str(tmp_path / "x"))
    assert code == 1
    assert "no such truth file" in err
