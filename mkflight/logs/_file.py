"""The file under every flight-folder log writer and reader.

Writing: created (never overwritten), line-flushed. A flush per line survives a killed
process (SPEC §6); ``close`` also fsyncs, so a clean end survives a power cut too.

Reading: a log may come from anywhere (``replay`` is handed other people's folders), so
the readers take only regular files (:func:`read_bytes`: a FIFO would block them forever,
a link to ``/dev/zero`` would never end) and refuse JSON nested deeper than any log
writes (:func:`too_deep`: the code after them recurses).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Final, Self

from mkflight.errors import ReplayError

#: Deeper JSON than any log writes (flight.json: config section -> list -> value).
MAX_JSON_DEPTH: Final = 32


def read_bytes(path: Path, *, what: str = "", max_bytes: int | None = None) -> bytes:
    """The content of the regular file ``path`` (a symlink is followed: reading is harmless).

    A FIFO, a device, a socket or a directory is refused, and never opened (opening a
    serial port can reset what is on it); the open file is checked again (``fstat``),
    so a rename in between cannot slip one in.

    Args:
        path: the file.
        what: what the file holds, for the message ("flight metadata").
        max_bytes: refuse a larger file (one that is never that large: ``flight.json``).

    Raises:
        ReplayError: cannot be opened or read, not a regular file, or larger than
            ``max_bytes``; the message names the file.
    """
    cannot = f"{path}: cannot read{' ' + what if what else ''}"
    not_regular = f"{cannot}: not a regular file"
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise ReplayError(not_regular)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as err:
        msg = f"{cannot}: {err}"
        raise ReplayError(msg) from err
    with open(fd, "rb") as f:
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise ReplayError(not_regular)
            if max_bytes is not None and st.st_size > max_bytes:
                msg = f"{cannot}: {st.st_size} bytes, more than the {max_bytes} such a file holds"
                raise ReplayError(msg)
            data = f.read() if max_bytes is None else f.read(max_bytes + 1)
        except OSError as err:
            msg = f"{cannot}: {err}"
            raise ReplayError(msg) from err
    if max_bytes is not None and len(data) > max_bytes:  # it grew while we read
        msg = f"{cannot}: more than the {max_bytes} bytes such a file holds"
        raise ReplayError(msg)
    return data


def too_deep(obj: Any, limit: int = MAX_JSON_DEPTH) -> bool:
    """True if the lists and objects in ``obj`` (decoded JSON) nest more than ``limit`` deep.

    Walks one level at a time, without recursion: what follows a reader (``str()``,
    msgspec, the config checks) recurses, and a line nested a thousand deep would end it
    in a ``RecursionError`` instead of an error naming the file.
    """
    level = [obj]
    for _ in range(limit + 1):
        level = [
            child
            for node in level
            if isinstance(node, dict | list)
            for child in (node.values() if isinstance(node, dict) else node)
        ]
        if not level:
            return False
    return True


def read_lines(path: Path) -> tuple[list[str], bool]:
    """The complete lines of a text log, and whether a last line was cut short (dropped).

    Raises:
        ReplayError: the file cannot be read, is not a regular file or is not UTF-8
            (naming it).
    """
    data = read_bytes(path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        msg = f"{path}: cannot read: {err}"
        raise ReplayError(msg) from err
    lines = text.split("\n")
    return lines[:-1], lines[-1] != ""


#: Lines kept before a write when not flushed one by one (a replay's).
BLOCK_BYTES: Final = 64 * 1024


class LineFile:
    """A new text file in a flight folder that writes and flushes whole lines.

    Each line goes to the kernel in one ``write`` (the file is unbuffered: nothing
    between the line and the system call), unless :attr:`flush_each_line` is set False.
    """

    def __init__(self, path: Path, encoding: str) -> None:
        self.path = path
        self._encoding = encoding
        self._file: BinaryIO | None = path.open("xb", buffering=0)
        self._pending: bytearray | None = None  # lines not written yet, when in blocks

    @property
    def flush_each_line(self) -> bool:
        """Flush every line: a flight's (a killed process loses nothing).

        A replay, which can write its folder again, sets it False and writes in blocks.
        """
        return self._pending is None

    @flush_each_line.setter
    def flush_each_line(self, value: bool) -> None:
        if value and self._pending is not None:
            pending, self._pending = self._pending, None
            if pending and self._file is not None:
                self._write(self._file, bytes(pending))
        elif not value and self._pending is None:
            self._pending = bytearray()

    def write_line(self, line: str) -> None:
        """Append ``line`` (with its newline) and flush it.

        Raises:
            RuntimeError: the file is closed.
        """
        self.write_encoded(line.encode(self._encoding))

    def write_encoded(self, data: bytes) -> None:
        """Append one line already encoded (with its newline) and flush it.

        Raises:
            RuntimeError: the file is closed.
        """
        file = self._file
        if file is None:
            msg = f"{self.path}: writer is closed"
            raise RuntimeError(msg)
        pending = self._pending
        if pending is not None:
            pending += data
            if len(pending) < BLOCK_BYTES:
                return
            data = bytes(pending)
            pending.clear()
        self._write(file, data)

    def _write(self, file: BinaryIO, data: bytes) -> None:
        """``data`` to the kernel: one system call unless it takes only part."""
        n = file.write(data)
        while n != len(data):  # the kernel took part of it (a disk filling up)
            if not n:
                raise OSError(errno.EIO, "write accepted no bytes", str(self.path))
            data = data[n:]
            n = file.write(data)

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._file is None

    def close(self) -> None:
        """Flush, fsync and close (idempotent)."""
        file, pending = self._file, self._pending
        if file is None:
            return
        self._file = self._pending = None
        try:
            if pending:
                self._write(file, bytes(pending))
            os.fsync(file.fileno())
        finally:
            file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
