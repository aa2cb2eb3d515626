"""The simulator's truth log, ``truth.txt``: where the vehicle really was (SPEC §6, §8).

Format (read by :mod:`mkflight.logs.flight`, :mod:`mkflight.analysis.precision` and
``numpy.loadtxt``, all of which skip ``#`` lines): a header line ``t x y z``; comments
``# t0_ns N`` (the host monotonic time of ``t`` = 0; the live simulator) and ``# airframe
{json}`` (the simulated airframe's kind, seed and constants, compact JSON on one line);
then rows ``t x y z``: ``t`` seconds since the origin, ``x y`` world metres (SPEC §1),
``z`` height up (m). A touchdown (the vehicle meeting the floor from the air) adds a
comment ``# touchdown T_S SPEED_MPS`` (``T_S`` on the rows' time base, the downward
speed at contact) just before the next row, so that the last line is always a row.
Created new (never overwritten), flushed per row: a killed process leaves it readable.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Final

from mkflight.conversions import NS_PER_S
from mkflight.logs._file import LineFile
from mkflight.sim.vehicle import VehicleState

TRUTH_HEADER: Final = "t x y z\n"


def airframe_comment(info: Mapping[str, object]) -> str:
    """The truth log's ``# airframe {json}`` line (compact JSON, no newline inside)."""
    return "# airframe " + json.dumps(info, separators=(",", ":")) + "\n"


def touchdown_comment(t_s: float, speed_mps: float) -> str:
    """The truth log's ``# touchdown T_S SPEED_MPS`` line (``T_S`` on the rows' time base)."""
    return f"# touchdown {t_s:.4f} {speed_mps:.4f}\n"


def parse_touchdowns(text: str) -> list[tuple[float, float]]:
    """Every ``(t_s, speed_mps)`` of a truth log's ``# touchdown`` lines, in order.

    A malformed touchdown line is skipped (the rows' reader reports the file's damage).
    """
    out: list[tuple[float, float]] = []
    for line in text.splitlines():
        words = line.split()
        if len(words) == 4 and words[:2] == ["#", "touchdown"]:
            try:
                out.append((float(words[2]), float(words[3])))
            except ValueError:
                continue
    return out


class TruthLog:
    """The ``t x y z`` truth file (module docstring), created new and flushed per row."""

    def __init__(
        self, path: str | Path, *, origin_ns: int, airframe: Mapping[str, object] | None = None
    ) -> None:
        """Create ``path`` (never overwritten); write the header, origin and airframe lines.

        Raises:
            FileExistsError: ``path`` exists.
        """
        self.origin_ns = origin_ns
        self._file = LineFile(Path(path), "utf-8")
        self._file.write_line(TRUTH_HEADER)
        self._file.write_line(f"# t0_ns {origin_ns} (host monotonic clock at t = 0)\n")
        if airframe is not None:
            self._file.write_line(airframe_comment(airframe))
        self._pending: list[str] = []
        self._last: tuple[int, VehicleState] | None = None
        self.rows = 0

    def write(self, t_ns: int, state: VehicleState) -> None:
        """One row: seconds since the origin, world x and y (m), height up (m).

        Touchdown comments noted since the last row go just before it.
        """
        for line in self._pending:
            self._file.write_line(line)
        self._pending.clear()
        x, y, _ = state.pos_w_m
        t_s = (t_ns - self.origin_ns) / NS_PER_S
        self._file.write_line(f"{t_s:.4f} {x:.5f} {y:.5f} {state.height_m:.5f}\n")
        self._last = (t_ns, state)
        self.rows += 1

    def touchdown(self, t_ns: int, speed_mps: float) -> None:
        """Note a touchdown at host ``t_ns``: written before the next row (never last)."""
        self._pending.append(touchdown_comment((t_ns - self.origin_ns) / NS_PER_S, speed_mps))

    def close(self, t_ns: int | None = None, state: VehicleState | None = None) -> None:
        """Write what is pending, then close (idempotent).

        A pending touchdown line is followed by a row of ``state`` at ``t_ns`` when that is
        later than the last row (so the last line stays a row), else written alone.
        """
        if self._pending:
            later = self._last is None or (t_ns is not None and t_ns > self._last[0])
            if t_ns is not None and state is not None and later:
                self.write(t_ns, state)
            else:
                for line in self._pending:
                    self._file.write_line(line)
                self._pending.clear()
        self._file.close()


__all__ = [
    "TRUTH_HEADER",
    "TruthLog",
    "airframe_comment",
    "parse_touchdowns",
    "touchdown_comment",
]
