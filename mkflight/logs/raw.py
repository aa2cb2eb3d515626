r"""Raw port recordings (``mk.raw``, ``laser.raw``): every byte each way, timestamped.

SPEC §6: a recording holds every byte read from and written to one serial port with the
host time of each read and write, so ``mkflight replay`` can feed the reads back through
a mock port byte for byte and compare the writes (the determinism check). The recorder
is a :data:`~mkflight.io.stream.Tap`: the MK link and the URG driver call it with each
chunk they read or write.

Format (version 1), all integers little-endian::

    header
      offset  size  field
      0       8     magic b"MKRAW\r\n\x1a" (the CR LF and ^Z catch text-mode mangling)
      8       2     version, uint16 (1)
      10      2     N, the port label's length in bytes, uint16
      12      8     start_wall_ns, int64: wall-clock start, ns since 1970-01-01 UTC
      20      8     start_t_ns, int64: the record clock's t_ns at the same instant
      28      N     the port label, UTF-8 (the device path, e.g. "/dev/ttyUSB0")
    then records, back to back until the end of the file
      0       8     t_ns, int64: host time of the read or write (the links' clock:
                    monotonic on the vehicle, the manual clock in the simulator)
      8       1     kind, one ASCII byte:
                      'r' bytes read from the device      (payload: the bytes)
                      'w' bytes written to the device     (payload: the bytes)
                      'o' the port was (re)opened         (payload: UTF-8 text, e.g. the path)
                      'c' the port was closed or was lost (payload: UTF-8 text, the reason)
      9       4     length of the payload in bytes, uint32
      13      len   payload

A record's wall time is ``start_wall_ns + (t_ns - start_t_ns)`` (:meth:`RawHeader.wall_ns`).
Records are in call order, which is time order for one port. Each record goes to the
kernel in one ``write`` as it happens (the file is unbuffered), so a killed process
loses nothing but, at worst, the tail of the record being written: the reader keeps every
complete record and reports the byte offset of the incomplete one
(:attr:`RawRecording.truncated_at`). A broken header (wrong magic, unknown version, cut
short), an unknown record kind, a record whose time is before the previous one's, or a
record running past the end whose time is more than a day after the previous one's
(damage, not a kill) is a
:class:`~mkflight.errors.ReplayError` naming the file and the byte offset.
"""

from __future__ import annotations

import errno
import os
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Final, Self

from mkflight.clock import Clock, MonotonicClock
from mkflight.conversions import NS_PER_S
from mkflight.errors import ReplayError
from mkflight.logs._file import read_bytes

__all__ = [
    "FORMAT_VERSION",
    "KINDS",
    "MAGIC",
    "RawHeader",
    "RawRecord",
    "RawRecorder",
    "RawRecording",
    "create_buffered",
    "create_unbuffered",
    "read_raw",
]

MAGIC: Final = b"MKRAW\r\n\x1a"
FORMAT_VERSION: Final = 1
#: Record kinds: read, written, port opened, port closed or lost.
KINDS: Final = frozenset("rwoc")
_DATA_KINDS: Final = frozenset("rw")
_EVENT_KINDS: Final = frozenset("oc")
_KIND_BYTE: Final = {k: k.encode("ascii") for k in KINDS}
_KIND_OF_BYTE: Final = {b: k for k, b in _KIND_BYTE.items()}

_HEADER = struct.Struct("<8sHHqq")  # magic, version, label length, start_wall_ns, start_t_ns
_RECORD = struct.Struct("<qcI")  # t_ns, kind, payload length
_pack_record = _RECORD.pack
_RECORD_HEAD_BYTES: Final = _RECORD.size
_DATA_KIND_BYTE: Final = {k: _KIND_BYTE[k] for k in _DATA_KINDS}
_MAX_LABEL_BYTES: Final = 0xFFFF
_MAX_PAYLOAD_BYTES: Final = 0xFFFF_FFFF
#: Records are in time order; one more than a day after the previous is corrupt.
_MAX_GAP_NS: Final = 86_400 * NS_PER_S

