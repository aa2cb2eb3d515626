from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mkflight.errors import ReplayError
from mkflight.logs.table4 import COLUMNS, FILE_NAME, Table4Row, Table4Writer, read_table4, rows_of

HEADER = (
    "AnglePitch AngleRoll AngleYaw AccX AccY AccZ ControlPitch ControlRoll ControlYaw "
    "StickPitch StickRoll StickYaw StickThrust index"
)


def _row(i: int) -> Table4Row:
    return Table4Row(0.01 * i, -0.02, 3.1, 0.118, -0.04, -9.79, -3, 1, -127, 0, 5, -2, 200, i)


def _write(folder: Path, rows: list[Table4Row]) -> Path:
    with Table4Writer(folder) as w:
        for r in rows:
            w.write_row(r)
    return folder / FILE_NAME


def test_header_is_exactly_the_fourteen_seed_names(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0)])
    assert path.read_text().splitlines()[0] == HEADER
    assert len(COLUMNS) == 14


def test_round_trip_and_loadtxt_reads_fourteen_columns(tmp_path: Path) -> None:
    rows = [_row(i) for i in range(4)]
    path = _write(tmp_path, rows)
    data = read_table4(path)
    assert rows_of(data) == rows
    assert data.rows.dtype["ControlPitch"] == np.int64
    assert data.rows.dtype["AccX"] == np.float64
    table = np.loadtxt(path, skiprows=1)
    assert table.shape == (4, 14)
    assert table[1].tolist() == [
        0.01,
        -0.02,
        3.1,
        0.118,
        -0.04,
        -9.79,
        -3,
        1,
        -127,
        0,
        5,
        -2,
        200,
        1,
    ]


def test_counts_are_written_as_integers(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0)])
    assert path.read_text().splitlines()[1].endswith(" -3 1 -127 0 5 -2 200 0")


def test_writer_rejects_a_fractional_count(tmp_path: Path) -> None:
    bad = Table4Row(0, 0, 0, 0, 0, 0, 1.5, 0, 0, 0, 0, 0, 0, 0)  # type: ignore[arg-type]
    with (
        Table4Writer(tmp_path) as w,
        pytest.raises(ValueError, match="ControlPitch must be an integer"),
    ):
        w.write_row(bad)


def test_nan_angles_round_trip(tmp_path: Path) -> None:
    row = Table4Row(math.nan, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 9)
    data = read_table4(_write(tmp_path, [row]))
    assert math.isnan(data.rows["AnglePitch"][0])


def test_reader_accepts_integral_floats_in_count_columns(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_text(HEADER + "\n" + "0.0 " * 6 + "3.0 " * 7 + "1\n")
    assert rows_of(read_table4(path))[0].control_pitch_counts == 3


def test_truncated_last_line_and_malformed_count(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0), _row(1)])
    with path.open("a") as f:
        f.write("0.1 0.2")
    data = read_table4(path)
    assert data.truncated
    assert len(data.rows) == 2
    path.write_text(HEADER + "\n" + "0 " * 6 + "2.5 " + "0 " * 6 + "1\n")
    with pytest.raises(
        ReplayError, match=rf"{FILE_NAME}:2: column ControlPitch: cannot parse '2.5'"
    ):
        read_table4(path)
