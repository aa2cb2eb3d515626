"""Reader of CARMEN laser logs: ``FLASER`` and ``ROBOTLASER1`` lines, plain text or gzip.

The format (as ``../shared/data/laser/README.md`` describes it, fields separated by
whitespace, one message per line, ``#`` lines are comments)::

    FLASER n r1 .. rn x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range
        accuracy remission_mode n r1 .. rn n_remissions [remissions] laser_x laser_y
        laser_theta robot_x robot_y robot_theta tv rv forward_safety_dist
        side_safety_dist turn_axis ipc_timestamp hostname logger_timestamp

* ``FLASER``: beam i at ``-pi/2 + i*pi/n`` rad (GMapping's reading of the 180-degree SICK
  logs), ranges >= 80 m (81.83) mean no return. The first pose triple is the laser's pose,
  the second the odometry (the corrected logs hold the corrected pose in both).
* ``ROBOTLASER1``: beam i at ``start_angle + i*angular_resolution``; values at or beyond
  ``maximum_range`` are no return.
* Angles are counter-clockwise from the robot's forward x axis (y left). The scan's time is
  the LAST field (``logger_timestamp``), in seconds.

Other message types (``ODOM``, ``PARAM``, ``NEFF``, ``SYNC`` ...) are skipped silently; they
are valid CARMEN, just not laser data. A laser line that cannot be parsed (too few fields,
a non-number, a count that does not fit the line, a non-finite pose or time) becomes a
:class:`MalformedLine` carrying its 1-based line number and the reason: it is counted and
reported, and every other line is still read (STYLE.md: garbage is counted data).
"""

from __future__ import annotations

import gzip
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mkflight.errors import ProtocolError

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: FLASER ranges at or beyond this are "no return" (SICK LMS reports 81.83 m).
FLASER_NO_RETURN_M = 80.0
#: Shortest valid range (SPEC §2: URG values below 20 mm are error codes).
DEFAULT_MIN_RANGE_M = 0.02
LASER_KINDS = ("FLASER", "ROBOTLASER1")


@dataclass(frozen=True, slots=True, eq=False)
class LaserRecord:
    """One laser scan of a CARMEN log.

    Attributes:
        kind: ``"FLASER"`` or ``"ROBOTLASER1"``.
        line_no: 1-based line number in the file.
        t_s: the scan's time, the line's last field (seconds).
        angles_rad: (n,) beam angles, counter-clockwise from the robot's x axis.
        ranges_m: (n,) ranges as logged (invalid ones included; see ``valid``).
        valid: (n,) finite and ``min_range_m <= r < max_range_m``.
        max_range_m: the exclusive upper bound used for ``valid``.
        laser_pose: (x_m, y_m, theta_rad) of the laser in the log's world frame.
        robot_pose: (x_m, y_m, theta_rad) of the robot (FLASER: the odometry triple).
    """

    kind: str
    line_no: int
    t_s: float
    angles_rad: FloatArray
    ranges_m: FloatArray
    valid: BoolArray
    max_range_m: float
    laser_pose: tuple[float, float, float]
    robot_pose: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class MalformedLine:
    """A laser line that could not be parsed: where and why."""

    line_no: int
    reason: str


@dataclass(frozen=True, slots=True)
class CarmenLog:
    """All laser records of a log, in file order, and the lines that failed."""

    records: list[LaserRecord]
    malformed: list[MalformedLine]


class _Bad(Exception):
    """Internal: one line is malformed (its message is the reason)."""


def _floats(fields: list[str], start: int, count: int, what: str) -> list[float]:
    if start + count > len(fields):
        msg = f"{what}: line ends after {len(fields)} fields, expected {start + count}"
        raise _Bad(msg)
    try:
        return [float(v) for v in fields[start : start + count]]
    except ValueError as err:
        msg = f"{what}: not a number ({err})"
        raise _Bad(msg) from err


def _count(fields: list[str], index: int, what: str) -> int:
    if index >= len(fields):
        msg = f"{what}: missing"
        raise _Bad(msg)
    try:
        value = int(fields[index])
    except ValueError as err:
        msg = f"{what}: not an integer: {fields[index]!r}"
        raise _Bad(msg) from err
    if value < 0 or value > 100_000:
        msg = f"{what}: out of range: {value}"
        raise _Bad(msg)
    return value


def _pose(values: list[float], what: str) -> tuple[float, float, float]:
    if not all(math.isfinite(v) for v in values):
        msg = f"{what}: non-finite value"
        raise _Bad(msg)
    return (values[0], values[1], values[2])


def _valid(ranges: FloatArray, min_range_m: float, max_range_m: float) -> BoolArray:
    with np.errstate(invalid="ignore"):
        ok: BoolArray = np.isfinite(ranges) & (ranges >= min_range_m) & (ranges < max_range_m)
    return ok


def _time(fields: list[str]) -> float:
    try:
        t = float(fields[-1])
    except ValueError as err:
        msg = f"timestamp (last field) not a number: {fields[-1]!r}"
        raise _Bad(msg) from err
    if not math.isfinite(t):
        msg = "timestamp (last field) not finite"
        raise _Bad(msg)
    return t


