r"""SCIP 2.0 replies and the client's incremental reply parser (sans-I/O).

:class:`ReplyParser` is fed whatever the port delivered and returns the replies those bytes
completed (``protocols/scip2.md`` §2.2, §6 items 1-3):

- bytes are split into lines at LF, partial lines are kept across reads, and a reply ends
  at an empty line (``LF LF``);
- within the lines before that empty line, the reply starts at the first line that looks
  like an echo (two capital letters, printable ASCII) followed by a status line; lines in
  front of it are counted as garbage. If a candidate fails, the next one is tried, so a
  reply after garbage lines is still found;
- every sum is checked: status, timestamp, each info line (with or without the ``;``)
  and each data block. A reply with any bad sum is dropped whole and counted (SC-21);
  a character outside ``'0'..'o'`` under a good sum makes the reply malformed;
- a scan's blocks are joined before the values are split (SC-12), and the number of
  values is checked against the echo's start, end and cluster, so a lost block is caught.

Nothing fed to it raises: bad input only moves the counters in :attr:`ReplyParser.stats`,
and every byte is accounted for: ``bytes_in`` = the bytes of the good replies returned (LF
LF included) + ``discarded_bytes`` + :attr:`ReplyParser.buffered`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Final

import numpy as np

from mkflight.urg.codec import (
    BLOCK_CHARS,
    CHAR_OFFSET,
    SCIP2_COMMAND,
    IntArray,
    chars_per_value,
    decode_array,
    decode_value,
    is_success,
    status_message,
    sum_char,
    value_count,
)

MAX_LINE_BYTES: Final = 256  # the longest real line is ~70 bytes; longer is garbage
MAX_REPLY_LINES: Final = 64  # a full MD scan has 35 lines; older lines beyond are garbage
INFO_COMMANDS: Final = frozenset(("VV", "PP", "II"))

_ECHO_RE: Final = re.compile(rb"[A-Z]{2}[ -~]{0,46}")
_STATUS_RE: Final = re.compile(rb"[0-9A-Z]{2}")
_SCAN_ECHO_RE: Final = re.compile(r"(G[DS]|M[DS])(\d{4})(\d{4})(\d{2})(?:(\d)(\d{2}))?(;.*)?")

_LF: Final = 0x0A
#: The verdicts of a scan's blocks' decoder (:func:`mkflight.urg.kernel_numba.scan_blocks`).
BLOCKS_OK: Final = 0
BLOCKS_SUM: Final = 1  # a block's sum is wrong: the reply is dropped as a sum error
BLOCKS_MALFORMED: Final = 2  # a block of a wrong size, a bad character, a cut value
#: A scan's data blocks (joined by LF) and the characters of a value -> the verdict
#: (``BLOCKS_*``) and the values.
BlockDecoder = Callable[[bytes, int], tuple[int, IntArray]]
#: A byte sum modulo 256 to its sum character: its low 6 bits from '0' (§2.3).
_SUM_CHARS: Final = bytes(((s & 0x3F) + CHAR_OFFSET) for s in range(256))
_SUM: Final = "sum"
_MALFORMED: Final = "malformed"


@dataclass(frozen=True, slots=True)
class Reply:
    """A reply without data: the echo (as sent, no LF) and the status (§2.2).

    ``status`` is two characters, or ``"0"`` for the bare answer of a SCIP 1.1 sensor to
    ``SCIP2.0`` (SC-01).
    """

    echo: str
    status: str

    @property
    def command(self) -> str:
        """``"SCIP2.0"`` or the two command letters (``"MD"``)."""
        return SCIP2_COMMAND if self.echo.startswith(SCIP2_COMMAND) else self.echo[:2]

    @property
    def tag(self) -> str | None:
        """The ``;string`` the command carried, without the ``;`` (§2.1), or None."""
        _, sep, tag = self.echo.partition(";")
        return tag if sep else None

    @property
    def ok(self) -> bool:
        """The status means success for this command (see :func:`codec.is_success`)."""
        return is_success(self.command, self.status)

    @property
    def message(self) -> str:
        """The status in words (§4), e.g. ``"laser is off (send BM first)"``."""
        return status_message(self.command, self.status)

    def answers(self, request: bytes) -> bool:
        r"""Whether this reply answers ``request`` (the command bytes sent, LF included).

        The echo must equal the request without its terminator; a stream message of an
        MD/MS request matches with the count digits ignored, since the sensor writes the
        remaining count there (§3.2, §6 item 2).
        """
        sent = request.rstrip(b"\r\n").decode("ascii", errors="replace")
        if self.echo == sent:
            return True
        if self.command not in ("MD", "MS") or self.status == "00":
            return False
        ours, _, our_tag = self.echo.partition(";")
        theirs, _, their_tag = sent.partition(";")
        return (
            len(ours) == len(theirs) == 15
            and ours[:13] == theirs[:13]
            and our_tag == their_tag
            and ours[13:].isdigit()
        )


@dataclass(frozen=True, slots=True)
class InfoReply(Reply):
    """A VV/PP/II reply: its ``KEY:value`` lines as a dict (§3). Unknown keys are kept."""

    info: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class TimeReply(Reply):
    """A ``TM1`` reply: the sensor's 24-bit millisecond timer (§3)."""

    timestamp_ms: int = 0


