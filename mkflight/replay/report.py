"""What a replay found (:func:`mkflight.replay.run.replay_flight`): the report's types.

:class:`ReplayReport` holds the replayed flight's own report, the determinism check
(:class:`~mkflight.replay.compare.CommandComparison` and :class:`TableComparison`, from
:func:`compare_tables`), the pace and what the feeder did; a replay of the original
system's tables holds a :class:`SeedComparison` instead of the tables' check.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mkflight.flight.app import FlightReport
from mkflight.replay.compare import CommandComparison
from mkflight.replay.feeder import FeedStats
from mkflight.replay.seed import ColumnComparison

TABLES = ("imu_50ms.log", "laser_100ms.log")


@dataclass(frozen=True, slots=True)
class TableComparison:
    """One table of the replay against the original's: equal, or the first differing row."""

    name: str
    rows_original: int
    rows_replayed: int
    first_difference: int | None  # 1-based line number, None when equal
    original_line: str = ""
    replayed_line: str = ""

    @property
    def equal(self) -> bool:
        """The files are the same, line for line."""
        return self.first_difference is None


@dataclass(slots=True)
class ReplayReport:
    """What :func:`replay_flight` found."""

    source: Path
    out_dir: Path
    flight: FlightReport
    commands: CommandComparison
    tables: list[TableComparison]
    overrides: list[str]
    rematch: bool
    recorded_s: float
    wall_s: float
    cpu_s: float
    feed: FeedStats
    matcher: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    start_ns: int = 0
    #: a replay of the original system's tables alone: its tables against those, by column
    seed: SeedComparison | None = None

    @property
    def speedup(self) -> float:
        """Recorded seconds per wall-clock second."""
        return self.recorded_s / self.wall_s if self.wall_s > 0 else float("inf")

    @property
    def deterministic(self) -> bool:
        """Every command byte and every table row reproduced (never, for the original's tables)."""
        return self.seed is None and self.commands.identical and all(t.equal for t in self.tables)


@dataclass(frozen=True, slots=True)
class SeedComparison:
    """A replay's tables against the original system's (rows paired from take-off on)."""

    imu_rows_played: int
    imu_rows: int
    laser_rows: int
    imu: list[ColumnComparison]
    laser: list[ColumnComparison]


def compare_tables(
    original: Path,
    replayed: Path,
    warnings: list[str] | None = None,
    upto: dict[str, int] | None = None,
) -> list[TableComparison]:
    """Each table of the replay line by line against the original's.

    A table missing from the original is not compared (a warning says so). ``upto``: per
    table, compare only the rows up to this index (its last column): a recording cut
    short says nothing about the flight after its end.
    """
    out = []
    for name in TABLES:
        if not (original / name).is_file():
            if warnings is not None:
                warnings.append(f"{original / name}: missing: the replay's is not compared")
            continue
        a = _lines(original / name)
        b = _lines(replayed / name)
        if upto is not None:
            last = upto.get(name, 0)
            a, b = _upto(a, last), _upto(b, last)
        first = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)
        if first is None and len(a) != len(b):
            first = min(len(a), len(b))
        out.append(
            TableComparison(
                name,
                max(len(a) - 1, 0),
                max(len(b) - 1, 0),
                None if first is None else first + 1,
                a[first] if first is not None and first < len(a) else "",
                b[first] if first is not None and first < len(b) else "",
            )
        )
    return out


def last_rows(folder: Path) -> dict[str, int]:
    """Per table of ``folder``, the index (last column) of its last whole row (0: none).

    A killed flight's tables end at the last step it wrote; the replayed daemon may step
    once more on a DebugOut the recording holds but the killed process had not yet
    written a row for. That row comes after the recording ended and is not compared.
    """
    out: dict[str, int] = {}
    for name in TABLES:
        path = folder / name
        lines = _lines(path) if path.is_file() else []
        rows = _upto(lines, 2**62)[1:]
        out[name] = int(rows[-1].rsplit(maxsplit=1)[-1]) if rows else 0
    return out


def _upto(lines: list[str], last_index: int) -> list[str]:
    """The header and the rows whose index (the last column) is at most ``last_index``."""
    out = lines[:1]
    for line in lines[1:]:
        fields = line.rsplit(maxsplit=1)
        try:
            index = int(fields[-1])
        except (ValueError, IndexError):
            index = last_index + 1
        if index <= last_index:
            out.append(line)
    return out


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return []