def _parse_flaser(fields: list[str], line_no: int, min_range_m: float) -> LaserRecord:
    n = _count(fields, 1, "FLASER beam count")
    ranges = np.array(_floats(fields, 2, n, "FLASER ranges"))
    tail = 2 + n
    poses = _floats(fields, tail, 6, "FLASER poses")
    if len(fields) != tail + 9:
        msg = f"FLASER with {n} beams must have {tail + 9} fields, has {len(fields)}"
        raise _Bad(msg)
    t = _time(fields)
    angles: FloatArray = -math.pi / 2 + np.arange(n, dtype=np.float64) * (math.pi / max(n, 1))
    return LaserRecord(
        kind="FLASER",
        line_no=line_no,
        t_s=t,
        angles_rad=angles,
        ranges_m=ranges,
        valid=_valid(ranges, min_range_m, FLASER_NO_RETURN_M),
        max_range_m=FLASER_NO_RETURN_M,
        laser_pose=_pose(poses[0:3], "FLASER pose"),
        robot_pose=_pose(poses[3:6], "FLASER odometry pose"),
    )


def _parse_robotlaser1(fields: list[str], line_no: int, min_range_m: float) -> LaserRecord:
    head = _floats(fields, 2, 5, "ROBOTLASER1 header")
    start, _fov, res, max_range, _acc = head
    if not (math.isfinite(start) and math.isfinite(res) and math.isfinite(max_range)):
        msg = "ROBOTLASER1 header: non-finite angle, resolution or range"
        raise _Bad(msg)
    n = _count(fields, 8, "ROBOTLASER1 beam count")
    ranges = np.array(_floats(fields, 9, n, "ROBOTLASER1 ranges"))
    n_rem = _count(fields, 9 + n, "ROBOTLASER1 remission count")
    tail = 10 + n + n_rem
    _floats(fields, 10 + n, n_rem, "ROBOTLASER1 remissions")
    poses = _floats(fields, tail, 6, "ROBOTLASER1 poses")
    if len(fields) != tail + 14:
        msg = f"ROBOTLASER1 with {n} beams must have {tail + 14} fields, has {len(fields)}"
        raise _Bad(msg)
    t = _time(fields)
    return LaserRecord(
        kind="ROBOTLASER1",
        line_no=line_no,
        t_s=t,
        angles_rad=np.asarray(start + np.arange(n, dtype=np.float64) * res, dtype=np.float64),
        ranges_m=ranges,
        valid=_valid(ranges, min_range_m, max_range),
        max_range_m=max_range,
        laser_pose=_pose(poses[0:3], "ROBOTLASER1 laser pose"),
        robot_pose=_pose(poses[3:6], "ROBOTLASER1 robot pose"),
    )


def parse_line(
    line: str, line_no: int, min_range_m: float = DEFAULT_MIN_RANGE_M
) -> LaserRecord | MalformedLine | None:
    """Parse one line: a record, a :class:`MalformedLine`, or None for non-laser lines."""
    fields = line.split()
    if not fields or fields[0] not in LASER_KINDS:
        return None
    try:
        if fields[0] == "FLASER":
            return _parse_flaser(fields, line_no, min_range_m)
        return _parse_robotlaser1(fields, line_no, min_range_m)
    except _Bad as err:
        return MalformedLine(line_no=line_no, reason=str(err))


def iter_carmen(
    lines: Iterable[str], min_range_m: float = DEFAULT_MIN_RANGE_M
) -> Iterator[LaserRecord | MalformedLine]:
    """Parse lines lazily (pure: no I/O), yielding laser records and malformed lines."""
    for line_no, line in enumerate(lines, start=1):
        item = parse_line(line, line_no, min_range_m)
        if item is not None:
            yield item


def parse_carmen(lines: Iterable[str], min_range_m: float = DEFAULT_MIN_RANGE_M) -> CarmenLog:
    """Parse all lines into a :class:`CarmenLog` (pure: no I/O)."""
    records: list[LaserRecord] = []
    malformed: list[MalformedLine] = []
    for item in iter_carmen(lines, min_range_m):
        if isinstance(item, MalformedLine):
            malformed.append(item)
        else:
            records.append(item)
    return CarmenLog(records=records, malformed=malformed)


def read_carmen(path: str | Path, min_range_m: float = DEFAULT_MIN_RANGE_M) -> CarmenLog:
    """Read a CARMEN log file (gzip when it starts with the gzip magic, else plain text).

    Undecodable bytes become U+FFFD, so they spoil only their own line (then malformed).

    Raises:
        ProtocolError: the file cannot be opened or decompressed.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            magic = fh.read(2)
        if magic == b"\x1f\x8b":
            with gzip.open(p, "rt", encoding="utf-8", errors="replace") as gz:
                return parse_carmen(gz, min_range_m)
        with p.open("r", encoding="utf-8", errors="replace") as fh:
            return parse_carmen(fh, min_range_m)
    except (OSError, EOFError) as err:
        msg = f"{p}: cannot read CARMEN log: {err}"
        raise ProtocolError(msg) from err