def _no_values() -> IntArray:
    empty: IntArray = np.zeros(0, dtype=np.int64)
    empty.flags.writeable = False
    return empty


@dataclass(frozen=True, slots=True)
class ScanReply(Reply):
    """One scan: a GD/GS reply (status 00) or an MD/MS stream message (status 99).

    ``values_mm[j]`` is the raw value in mm of steps ``start_step + j*cluster`` onwards
    (error codes < 20 included: convert with :func:`mkflight.urg.units.ranges_m`), a
    read-only array: the driver converts a scan to metres without a Python int per beam;
    :attr:`values` gives them as a tuple. ``timestamp_ms`` is the 24-bit sensor time of
    step 0 (§3.3). ``remaining`` is the count the sensor wrote into an MD/MS echo (scans
    still to come, §3.2), else None. Two replies are equal when every field and every
    value is.
    """

    timestamp_ms: int = 0
    values_mm: IntArray = field(default_factory=_no_values, compare=False)
    start_step: int = 0
    end_step: int = 0
    cluster: int = 1
    remaining: int | None = None

    @property
    def values(self) -> tuple[int, ...]:
        """The raw values (mm) as Python ints."""
        return tuple(self.values_mm.tolist())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ScanReply) or other.__class__ is not self.__class__:
            return NotImplemented
        return (
            self.echo == other.echo
            and self.status == other.status
            and self.timestamp_ms == other.timestamp_ms
            and self.start_step == other.start_step
            and self.end_step == other.end_step
            and self.cluster == other.cluster
            and self.remaining == other.remaining
            and np.array_equal(self.values_mm, other.values_mm)
        )


AnyReply = Reply | InfoReply | TimeReply | ScanReply


@dataclass(slots=True)
class ParserStats:
    """Counters of everything the parser saw; the driver reports them (STYLE §2)."""

    bytes_in: int = 0
    replies: int = 0
    sum_errors: int = 0
    malformed: int = 0
    garbage_lines: int = 0
    overflows: int = 0
    discarded_bytes: int = 0  # every byte fed that did not end up in a good reply

    @property
    def dropped(self) -> int:
        """Replies dropped whole: a bad sum or a malformed body."""
        return self.sum_errors + self.malformed


