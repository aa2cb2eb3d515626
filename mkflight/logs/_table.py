"""The text-table format of TABLE III and TABLE IV (SPEC §6).

Both tables are §E of the 2011 QUT CyPhy MikroKopter documentation.

One header line of column names separated by single spaces, then one row per line:
space-separated values, floats as Python's shortest round-trip ``repr`` (``0.1``,
``-2.5e-05``, ``nan``, ``inf``), integer columns as plain integers, the last column the
``index`` (strictly increasing). Every line ends with a newline; each row is written and
flushed in one go, so a killed process leaves every complete row readable and at most a
last line without its newline, which readers drop (``truncated=True``).
``numpy.loadtxt(f, skiprows=1)`` reads the files (it parses ``nan``/``inf``), and so does
MATLAB's ``importdata(f, ' ', 1)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from operator import call
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from mkflight.errors import ReplayError
from mkflight.logs._file import LineFile, read_bytes

Value = float | int
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
#: Numbers a column's text cache holds before it starts again (:class:`RowFormatter`).
TEXT_CACHE_SIZE: Final = 4096


@dataclass(frozen=True, slots=True)
class TableFormat:
    """A table's file name, column names and which columns hold integers (MK counts).

    ``repeating``: the float columns take few distinct values (scaled integer counts), so
    the writer remembers their texts (:class:`RowFormatter`).
    """

    file_name: str
    columns: tuple[str, ...]
    int_columns: frozenset[str]
    repeating: bool = False

    @property
    def header(self) -> str:
        """The first line of the file, without its newline."""
        return " ".join(self.columns)

    @property
    def dtype(self) -> np.dtype[np.void]:
        """The reader's structured dtype: one field per column, named as in the header."""
        return np.dtype(
            [(c, np.int64 if c in self.int_columns else np.float64) for c in self.columns]
        )


@dataclass(frozen=True, slots=True, eq=False)
class TableData:
    """What a reader returns: the rows as a structured array (fields named as the header).

    ``truncated`` is True when the last line had no newline (the writer was killed
    mid-row): that partial line is not in ``rows``.
    """

    path: Path
    rows: npt.NDArray[np.void]
    truncated: bool


def format_row(fmt: TableFormat, values: tuple[Value, ...]) -> str:
    """One row as a line (with its newline).

    Raises:
        ValueError: wrong number of values, or an integer column given a non-integral value.
    """
    if len(values) != len(fmt.columns):
        msg = f"{fmt.file_name}: expected {len(fmt.columns)} values, got {len(values)}"
        raise ValueError(msg)
    ints = fmt.int_columns
    fields = [
        _int_field(fmt, name, value) if name in ints else repr(float(value))
        for name, value in zip(fmt.columns, values, strict=True)
    ]
    return " ".join(fields) + "\n"


def _int_field(fmt: TableFormat, name: str, value: Value) -> str:
    """An integer column's text (a float must be integral)."""
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        msg = f"{fmt.file_name}: {name} must be an integer, got {value!r}"
        raise ValueError(msg)
    return str(int(value))


class RowFormatter:
    """:func:`format_row` of one table, in fewer steps; the same bytes, the same errors.

    A float's shortest round-trip ``repr`` costs about a microsecond, most of a row's time,
    and a row of Python steps per value costs as much again. So:

    * the columns are formatted by the types' own ``float.__repr__`` / ``int.__repr__``
      in one ``map`` (for a float, numpy's float64 included, that is ``repr(float(v))``;
      for an int or a bool ``str(int(v))``); a value of another type, such as an int in a
      float column or a numpy integer, makes the whole row go through :func:`format_row`;
    * with ``fmt.repeating`` (TABLE IV: the MK's integer counts scaled, a few hundred
      numbers in a flight), each column but the index keeps a dict from a number to its
      text (:data:`TEXT_CACHE_SIZE` at most, then it starts again). A dict finds a key
      *equal* to the value, and equal numbers have one text, except ``0.0`` and ``-0.0``
      (equal) and NaN (equal to nothing): those are never cached.
    """

    __slots__ = ("_caches", "_fmt", "_int_flags", "_typed")

    def __init__(self, fmt: TableFormat) -> None:
        self._fmt = fmt
        self._int_flags = tuple(name in fmt.int_columns for name in fmt.columns)
        self._typed: tuple[Callable[[Value], str], ...] = tuple(
            int.__repr__ if is_int else float.__repr__ for is_int in self._int_flags
        )
        floats: dict[Value, str] = {}
        ints: dict[Value, str] = {}
        self._caches: tuple[dict[Value, str], ...] | None = (
            tuple(ints if is_int else floats for is_int in self._int_flags[:-1])
            if fmt.repeating
            else None
        )

    def __call__(self, values: tuple[Value, ...]) -> str:
        """The row as a line (with its newline), as :func:`format_row` gives it.

        Raises:
            ValueError: wrong number of values, or an integer column given a non-integral
                value.
        """
        if len(values) != len(self._typed):
            return format_row(self._fmt, values)  # raises
        try:
            if self._caches is None:
                return " ".join(map(call, self._typed, values)) + "\n"
            texts: list[str | None] = list(map(dict.get, self._caches, values))
            if None in texts:
                self._fill(self._caches, texts, values)
            texts.append(self._typed[-1](values[-1]))
            return " ".join(texts) + "\n"  # type: ignore[arg-type]  # no None left
        except TypeError:
            return format_row(self._fmt, values)  # another type, or raises its own error

    def _fill(
        self,
        caches: tuple[dict[Value, str], ...],
        texts: list[str | None],
        values: tuple[Value, ...],
    ) -> None:
        """The texts of the values not in the caches, remembered.

        Raises:
            TypeError: a value of a type the column's ``__repr__`` does not take.
        """
        for i, text in enumerate(texts):
            if text is not None:
                continue
            value = values[i]
            text = texts[i] = self._typed[i](value)
            if not self._int_flags[i] and (value == 0 or value != value):
                continue  # +-0.0 are equal, NaN equals nothing: never cached
            cache = caches[i]
            if len(cache) >= TEXT_CACHE_SIZE:
                cache.clear()
            cache[value] = text


