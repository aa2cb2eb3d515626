from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.errors import ReplayError
from mkflight.logs.table3 import COLUMNS, FILE_NAME, Table3Row, Table3Writer, read_table3, rows_of

HEADER = (
    "W_Vel.x B_Vel.x B_esti_Vel.x W_Vel.y B_Vel.y B_esti_Vel.y "
    "CurrentPosition.x CurrentPosition.y CurrentPosition.theta index"
)


def _row(i: int, v: float = 0.5) -> Table3Row:
    return Table3Row(v, -v, 0.1 * i, 1e-7, -2.5e-5, 3.0, 0.25 * i, -1.0, math.pi, i)


def _from(*v: float, index: int) -> Table3Row:
    return Table3Row(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], index)


def _write(folder: Path, rows: list[Table3Row]) -> Path:
    with Table3Writer(folder) as w:
        for r in rows:
            w.write_row(r)
    return folder / FILE_NAME


def test_header_is_exactly_the_ten_seed_names(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0)])
    assert path.read_text().splitlines()[0] == HEADER
    assert len(COLUMNS) == 10


def test_round_trip_and_loadtxt_reads_ten_columns(tmp_path: Path) -> None:
    rows = [_row(i) for i in range(5)]
    path = _write(tmp_path, rows)
    data = read_table3(path)
    assert not data.truncated
    assert rows_of(data) == rows
    assert data.rows["index"].tolist() == [0, 1, 2, 3, 4]
    table = np.loadtxt(path, skiprows=1)
    assert table.shape == (5, 10)
    assert table[:, 9].tolist() == [0, 1, 2, 3, 4]
    assert table[2, 6] == 0.5


def test_nan_is_written_as_nan_and_loadtxt_reads_it(tmp_path: Path) -> None:
    path = _write(tmp_path, [_from(*([math.nan] * 9), index=7)])
    assert path.read_text().splitlines()[1].startswith("nan nan ")
    assert np.isnan(np.loadtxt(path, skiprows=1, ndmin=2)[0, :9]).all()
    assert np.isnan(read_table3(path).rows["W_Vel.x"][0])


def test_each_row_is_flushed_as_written(tmp_path: Path) -> None:
    w = Table3Writer(tmp_path)
    w.write_row(_row(1))
    assert len((tmp_path / FILE_NAME).read_text().splitlines()) == 2  # before close
    w.close()
    w.close()  # idempotent


def test_writer_rejects_a_non_increasing_index(tmp_path: Path) -> None:
    with Table3Writer(tmp_path) as w:
        w.write_row(_row(3))
        with pytest.raises(ValueError, match="index 3 not above the previous 3"):
            w.write_row(_row(3))


def test_writer_never_overwrites_a_log(tmp_path: Path) -> None:
    _write(tmp_path, [])
    with pytest.raises(FileExistsError):
        Table3Writer(tmp_path)


def test_truncated_last_line_reads_complete_rows_with_flag(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0), _row(1)])
    with path.open("a") as f:
        f.write("0.1 0.2 0.")  # the process was killed mid-row
    data = read_table3(path)
    assert data.truncated
    assert data.rows["index"].tolist() == [0, 1]


def test_malformed_row_names_file_and_line(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0), _row(1)])
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace("-1.0", "x1.0")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ReplayError, match=rf"{FILE_NAME}:3: column CurrentPosition.y"):
        read_table3(path)


def test_wrong_column_count_names_file_and_line(tmp_path: Path) -> None:
    path = _write(tmp_path, [_row(0)])
    with path.open("a") as f:
        f.write("1 2 3\n")
    with pytest.raises(ReplayError, match=rf"{FILE_NAME}:3: expected 10 columns, got 3"):
        read_table3(path)


def test_wrong_header_and_decreasing_index_are_errors(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_text("a b c\n")
    with pytest.raises(ReplayError, match=":1: expected the header"):
        read_table3(path)
    path.write_text(HEADER + "\n" + "0 " * 9 + "5\n" + "0 " * 9 + "4\n")
    with pytest.raises(ReplayError, match=":3: index 4 not above the previous 5"):
        read_table3(path)


finite_or_not = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.lists(finite_or_not, min_size=9, max_size=9), min_size=1, max_size=5))
def test_round_trip_is_exact_for_any_float(
    tmp_path_factory: pytest.TempPathFactory, values: list[list[float]]
) -> None:
    folder = tmp_path_factory.mktemp("flight")
    rows = [_from(*v, index=i) for i, v in enumerate(values)]
    data = read_table3(_write(folder, rows))
    got = np.array([list(r)[:9] for r in data.rows.tolist()], dtype=float)
    np.testing.assert_array_equal(got, np.array(values, dtype=float))