class ReplyParser:
    """Incremental client decoder of SCIP 2.0 replies (see the module docstring)."""

    def __init__(self, decode_blocks: BlockDecoder | None = None) -> None:
        self.stats = ParserStats()
        #: the compiled :func:`~mkflight.urg.kernel_numba.scan_blocks` for a scan's data
        #: blocks (None: :func:`_scan_data` and :func:`decode_array`, with the same outcome)
        self.decode_blocks = decode_blocks
        self._partial = bytearray()  # an unfinished line
        self._lines: list[bytes] = []  # the complete lines of the reply being collected
        self._skipping = False  # inside an over-long line: drop bytes until LF

    @property
    def buffered(self) -> int:
        """Bytes held until more data arrives (an unfinished line or reply)."""
        return len(self._partial) + sum(len(line) + 1 for line in self._lines)

    def reset(self) -> None:
        """Forget a partial reply (after the port was re-opened), counting its lines."""
        self.stats.garbage_lines += len(self._lines) + bool(self._partial)
        self.stats.discarded_bytes += self.buffered
        self._partial.clear()
        self._lines.clear()
        self._skipping = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Reply]:
        """Consume ``data`` and return the complete, valid replies it finished."""
        data = bytes(data)
        stats = self.stats
        stats.bytes_in += len(data)
        out: list[Reply] = []
        pos = 0
        while True:
            if not self._partial and not self._skipping:
                pos = self._take_lines(data, pos, out)
            nl = data.find(b"\n", pos)
            if nl < 0:
                if self._skipping:
                    stats.discarded_bytes += len(data) - pos
                else:
                    self._partial += data[pos:]
                    if len(self._partial) > MAX_LINE_BYTES:
                        stats.overflows += 1
                        stats.discarded_bytes += len(self._partial)
                        self._partial.clear()
                        self._skipping = True
                return out
            chunk = data[pos:nl]
            pos = nl + 1
            if self._skipping:
                self._skipping = False  # the end of an over-long line
                stats.discarded_bytes += len(chunk) + 1
                continue
            if self._partial:
                self._partial += chunk
                line = bytes(self._partial)
                self._partial.clear()
            else:
                line = chunk
            if len(line) > MAX_LINE_BYTES:
                stats.overflows += 1
                stats.discarded_bytes += len(line) + 1
            elif line:
                self._lines.append(line)
                if len(self._lines) > MAX_REPLY_LINES:
                    stats.discarded_bytes += len(self._lines[0]) + 1
                    del self._lines[0]
                    stats.garbage_lines += 1
            elif self._lines:
                lines, self._lines = self._lines, []
                reply = self._finish(lines)
                if reply is not None:
                    out.append(reply)
            else:
                stats.discarded_bytes += 1  # an LF between replies

    def _take_lines(self, data: bytes, pos: int, out: list[Reply]) -> int:
        """Whole lines from ``pos`` on in bulk; returns where :meth:`feed`'s line loop goes on.

        The common case of that loop at the cost of a few C calls: the lines of a reply up
        to its empty line (then the reply is finished into ``out``), or the complete lines
        of an unfinished one (kept). Whatever the loop treats specially -- an empty line
        first, an over-long line, more lines than a reply holds -- is left to it, so both
        give the same replies and counters.
        """
        while pos < len(data) and data[pos] != _LF:
            end = data.find(b"\n\n", pos)
            cut = end if end >= 0 else data.rfind(b"\n", pos)
            if cut < 0:
                return pos
            lines = data[pos:cut].split(b"\n")
            if (
                len(self._lines) + len(lines) > MAX_REPLY_LINES
                or max(map(len, lines)) > MAX_LINE_BYTES
            ):
                return pos
            if end < 0:
                self._lines += lines
                return cut + 1
            if self._lines:
                lines = self._lines + lines
                self._lines = []
            pos = end + 2
            reply = self._finish(lines)
            if reply is not None:
                out.append(reply)
        return pos

    def _finish(self, lines: list[bytes]) -> Reply | None:
        """Find the reply in the lines of one ``LF LF``-terminated block, or count them."""
        stats = self.stats
        failure: tuple[int, str] | None = None
        for i in range(len(lines) - 1):
            if not _ECHO_RE.fullmatch(lines[i]):
                continue
            result = _parse(lines, i, self.decode_blocks)
            if isinstance(result, Reply):
                stats.garbage_lines += i
                stats.discarded_bytes += sum(len(line) + 1 for line in lines[:i])
                stats.replies += 1
                return result
            if result is not None and failure is None:
                failure = (i, result)
        stats.discarded_bytes += sum(len(line) + 1 for line in lines) + 1  # + the empty line
        if failure is None:
            stats.garbage_lines += len(lines)
            return None
        start, kind = failure
        stats.garbage_lines += start
        if kind == _SUM:
            stats.sum_errors += 1
        else:
            stats.malformed += 1
        return None


def _parse(lines: list[bytes], i: int, decode_blocks: BlockDecoder | None) -> Reply | str | None:
    """Parse the reply whose echo is ``lines[i]`` (``decode_blocks``: see :class:`ReplyParser`).

    Returns:
        The reply; ``"sum"`` or ``"malformed"`` if it is a reply but a bad one; None if
        ``lines[i + 1]`` is not a status line (so ``lines[i]`` is no echo).
    """
    echo = lines[i].decode("ascii")
    status_raw = lines[i + 1]
    body = lines[i + 2 :]
    if echo == SCIP2_COMMAND and status_raw == b"0":
        return Reply(echo, "0") if not body else _MALFORMED
    if len(status_raw) != 3 or not _STATUS_RE.fullmatch(status_raw[:2]):
        return None
    if sum_char(status_raw[:2]) != status_raw[2]:
        return _SUM
    status = status_raw[:2].decode("ascii")
    command = echo[:2]
    chars = chars_per_value(command)
    if chars is not None:
        expects_data = status == ("00" if command[0] == "G" else "99")
        if body:
            return _parse_scan(echo, status, body, chars, decode_blocks)
        return _MALFORMED if expects_data else Reply(echo, status)
    if not body:
        return Reply(echo, status)
    if command in INFO_COMMANDS:
        return _parse_info(echo, status, body)
    for line in body:
        if len(line) < 2 or sum_char(line[:-1]) != line[-1]:
            return _SUM
    if command == "TM" and len(body) == 1 and len(body[0]) == 5:
        try:
            return TimeReply(echo, status, decode_value(body[0][:4]))
        except ValueError:  # a good sum over characters outside '0'..'o'
            return _MALFORMED
    return Reply(echo, status)


