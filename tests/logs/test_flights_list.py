"""``mkflight flights``: a folder of flights listed, and its ``--json`` loaded by pandas."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from mkflight.analysis.precision import hold_samples, parse_truth, precision, with_truth
from mkflight.logs import read_events
from mkflight.logs.flight_list import FIELDS
from tests.flights import HOVER_SIM_8S

pytestmark = pytest.mark.background(HOVER_SIM_8S)

MKFLIGHT = [sys.executable, "-m", "mkflight"]


def approx(value: float) -> Any:
    """pandas parses JSON floats to within an ulp or so (its fast parser)."""
    return pytest.approx(value, rel=1e-12, abs=0)


def _edit_flight_json(folder: Path, summary: dict[str, Any] | None, **top: Any) -> None:
    """Change ``flight.json``: summary fields (None: no summary, a killed flight), top keys."""
    path = folder / "flight.json"
    info = json.loads(path.read_text())
    info["summary"] = None if summary is None else info["summary"] | summary
    path.write_text(json.dumps(info | top))


@pytest.fixture(scope="module")
def lab(sim_flight: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A lab's flights folder: flown, edited copies, a killed one, a sim hover, and clutter."""
    base = tmp_path_factory.mktemp("lab")
    shutil.copytree(sim_flight, base / "0003-20261126-1057")
    failed = base / "0010-20261126-1130"
    shutil.copytree(sim_flight, failed, ignore=shutil.ignore_patterns("truth.txt"))
    _edit_flight_json(
        failed,
        mkflight_version="0.0.9",
        summary={
            "end_reason": "failsafe: t+5.00s LAND laser_stale",
            "exit_code": 1,
            "duration_s": 33.25,
            "failsafes": [
                "t+5.00s LAND laser_stale",
                "t+6.10s WARN battery_low",
                "t+7.00s LAND laser_stale",
                "t+9.00s LAND stop_sigterm",
            ],
            "precision_estimate": {"std_x_m": 0.02, "std_y_m": 0.03, "std_z_m": 0.01, "samples": 9},
        },
    )
    killed = base / "0011-20261126-1200"
    shutil.copytree(sim_flight, killed)
    _edit_flight_json(killed, None)
    events = (killed / "events.jsonl").read_bytes()
    (killed / "events.jsonl").write_bytes(events[: len(events) // 2])  # cut mid-line
    hover = base / "0012-20261126-1300"
    proc = subprocess.run(
        [*MKFLIGHT, "sim", "hover", "--duration", "15", "--log-dir", str(hover)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    old = base / "flight-20261120-101010"  # an older name, tables only (no flight.json)
    old.mkdir()
    shutil.copy(sim_flight / "imu_50ms.log", old)
    broken = base / "0004-20261126-1100"
    broken.mkdir()
    (broken / "flight.json").write_text("{not json")
    (base / "notes").mkdir()
    (base / "notes" / "todo.txt").write_text("calibrate")
    (base / "latest").symlink_to("0012-20261126-1300")
    (base / ".lock").write_text("")
    return base


def _run(*args: str) -> str:
    proc = subprocess.run(
        [*MKFLIGHT, "flights", *args], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith("config: built-in defaults")  # the one line of a config user
    assert proc.stderr.count("\n") == 1
    return proc.stdout


def _truth_std(folder: Path) -> list[float]:
    samples = hold_samples(read_events(folder / "events.jsonl").events)
    truth = parse_truth((folder / "truth.txt").read_text(), "truth.txt")
    p = precision(with_truth(samples, truth), "truth")
    return [p.x.std_m, p.y.std_m, p.z.std_m]


def test_json_loads_into_pandas_with_each_flights_figures(lab: Path, sim_flight: Path) -> None:
    df = pd.read_json(io.StringIO(_run(str(lab), "--json")))  # as a user would
    assert list(df.columns) == list(FIELDS)
    assert list(df["folder"]) == [
        "flight-20261120-101010",
        "0003-20261126-1057",
        "0004-20261126-1100",
        "0010-20261126-1130",
        "0011-20261126-1200",
        "0012-20261126-1300",
    ]
    for column in ("duration_s", "flight_s", "est_std_x_m", "truth_std_z_m", "exit_code"):
        assert pd.api.types.is_numeric_dtype(df[column]), column
    assert list(df["status"]) == [
        "no flight.json",
        "ended",
        "unreadable",
        "ended",
        "no summary",
        "ended",
    ]
    rows = df.set_index("folder")
    flown = json.loads((sim_flight / "flight.json").read_text())
    s = flown["summary"]
    row = rows.loc["0003-20261126-1057"]
    assert row["number"] == 3
    assert row["kind"] == "fly"
    assert row["start_utc"] == flown["start_utc"]
    assert row["duration_s"] == approx(s["duration_s"])
    assert row["flight_s"] == approx(s["flight_s"])
    assert row["end_reason"] == s["end_reason"]
    assert row["exit_code"] == s["exit_code"]
    assert row["final_phase"] == s["final_phase"]
    assert bool(row["released"]) is s["released"]
    assert row["est_std_x_m"] == approx(s["precision_estimate"]["std_x_m"])
    assert row["est_std_z_m"] == approx(s["precision_estimate"]["std_z_m"])
    truth = _truth_std(sim_flight)
    assert [row["truth_std_x_m"], row["truth_std_y_m"], row["truth_std_z_m"]] == pytest.approx(
        truth, abs=1e-6
    )
    unplanned = [d for d in s["failsafes"] if not d.split()[-1].startswith("stop_")]
    assert row["failsafe_count"] == len(unplanned)  # the --duration stop is planned, not counted
    assert row["mkflight_version"] == flown["mkflight_version"]
    assert row["fc_version"] == flown["fc_version"]
    failed = rows.loc["0010-20261126-1130"]
    assert failed["exit_code"] == 1
    assert failed["duration_s"] == approx(33.25)
    assert failed["end_reason"] == "failsafe: t+5.00s LAND laser_stale"
    assert failed["est_std_y_m"] == approx(0.03)
    assert pd.isna(failed["truth_std_x_m"])  # no truth.txt
    assert failed["failsafe_count"] == 3  # the planned stop_sigterm left out
    assert failed["failsafe_kinds"] == "LAND laser_stale; WARN battery_low"
    assert failed["mkflight_version"] == "0.0.9"
    killed = rows.loc["0011-20261126-1200"]
    assert pd.isna(killed["end_reason"])
    assert pd.isna(killed["exit_code"])
    events = read_events(lab / "0011-20261126-1200" / "events.jsonl").events
    assert killed["duration_s"] == pytest.approx((events[-1].t_ns - events[0].t_ns) / 1e9)
    hover = rows.loc["0012-20261126-1300"]
    hs = json.loads((lab / "0012-20261126-1300" / "flight.json").read_text())["summary"]
    assert hover["kind"] == "sim hover"
    assert hover["duration_s"] == approx(hs["sim_s"])
    assert hover["end_reason"] == hs["end"]
    assert hover["truth_std_y_m"] == approx(hs["std_y_m"])
    assert pd.isna(hover["est_std_x_m"])
    assert "flight.json" in rows.loc["0004-20261126-1100"]["error"]
    assert pd.isna(rows.loc["flight-20261120-101010"]["number"])


def test_text_is_aligned_columns(lab: Path, sim_flight: Path) -> None:
    lines = _run(str(lab)).splitlines()
    assert lines[0].split()[:3] == ["flight", "start", "(UTC)"]
    assert len(lines) == 7  # the header and six flights: no notes, latest, .lock
    start = lines[0].index("start")
    assert {line[start - 2 : start] for line in lines} == {"  "}
    assert all(line[start : start + 4] in ("star", "2026", "-   ") for line in lines)
    killed = next(line for line in lines if line.startswith("0011-"))
    assert "no summary" in killed
    failed = next(line for line in lines if line.startswith("0010-"))
    assert failed.endswith("3: LAND laser_stale; WARN battery_low")
    assert "0.0200 0.0300 0.0100 e" in failed
    flown = next(line for line in lines if line.startswith("0003-"))
    truth = " ".join(f"{v:.4f}" for v in _truth_std(sim_flight)) + " t"
    assert truth in flown


def test_the_default_dir_is_logging_dir_and_a_missing_one_is_an_error(
    lab: Path, tmp_path: Path
) -> None:
    out = _run("--json", "--set", f"logging.dir={lab}")
    assert len(json.loads(out)) == 6
    proc = subprocess.run(
        [*MKFLIGHT, "flights", str(tmp_path / "none")], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 1
    assert proc.stderr.splitlines() == [
        "config: built-in defaults",
        f"error: {tmp_path / 'none'}: no such folder of flights",
    ]
    (tmp_path / "empty").mkdir()
    assert _run(str(tmp_path / "empty")).strip() == f"no flight folders in {tmp_path / 'empty'}"
    assert _run(str(tmp_path / "empty"), "--json").strip() == "[]"
