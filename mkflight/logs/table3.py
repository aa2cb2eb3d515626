"""``laser_100ms.log``: the 100 ms laser-step log (SPEC §6).

It is TABLE III of the 2011 QUT CyPhy MikroKopter documentation (§E).

Format (see :mod:`mkflight.logs._table`): a header line of exactly these 10 names,
space-separated, then one row per 100 ms step, every value a float except ``index``
(the header is one line, folded here)::

    W_Vel.x B_Vel.x B_esti_Vel.x W_Vel.y B_Vel.y B_esti_Vel.y
        CurrentPosition.x CurrentPosition.y CurrentPosition.theta index
    0.012 0.011 0.01 -0.003 -0.004 -0.002 0.101 -0.02 0.0031 17

Velocities in m/s (world frame W, then body frame B from the laser, then the filter's
body-frame estimate; SPEC §1), position in m and heading in rad in W, ``index`` +1 per
100 ms step (strictly increasing; a skipped step leaves a gap). The documented table labels
column 2 ``B_Vel.y``; it is the body velocity along x. NaN (no valid value) is written
``nan``, which ``numpy.loadtxt(f, skiprows=1)`` reads as NaN.
"""

from __future__ import annotations

from pathlib import Path

import msgspec

from mkflight.logs._table import TableData, TableFormat, TableWriter, read_table

FILE_NAME = "laser_100ms.log"
COLUMNS = (
    "W_Vel.x",
    "B_Vel.x",
    "B_esti_Vel.x",
    "W_Vel.y",
    "B_Vel.y",
    "B_esti_Vel.y",
    "CurrentPosition.x",
    "CurrentPosition.y",
    "CurrentPosition.theta",
    "index",
)
FORMAT = TableFormat(FILE_NAME, COLUMNS, frozenset({"index"}))


class Table3Row(msgspec.Struct, frozen=True, gc=False):
    """One TABLE III row, fields in column order (the flight step returns these).

    A frozen Struct (one C call to build, ~10x cheaper than a frozen dataclass's ten
    ``object.__setattr__``: one per scan on the flight step's path), untracked by the
    garbage collector: it holds numbers.
    """

    w_vel_x_mps: float
    b_vel_x_mps: float
    b_esti_vel_x_mps: float
    w_vel_y_mps: float
    b_vel_y_mps: float
    b_esti_vel_y_mps: float
    x_m: float
    y_m: float
    theta_rad: float
    index: int


_values = msgspec.structs.astuple  # a row's values in column order, in one call (shallow)


class Table3Writer(TableWriter):
    """Creates ``laser_100ms.log`` in a flight folder; each row is flushed as written."""

    def __init__(self, folder: str | Path) -> None:
        super().__init__(folder, FORMAT)

    def write_row(self, row: Table3Row) -> None:
        """Append and flush one row.

        Raises:
            ValueError: ``index`` not above the previous row's.
        """
        self.write_values(_values(row))  # shallow


def read_table3(path: str | Path) -> TableData:
    """Read a ``laser_100ms.log`` (rows fielded by the header names, e.g. ``"W_Vel.x"``).

    Raises:
        ReplayError: a wrong header or malformed row, naming the file and line.
    """
    return read_table(path, FORMAT)


def rows_of(data: TableData) -> list[Table3Row]:
    """The rows of a read table as :class:`Table3Row` records (for replay)."""
    return [Table3Row(*r.tolist()) for r in data.rows]