def _parse_info(echo: str, status: str, body: list[bytes]) -> InfoReply | str:
    """``KEY:value;S`` lines; S covers ``KEY:value``, or the ``;`` too (§2.3)."""
    info: dict[str, str] = {}
    for line in body:
        if len(line) < 2:
            return _MALFORMED
        total = line[-1]
        if line[-2:-1] == b";":
            text = line[:-2]
            good = sum_char(text) == total or sum_char(line[:-1]) == total
        else:
            text = line[:-1]
            good = sum_char(text) == total
        if not good:
            return _SUM
        key, sep, value = text.decode("latin-1").partition(":")
        if sep:
            info[key] = value  # a line without ':' is an unknown extra: ignored (§6 item 9)
    return InfoReply(echo, status, info)


def _parse_scan(
    echo: str, status: str, body: list[bytes], chars: int, decode_blocks: BlockDecoder | None
) -> ScanReply | str:
    """Timestamp line, then data blocks joined before splitting the values (§2.5, §3.2)."""
    stamp = body[0]
    if len(stamp) != 5:
        return _MALFORMED
    if sum_char(stamp[:4]) != stamp[4]:
        return _SUM
    values: IntArray | None
    if decode_blocks is not None:
        verdict, values = decode_blocks(b"\n".join(body[1:]), chars)
        if verdict != BLOCKS_OK:
            return _SUM if verdict == BLOCKS_SUM else _MALFORMED
        values.flags.writeable = False
        fields = _scan_echo(echo)
        if fields is None:
            return _MALFORMED
    else:
        joined = _scan_data(body[1:])
        if isinstance(joined, str):
            return joined
        fields = _scan_echo(echo)
        if fields is None:
            return _MALFORMED
        values = decode_array(joined, chars)
    try:
        timestamp_ms = decode_value(stamp[:4])
    except ValueError:
        return _MALFORMED
    start, end, cluster, remaining = fields
    if values is None or end < start or len(values) != value_count(start, end, cluster):
        return _MALFORMED
    return ScanReply(
        echo,
        status,
        timestamp_ms=timestamp_ms,
        values_mm=values,
        start_step=start,
        end_step=end,
        cluster=cluster,
        remaining=remaining,
    )


@lru_cache(maxsize=16)
def _scan_echo(echo: str) -> tuple[int, int, int, int | None] | None:
    """Start, end, cluster and the remaining count of a GD/GS/MD/MS echo, None if malformed.

    (§3.1-3.2; a G echo has no scan interval and count, an M echo has both.) Every scan of
    a stream carries the same echo (the count stays 00 for an endless MD): remembered.
    """
    m = _SCAN_ECHO_RE.fullmatch(echo)
    if m is None or (m[5] is None) != (echo[0] == "G"):
        return None
    return int(m[2]), int(m[3]), int(m[4]), (int(m[6]) if m[6] is not None else None)


def _scan_data(blocks: list[bytes]) -> bytes | str:
    """The blocks' characters joined, each block's sum checked and stripped (§2.3, §2.5).

    Every block but the last holds 64 characters, the last 1 to 64 (else ``"malformed"``);
    each block's sum must hold (else ``"sum"``); the first failing block decides. The
    leading full blocks are checked together: their bytes as rows of 65 (64 characters
    and the sum), summed per row by numpy.
    """
    full = BLOCK_CHARS + 1
    last = len(blocks) - 1
    k = max(last, 0)  # every block but the last full (a scan's shape): checked in C
    if last > 0 and not min(map(len, blocks[:last])) == max(map(len, blocks[:last])) == full:
        k = 0
        while k < last and len(blocks[k]) == full:
            k += 1
    head = b""
    if k:
        joined = b"".join(blocks[:k])
        chars = np.frombuffer(joined, dtype=np.uint8).reshape(k, full)[:, :BLOCK_CHARS]
        # the byte sum modulo 256 keeps its low 6 bits: uint8 sums are exact enough; the
        # table turns each into its sum character, compared with every 65th byte
        sums = chars.sum(axis=1, dtype=np.uint8).tobytes().translate(_SUM_CHARS)
        if sums != joined[BLOCK_CHARS::full]:
            return _SUM
        head = chars.tobytes()
    if last < 0:
        return head
    block = blocks[k]  # the last block, or the first of a wrong size
    size = len(block) - 1
    if not 1 <= size <= BLOCK_CHARS or (k < last and size != BLOCK_CHARS):
        return _MALFORMED
    if sum_char(block[:-1]) != block[-1]:
        return _SUM
    return head + block[:-1]
