"""``imu_50ms.log``: the 50 ms IMU/command-step log (SPEC §6).

It is TABLE IV of the 2011 QUT CyPhy MikroKopter documentation (§E).

Format (see :mod:`mkflight.logs._table`): a header line of exactly these 14 names,
space-separated, then one row per 50 ms step (the header is one line, folded here)::

    AnglePitch AngleRoll AngleYaw AccX AccY AccZ ControlPitch ControlRoll ControlYaw
        StickPitch StickRoll StickYaw StickThrust index
    0.012 -0.004 1.571 0.118 -0.04 -9.79 -3 1 0 0 0 0 200 42

Angles in rad and accelerations (the specific force) in m/s², both in the body frame
as SPEC §1 defines them; ``Control*`` are the ExternControl counts sent (nick, roll, yaw
with the MK's signs: + nick = nose down), ``Stick*`` the pilot's stick counts received,
all integers, as is ``index`` (+1 per 50 ms step, strictly increasing). NaN is written
``nan``, which ``numpy.loadtxt(f, skiprows=1)`` reads as NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from operator import attrgetter
from pathlib import Path

from mkflight.logs._table import TableData, TableFormat, TableWriter, read_table

FILE_NAME = "imu_50ms.log"
COLUMNS = (
    "AnglePitch",
    "AngleRoll",
    "AngleYaw",
    "AccX",
    "AccY",
    "AccZ",
    "ControlPitch",
    "ControlRoll",
    "ControlYaw",
    "StickPitch",
    "StickRoll",
    "StickYaw",
    "StickThrust",
    "index",
)
INT_COLUMNS = frozenset(COLUMNS[6:])
#: The angles and accelerations are the MK's integer counts scaled: a few hundred
#: distinct values, whose texts the writer remembers.
FORMAT = TableFormat(FILE_NAME, COLUMNS, INT_COLUMNS, repeating=True)


@dataclass(frozen=True, slots=True)
class Table4Row:
    """One TABLE IV row, fields in column order (the flight step returns these)."""

    pitch_rad: float
    roll_rad: float
    yaw_rad: float
    acc_x_mps2: float
    acc_y_mps2: float
    acc_z_mps2: float
    control_pitch_counts: int
    control_roll_counts: int
    control_yaw_counts: int
    stick_pitch_counts: int
    stick_roll_counts: int
    stick_yaw_counts: int
    stick_thrust_counts: int
    index: int


_NAMES = tuple(f.name for f in fields(Table4Row))
"""The row's fields in column order (``astuple`` would deep-copy every value)."""
_values = attrgetter(*_NAMES)  # a row's values in column order, in one call


class Table4Writer(TableWriter):
    """Creates ``imu_50ms.log`` in a flight folder; each row is flushed as written."""

    def __init__(self, folder: str | Path) -> None:
        super().__init__(folder, FORMAT)

    def write_row(self, row: Table4Row) -> None:
        """Append and flush one row.

        Raises:
            ValueError: a count that is not an integer, or ``index`` not above the previous.
        """
        self.write_values(_values(row))  # shallow


def read_table4(path: str | Path) -> TableData:
    """Read an ``imu_50ms.log`` (rows fielded by the header names, e.g. ``"AccX"``).

    Raises:
        ReplayError: a wrong header or malformed row, naming the file and line.
    """
    return read_table(path, FORMAT)


def rows_of(data: TableData) -> list[Table4Row]:
    """The rows of a read table as :class:`Table4Row` records (for replay)."""
    names = [f.name for f in fields(Table4Row)]
    return [Table4Row(**dict(zip(names, r.tolist(), strict=True))) for r in data.rows]
