"""The table writers' row formatter writes format_row's bytes and raises its errors."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.logs import _table, table3, table4
from mkflight.logs._table import RowFormatter, format_row


def _outcome(fmt: _table.TableFormat, values: tuple[Any, ...], formatter: Any) -> tuple[str, str]:
    try:
        return "line", formatter(fmt, values) if formatter is format_row else formatter(values)
    except (TypeError, ValueError, OverflowError) as err:
        return type(err).__name__, str(err)


# the numbers a flight writes (scaled counts, NaN, both zeros, inf) in the types it may use
_FLOATS = [0.0, -0.0, math.nan, math.inf, -math.inf, 0.1, -2.5e-05, 1e300, 9.81 / 3]
_NUMBERS = st.one_of(
    st.sampled_from(_FLOATS),
    st.integers(-300, 300).map(lambda c: c * 0.0174532925),  # an MK angle count, scaled
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.booleans(),
    st.integers(-3, 3).map(float),  # an integral float (an int column accepts it)
    st.sampled_from(_FLOATS).map(np.float64),
    st.integers(-3, 3).map(np.int64),
    st.sampled_from([v for v in _FLOATS if v != 1e300]).map(np.float32),  # no overflow
)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(_NUMBERS, min_size=14, max_size=14), min_size=1, max_size=20))
def test_table4_rows_are_format_rows_bytes_and_errors(rows: list[list[Any]]) -> None:
    formatter = RowFormatter(table4.FORMAT)  # caches fill as the rows go
    for row in rows + rows:  # the second time round, from the caches
        values = tuple(row)
        assert _outcome(table4.FORMAT, values, formatter) == _outcome(
            table4.FORMAT, values, format_row
        )


@settings(max_examples=100, deadline=None)
@given(st.lists(st.lists(_NUMBERS, min_size=10, max_size=10), min_size=1, max_size=10))
def test_table3_rows_are_format_rows_bytes_and_errors(rows: list[list[Any]]) -> None:
    formatter = RowFormatter(table3.FORMAT)
    for values in map(tuple, rows):
        assert _outcome(table3.FORMAT, values, formatter) == _outcome(
            table3.FORMAT, values, format_row
        )


def test_zeros_and_nan_keep_their_own_text_after_a_cached_value() -> None:
    formatter = RowFormatter(table4.FORMAT)
    for first, second in ((0.0, -0.0), (-0.0, 0.0), (math.nan, math.nan)):
        for value in (first, second, first):
            row = (value,) * 6 + (0,) * 7 + (1,)
            assert formatter(row) == format_row(table4.FORMAT, row)
    assert formatter((-0.0,) * 6 + (0,) * 7 + (2,)).startswith("-0.0 -0.0 ")


def test_caches_start_again_when_full_and_stay_exact(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_table, "TEXT_CACHE_SIZE", 16)
    formatter = RowFormatter(table4.FORMAT)
    for i in range(200):
        angles = (i * 0.001, -i * 0.002, 0.0)
        row = (*angles, i % 7 * 0.1, 1.5, -9.81, i % 40 - 20, 0, 0, 0, 0, 0, i, i)
        assert formatter(row) == format_row(table4.FORMAT, row)
    floats_cache = formatter._caches[0]  # type: ignore[index]
    assert 0 < len(floats_cache) <= 16


def test_wrong_length_and_fractional_count_raise_format_rows_errors() -> None:
    formatter = RowFormatter(table4.FORMAT)
    with pytest.raises(ValueError, match="expected 14 values, got 3"):
        formatter((1.0, 2.0, 3))
    row = (0.0,) * 6 + (2.5,) + (0,) * 6 + (1,)
    with pytest.raises(ValueError, match=r"ControlPitch must be an integer, got 2\.5"):
        formatter(row)