#: Opens the recording's file; the default creates it (never overwrites) unbuffered.
FileOpener = Callable[[Path], BinaryIO]


def create_unbuffered(path: Path) -> BinaryIO:
    """Create ``path`` for binary writing, unbuffered: each ``write`` is one syscall."""
    return path.open("xb", buffering=0)


def create_buffered(path: Path) -> BinaryIO:
    """Create ``path`` for binary writing in blocks (a replay's: it can be written again)."""
    return path.open("xb")


@dataclass(frozen=True, slots=True)
class RawHeader:
    """A recording's header: which port, and how its clock relates to wall time."""

    version: int
    port_name: str
    start_wall_ns: int
    start_t_ns: int

    def wall_ns(self, t_ns: int) -> int:
        """Return the wall-clock time (ns since the Unix epoch, UTC) of a record's ``t_ns``."""
        return self.start_wall_ns + (t_ns - self.start_t_ns)


@dataclass(frozen=True, slots=True)
class RawRecord:
    """One record: a chunk read ('r') or written ('w'), or a port event ('o', 'c')."""

    t_ns: int
    kind: str
    data: bytes

    @property
    def text(self) -> str:
        """The payload as text (for 'o'/'c' events; invalid UTF-8 is replaced)."""
        return self.data.decode("utf-8", errors="replace")


@dataclass(frozen=True, slots=True)
class RawRecording:
    """What :func:`read_raw` returns.

    ``truncated_at``: the byte offset of an incomplete last record that was dropped (a
    process killed mid-write or a full disk), else None; ``warning`` says it in words.
    """

    path: Path
    header: RawHeader
    records: list[RawRecord]
    size_bytes: int
    truncated_at: int | None = None

    @property
    def truncated(self) -> bool:
        """True if an incomplete last record was dropped."""
        return self.truncated_at is not None

    @property
    def warning(self) -> str | None:
        """A message about the dropped incomplete last record, or None."""
        if self.truncated_at is None:
            return None
        return (
            f"{self.path}: incomplete last record at byte {self.truncated_at} "
            f"({self.size_bytes - self.truncated_at} bytes) dropped"
        )

    def payload(self, kind: str) -> bytes:
        """All the bytes of one direction ('r' or 'w'), concatenated in order."""
        return b"".join(r.data for r in self.records if r.kind == kind)

    def __iter__(self) -> Iterator[RawRecord]:
        return iter(self.records)


