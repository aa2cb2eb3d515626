"""``mkflight calibrate acc`` and ``mkflight flight-time`` end to end (the real CLI process)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from mkflight.config import load_config
from tests.analysis.seed_tables import TABLE_I_RUNS, TABLE_II_RUNS, as_text
from tests.integration.test_cli_mk_info import error_lines, run_cli


@pytest.fixture
def table_i(tmp_path: Path) -> Path:
    path = tmp_path / "table1.csv"
    path.write_text("# seed TABLE I, three runs\n" + as_text(TABLE_I_RUNS, sep=","))
    return path


@pytest.fixture
def table_ii(tmp_path: Path) -> Path:
    path = tmp_path / "table2.txt"
    path.write_text(as_text(TABLE_II_RUNS, sep="\t", header=False))
    return path


async def test_calibrate_json_has_exactly_the_keys(table_i: Path, table_ii: Path) -> None:
    code, out, err, _ = await run_cli("calibrate", "acc", str(table_i), "--json")
    assert code == 0, err
    result = json.loads(out)
    assert set(result) == {"k_counts_per_g", "residual_rms_counts", "rows"}
    assert round(result["k_counts_per_g"], 1) == 606.3
    assert result["rows"] == 33
    code, out, err, _ = await run_cli("calibrate", "acc", str(table_ii), "--axis", "roll", "--json")
    assert code == 0, err
    assert round(json.loads(out)["k_counts_per_g"], 2) == 603.44


async def test_calibrate_text_shows_k_residual_and_each_row(table_i: Path) -> None:
    code, out, err, _ = await run_cli("calibrate", "acc", str(table_i))
    assert code == 0, err
    lines = out.splitlines()
    assert "k = 606.315 counts/g" in lines[0]
    assert "residual RMS 11.60 counts over 33 rows" in lines[1]
    assert len(lines) == 3 + 33
    assert lines[3].split() == ["3", "-90.00", "602.00", "606.32", "-4.32"]


async def test_calibrate_writes_the_config_keeping_other_keys(
    table_ii: Path, tmp_path: Path
) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("# a comment\nmk:\n  port: /dev/ttyUSB7\ncontrol:\n  kp_xy: 1.5\n")
    code, out, err, _ = await run_cli(
        "calibrate", "acc", str(table_ii), "--axis", "roll", "--write-config", str(cfg)
    )
    assert code == 0, err
    assert f"wrote mk.acc_roll_counts_per_g = 603.439 to {cfg}" in out
    data = yaml.safe_load(cfg.read_text())
    assert data == {
        "mk": {"port": "/dev/ttyUSB7", "acc_roll_counts_per_g": 603.439},
        "control": {"kp_xy": 1.5},
    }
    loaded = load_config(cfg)
    assert loaded.mk.acc_roll_counts_per_g == 603.439
    assert loaded.mk.acc_nick_counts_per_g == 606.3
    assert [name for name in os.listdir(tmp_path) if name.startswith(".")] == []


async def test_calibrate_refuses_an_invalid_config(table_i: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "cfg.yaml"
    original = "mk:\n  no_such_key: 1\n"
    cfg.write_text(original)
    code, _, err, _ = await run_cli(
        "calibrate", "acc", str(table_i), "--write-config", str(cfg), "--json"
    )
    assert code == 2
    assert error_lines(err) == [f"error: {cfg}: mk.no_such_key: unknown key"]
    assert cfg.read_text() == original


async def test_calibrate_malformed_row_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("angle_deg,counts\n-90,602\n-60,5x2\n")
    code, out, err, _ = await run_cli("calibrate", "acc", str(path))
    assert code == 1
    assert out == ""
    (line,) = error_lines(err)
    assert line.startswith(f"error: {path}:3: malformed row '-60,5x2'")
    assert "Traceback" not in err


async def test_calibrate_empty_and_missing_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    code, _, err, _ = await run_cli("calibrate", "acc", str(empty))
    assert code == 1
    assert error_lines(err) == [
        f"error: {empty}: no data rows (expected lines of 'angle_deg counts')"
    ]
    missing = tmp_path / "missing.txt"
    code, _, err, _ = await run_cli("calibrate", "acc", str(missing))
    assert code == 1
    assert error_lines(err) == [
        f"error: {missing}: cannot read calibration table: No such file or directory"
    ]


async def test_flight_time_json_seed_numbers() -> None:
    code, out, err, _ = await run_cli(
        "flight-time", "--capacity-ah", "2.2", "--current-a", "6.8", "--mass-g", "1040", "--json"
    )
    assert code == 0, err
    result = json.loads(out)
    assert set(result) == {"ideal_min", "derated_min", "thrust_per_motor_g"}
    assert round(result["ideal_min"], 1) == 19.4
    assert round(result["derated_min"], 2) == 17.47
    assert result["thrust_per_motor_g"] == 260
    code, out, err, _ = await run_cli(
        "flight-time", "--capacity-ah", "2.2", "--current-a", "6.8", "--extra-current-a", "0.5"
    )
    assert code == 0, err
    assert "derated   16.27 min" in out
    code, out, _, _ = await run_cli("flight-time", "--capacity-ah", "2.2", "--current-a", "6.8")
    assert "thrust" not in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--capacity-ah", "0", "--current-a", "6.8"], "argument --capacity-ah: must be"),
        (["--capacity-ah", "2.2", "--current-a", "-1"], "argument --current-a: must be"),
        (["--capacity-ah", "2.2", "--current-a", "nan"], "argument --current-a: must be"),
        (["--capacity-ah", "x", "--current-a", "6.8"], "argument --capacity-ah: expected a"),
        (["--capacity-ah", "2.2", "--current-a", "6.8", "--usable", "1.5"], "(0, 1]"),
        (["--capacity-ah", "2.2", "--current-a", "6.8", "--usable", "0"], "--usable"),
        (["--capacity-ah", "2.2", "--current-a", "6.8", "--mass-g", "-5"], "--mass-g"),
        (["--capacity-ah", "2.2", "--current-a", "6.8", "--extra-current-a", "-1"], ">= 0"),
        (["--current-a", "6.8"], "--capacity-ah"),
    ],
)
async def test_flight_time_bad_values_are_usage_errors(args: list[str], message: str) -> None:
    code, out, err, _ = await run_cli("flight-time", *args)
    assert code == 2
    assert out == ""
    (line,) = error_lines(err)
    assert message in line


async def test_calibrate_bad_axis_is_a_usage_error(table_i: Path) -> None:
    code, _, err, _ = await run_cli("calibrate", "acc", str(table_i), "--axis", "yaw")
    assert code == 2
    assert len(error_lines(err)) == 1


def test_write_config_creates_a_missing_file(
    table_i: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mkflight.commands.calibrate import cmd_calibrate_acc

    cfg = tmp_path / "new.yaml"
    assert (
        cmd_calibrate_acc(file=str(table_i), axis="nick", as_json=True, write_config=str(cfg)) == 0
    )
    assert yaml.safe_load(cfg.read_text()) == {"mk": {"acc_nick_counts_per_g": 606.315}}
    assert set(json.loads(capsys.readouterr().out)) == {
        "k_counts_per_g",
        "residual_rms_counts",
        "rows",
    }
