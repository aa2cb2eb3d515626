"""The file under every flight-folder log writer: created (never overwritten), line-flushed.

A flush per line survives a killed process (SPEC §6); ``close`` also fsyncs, so a clean
end survives a power cut too.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType
from typing import Self, TextIO

from mkflight.errors import ReplayError


def read_lines(path: Path) -> tuple[list[str], bool]:
    """The complete lines of a text log, and whether a last line was cut short (dropped).

    Raises:
        ReplayError: the file cannot be read or is not UTF-8 (naming it).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        msg = f"{path}: cannot read: {err}"
        raise ReplayError(msg) from err
    lines = text.split("\n")
    return lines[:-1], lines[-1] != ""


class LineFile:
    """A new text file in a flight folder that writes and flushes whole lines."""

    def __init__(self, path: Path, encoding: str) -> None:
        self.path = path
        self._file: TextIO | None = path.open("x", encoding=encoding, newline="\n")
        #: flush every line (a flight: a killed process loses nothing); a replay, which
        #: can write its folder again, sets it False and writes in blocks
        self.flush_each_line = True

    def write_line(self, line: str) -> None:
        """Append ``line`` (with its newline) and flush it.

        Raises:
            RuntimeError: the file is closed.
        """
        if self._file is None:
            msg = f"{self.path}: writer is closed"
            raise RuntimeError(msg)
        self._file.write(line)
        if self.flush_each_line:
            self._file.flush()

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._file is None

    def close(self) -> None:
        """Flush, fsync and close (idempotent)."""
        if self._file is None:
            return
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self._file = None

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