class RawRecorder:
    """Records one port's traffic to a new raw file; an instance is a :data:`Tap`.

    Created before take-off: opening the file or writing the header raises (the daemon
    decides whether to fly without a recording). Afterwards nothing raises into the link
    on a disk error: the first :class:`OSError` is kept in :attr:`error`, recording
    stops, and every later record is counted in :attr:`dropped` (the flight must not die
    because the disk filled up).

    Args:
        path: the file to create; an existing file is never overwritten.
        port_name: the port's label for the header (its device path).
        clock: the clock the records' ``t_ns`` come from (read once here for the header's
            ``start_t_ns``; default monotonic).
        wall_clock_ns: wall-clock now in ns since the epoch (default ``time.time_ns``).
        opener: creates the file (a seam for tests); default ``open(path, "xb",
            buffering=0)``.

    Raises:
        FileExistsError: ``path`` exists (the message names it).
        OSError: the file cannot be created or the header cannot be written.
        ValueError: the port label is longer than 65535 UTF-8 bytes.
    """

    def __init__(
        self,
        path: str | Path,
        port_name: str,
        *,
        clock: Clock | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        opener: FileOpener = create_unbuffered,
    ) -> None:
        self.path = Path(path)
        self.port_name = port_name
        label = port_name.encode("utf-8")
        if len(label) > _MAX_LABEL_BYTES:
            msg = f"{self.path}: port label too long ({len(label)} bytes)"
            raise ValueError(msg)
        start_t_ns = (clock or MonotonicClock()).now_ns()
        start_wall_ns = wall_clock_ns()
        try:
            self._file: BinaryIO | None = opener(self.path)
        except FileExistsError as err:
            raise FileExistsError(
                errno.EEXIST, "raw recording exists, not overwriting it", str(self.path)
            ) from err
        header = _HEADER.pack(MAGIC, FORMAT_VERSION, len(label), start_wall_ns, start_t_ns)
        try:
            self._write_all(header + label)
        except BaseException:
            self._file.close()
            raise
        self.header = RawHeader(FORMAT_VERSION, port_name, start_wall_ns, start_t_ns)
        self.records = 0
        self.bytes_read = 0
        self.bytes_written = 0
        self.dropped = 0
        self.errors = 0
        self.error: OSError | None = None

    @property
    def recording(self) -> bool:
        """True while records are still being written (not closed, no disk error)."""
        return self._file is not None and self.error is None

    def __call__(self, direction: str, t_ns: int, data: bytes) -> None:
        """Record ``data`` read from ('r') or written to ('w') the port at ``t_ns``.

        Raises:
            ValueError: ``direction`` is not 'r' or 'w' (a bug in the caller).
        """
        file = self._file
        kind = _DATA_KIND_BYTE.get(direction)
        if file is not None and self.error is None and kind is not None:
            # The common case in one write, without _record's checks and calls (a record
            # holds at most 4 GiB: a chunk read or written is never near that).
            size = len(data)
            record = _pack_record(t_ns, kind, size) + data
            try:
                n = file.write(record)
                if n != size + _RECORD_HEAD_BYTES:
                    self._write_all(memoryview(record)[n or 0 :])
            except OSError as err:
                self._fail(err)
                self.dropped += 1
                return
            self.records += 1
            if kind == b"r":
                self.bytes_read += size
            else:
                self.bytes_written += size
            return
        if direction not in _DATA_KINDS:
            msg = f"{self.path}: direction must be 'r' or 'w', got {direction!r}"
            raise ValueError(msg)
        if self._record(direction, t_ns, data):
            if direction == "r":
                self.bytes_read += len(data)
            else:
                self.bytes_written += len(data)

    def mark(self, kind: str, t_ns: int, text: str = "") -> None:
        """Record a port event: 'o' (re)opened, 'c' closed or lost, with a short text.

        Raises:
            ValueError: ``kind`` is not 'o' or 'c'.
        """
        if kind not in _EVENT_KINDS:
            msg = f"{self.path}: event kind must be 'o' or 'c', got {kind!r}"
            raise ValueError(msg)
        self._record(kind, t_ns, text.encode("utf-8"))

    def _record(self, kind: str, t_ns: int, payload: bytes) -> bool:
        """Write one record; False (and counted) if it was not recorded."""
        if not self.recording:
            self.dropped += 1
            return False
        if len(payload) > _MAX_PAYLOAD_BYTES:
            msg = f"{self.path}: a record holds at most 4 GiB, got {len(payload)} bytes"
            raise ValueError(msg)
        try:
            self._write_all(_RECORD.pack(t_ns, _KIND_BYTE[kind], len(payload)) + payload)
        except OSError as err:
            self._fail(err)
            self.dropped += 1
            return False
        self.records += 1
        return True

    def _write_all(self, data: bytes | memoryview) -> None:
        """Write ``data`` (one syscall unless the kernel takes only part of it)."""
        assert self._file is not None
        view = memoryview(data)
        while view:
            n = self._file.write(view)
            if n is None or n <= 0:  # non-blocking file, or a kernel that took nothing
                raise OSError(errno.EIO, "write accepted no bytes", str(self.path))
            view = view[n:]

    def _fail(self, err: OSError) -> None:
        """Count a disk error and keep the first; recording stops after it."""
        self.errors += 1
        if self.error is None:
            self.error = err

    def close(self) -> None:
        """Flush, fsync and close (idempotent); a disk error is kept, not raised."""
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.flush()
            os.fsync(file.fileno())
        except OSError as err:
            self._fail(err)
        finally:
            try:
                file.close()
            except OSError as err:
                self._fail(err)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def read_raw(path: str | Path) -> RawRecording:
    """Read a whole raw recording (one read; records decoded with ``struct.unpack_from``).

    Raises:
        ReplayError: the file cannot be read or is not a regular file, its header is
            broken (wrong magic, unknown version, cut short, label not UTF-8) or a
            record has an unknown kind; the message names the file and the byte offset.
    """
    path = Path(path)
    blob = read_bytes(path)
    header, offset = _parse_header(path, blob)
    records: list[RawRecord] = []
    append = records.append
    size = len(blob)
    view = memoryview(blob)
    unpack_from = _RECORD.unpack_from
    record_size = _RECORD.size
    kind_of_byte = _KIND_OF_BYTE
    truncated_at: int | None = None
    prev_ns: int | None = None
    while offset < size:
        if size - offset < record_size:
            truncated_at = offset
            break
        t_ns, kind_byte, length = unpack_from(blob, offset)
        kind = kind_of_byte.get(kind_byte)
        if kind is None:
            msg = f"{path}: byte {offset + 8}: unknown record kind {kind_byte!r}"
            raise ReplayError(msg)
        start = offset + record_size
        end = start + length
        if end > size and prev_ns is not None and not prev_ns <= t_ns <= prev_ns + _MAX_GAP_NS:
            # A record cut by a kill keeps a plausible time; this is damage, not a kill.
            msg = (
                f"{path}: byte {offset}: a record running past the end of the file, its "
                f"time {t_ns} ns not within a day after the previous one ({prev_ns} ns): "
                "the file is corrupt here"
            )
            raise ReplayError(msg)
        if end > size:
            truncated_at = offset
            break
        if prev_ns is not None and t_ns < prev_ns:
            msg = (
                f"{path}: byte {offset}: record time {t_ns} ns is before the previous "
                f"record's ({prev_ns} ns): records out of time order, the file is damaged"
            )
            raise ReplayError(msg)
        prev_ns = t_ns
        append(RawRecord(t_ns, kind, bytes(view[start:end])))
        offset = end
    return RawRecording(path, header, records, size, truncated_at)