class TableWriter(LineFile):
    """Writes one table file in a flight folder, flushing every row.

    The file is created (never overwritten: ``FileExistsError`` if it exists) and the
    header written and flushed at once (:class:`~mkflight.logs._file.LineFile`).
    """

    def __init__(self, folder: str | Path, fmt: TableFormat) -> None:
        super().__init__(Path(folder) / fmt.file_name, "ascii")
        self.fmt = fmt
        self._format = RowFormatter(fmt)
        self._last_index: int | None = None
        self.write_line(fmt.header + "\n")

    def write_values(self, values: tuple[Value, ...]) -> None:
        """Append one row (columns in table order) and flush it.

        Raises:
            ValueError: a malformed row, or an index not above the previous one.
            RuntimeError: the writer is closed.
        """
        if self.closed:
            msg = f"{self.path}: writer is closed"
            raise RuntimeError(msg)
        line = self._format(values)
        index = int(values[-1])
        if self._last_index is not None and index <= self._last_index:
            msg = f"{self.path}: index {index} not above the previous {self._last_index}"
            raise ValueError(msg)
        self.write_line(line)
        self._last_index = index

    @property
    def last_index(self) -> int | None:
        """The index of the last row written (None before the first)."""
        return self._last_index


def _parse(fmt: TableFormat, path: Path, line_no: int, line: str) -> tuple[Value, ...]:
    """One row's values, or ReplayError naming the file, the line and the column."""
    fields = line.split()
    if len(fields) != len(fmt.columns):
        msg = f"{path}:{line_no}: expected {len(fmt.columns)} columns, got {len(fields)}"
        raise ReplayError(msg)
    out: list[Value] = []
    for name, text in zip(fmt.columns, fields, strict=True):
        try:
            out.append(_int(text) if name in fmt.int_columns else float(text))
        except ValueError as err:
            shown = text if len(text) <= 40 else text[:40] + "..."
            msg = f"{path}:{line_no}: column {name}: cannot parse {shown!r}"
            raise ReplayError(msg) from err
    return tuple(out)


def _int(text: str) -> int:
    """An integer column: ``12`` or an integral float such as ``12.0`` (other writers).

    Raises:
        ValueError: not an integer, or outside int64 (the reader's dtype).
    """
    try:
        value = int(text)
    except ValueError:
        number = float(text)
        if not number.is_integer():
            raise
        value = int(number)
    if not _INT64_MIN <= value <= _INT64_MAX:
        msg = f"{value:.3g} is outside int64"
        raise ValueError(msg)
    return value


def read_table(path: str | Path, fmt: TableFormat) -> TableData:
    """Read a table file written by :class:`TableWriter` (or by the documented system).

    Blank lines are skipped; a last line without newline is dropped (``truncated``).

    Raises:
        ReplayError: unreadable file, wrong header, a malformed row or a non-increasing
            index; the message names the file and the line.
    """
    path = Path(path)
    data = read_bytes(path)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as err:
        msg = f"{path}: cannot read: {err}"
        raise ReplayError(msg) from err
    lines = text.split("\n")
    truncated = lines[-1] != ""  # the text after the last newline: a partial row
    complete = lines[:-1]
    if not complete or complete[0].split() != list(fmt.columns):
        got = complete[0] if complete else text
        msg = f"{path}:1: expected the header {fmt.header!r}, got {got[:200]!r}"
        raise ReplayError(msg)
    rows: list[tuple[Value, ...]] = []
    last_index: int | None = None
    for line_no, line in enumerate(complete[1:], start=2):
        if not line.strip():
            continue
        values = _parse(fmt, path, line_no, line)
        index = int(values[-1])
        if last_index is not None and index <= last_index:
            msg = f"{path}:{line_no}: index {index} not above the previous {last_index}"
            raise ReplayError(msg)
        last_index = index
        rows.append(values)
    return TableData(path=path, rows=np.array(rows, dtype=fmt.dtype), truncated=truncated)