def _parse_header(path: Path, blob: bytes) -> tuple[RawHeader, int]:
    """Decode the header; return it and the offset of the first record."""
    magic = blob[: len(MAGIC)]
    if magic != MAGIC[: len(magic)]:
        msg = f"{path}: byte 0: not a raw recording (magic {magic!r}, expected {MAGIC!r})"
        raise ReplayError(msg)
    if len(blob) < _HEADER.size:
        msg = f"{path}: byte {len(blob)}: header cut short ({_HEADER.size} bytes at least)"
        raise ReplayError(msg)
    _, version, label_len, start_wall_ns, start_t_ns = _HEADER.unpack_from(blob, 0)
    if version != FORMAT_VERSION:
        msg = f"{path}: byte 8: unknown format version {version} (this reads {FORMAT_VERSION})"
        raise ReplayError(msg)
    end = _HEADER.size + label_len
    if len(blob) < end:
        msg = f"{path}: byte {len(blob)}: header cut short in the port label ({end} bytes)"
        raise ReplayError(msg)
    try:
        port_name = blob[_HEADER.size : end].decode("utf-8")
    except UnicodeDecodeError as err:
        msg = f"{path}: byte {_HEADER.size + err.start}: port label is not UTF-8"
        raise ReplayError(msg) from err
    return RawHeader(version, port_name, start_wall_ns, start_t_ns), end
