r"""Fuzzing (issue 10): seeded random streams through both parsers, the MK link and the URG driver.

Run: ``python tools/fuzz.py`` (``--frames N --scans N``, default 100000 each; ``--seed S``;
``--pty-frames N --pty-scans N`` for the pty passes, default 20000 and 5000; ``--json``).
Exit 0 only if every must-be-0 figure is 0; 1 otherwise; 2 on a usage error.

Streams are built from *pieces* whose effect on a parser is known exactly, whatever comes
before or after them, so a stream's expected counters are the sums of its pieces':

* MK (``mk-serial.md`` §3): valid frames of every kind the link knows (DebugOut, VersionInfo,
  ExternControl, Confirm, PPM, Label, the requests, the ``#dk`` MK3MAG frame, any address and
  command); frames with one byte changed (one CRC error each); truncated frames and ``'#'``
  look-alikes (abandoned at the next frame's ``'#'``); malformed frames (short, bad length, a
  character outside ``'='..'|'``, a bad address, all with a good checksum); overflows (170
  bytes without ``'\r'``); garbage runs (any byte but ``'#'``: CR, LF, payload characters).
* SCIP (``scip2.md`` §2, §6): valid replies of every kind the parser returns (GD/GS/MD/MS
  scans, status-only replies, the SCIP 1.1 ``0``, VV/PP/II with either sum rule, TM1, summed
  bodies); replies with one bad sum; scans cut short (then ``LF LF``); garbage lines in front
  of a reply; blocks of SCIP look-alikes (echoes, statuses, time stamps, data blocks, empty
  and over-long lines). Look-alikes never put an echo line right before a status line: SCIP
  has no start byte, and such a pair *is* a reply.

The pure passes feed the streams in random reads of 1 byte to 4 KiB and check every counter
after each batch. The pty passes run the real :class:`~mkflight.mk.link.MkLink` and
:class:`~mkflight.urg.driver.UrgDriver` on serialx over a :class:`~mkflight.io.pty.PtyDevice`:
units of pieces around one valid DebugOut / current-stream scan, written in chunks (each
awaited until the client has read it); the consumer must get every one of them, unchanged.
The MK consumer answers each sample with a fuzzed ExternControl (NaN, inf, 127.5, gas -1,
nick 128 ...); what the link writes is parsed on the FC's end and checked against the limits.

Figures per pass: tried (frame or scan pieces; for SCIP, status/info/time replies are mixed
in besides and counted in valid and found), valid (embedded), found, missed, exceptions
escaped, counter mismatches (a counter that differs from its pieces' sum, a failed identity
``bytes_in = good bytes + discarded_bytes + buffered``, a frame found that was not
embedded), out-of-limit commands (MK link), seconds.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import itertools
import json
import math
import random
import re
import struct
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Generic, TypeVar

import numpy as np

from mkflight.commands.progress import tty_bar
from mkflight.errors import CommandRangeError, LinkError
from mkflight.eventlog import configure_events
from mkflight.io.pty import PtyDevice
from mkflight.io.serial import open_serial
from mkflight.mk.codec import MAX_FRAME_BYTES, Frame, FrameParser, checksum, encode_frame
from mkflight.mk.codec import ParserStats as MkStats
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import (
    FORBIDDEN_COMMANDS,
    Confirm,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
    VersionInfo,
)
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug
from mkflight.sim.urg_answers import UrgIdentity, ii_lines, pp_lines, vv_lines
from mkflight.urg.codec import status_line, sum_char, timestamp_line, value_count
from mkflight.urg.driver import UrgDriver, UrgSettings
from mkflight.urg.replies import InfoReply, Reply, ReplyParser, ScanReply, TimeReply
from mkflight.urg.replies import ParserStats as UrgStats

T = TypeVar("T")
Advance = Callable[[int], None]
LF: Final = b"\n"


# ================================================================= pieces and their sums
@dataclass(frozen=True, slots=True)
class Piece(Generic[T]):
    """Bytes, the ``valid`` frames/replies in them (``sizes``: their bytes on the wire) and
    the exact increments of the parser's other ``counts``; every other byte is discarded.
    The parser is idle before and after a piece."""

    data: bytes
    valid: tuple[T, ...] = ()
    sizes: tuple[int, ...] = ()
    counts: tuple[tuple[str, int], ...] = ()


def join(pieces: Iterable[Piece[T]]) -> Piece[T]:
    """One piece of several, in order."""
    items = list(pieces)
    counts: Counter[str] = Counter()
    for p in items:
        counts.update(dict(p.counts))
    return Piece(
        b"".join(p.data for p in items),
        tuple(v for p in items for v in p.valid),
        tuple(s for p in items for s in p.sizes),
        tuple(sorted(counts.items())),
    )


@dataclass(slots=True)
class Totals:
    """Sums over the pieces fed: what the parser's counters must read."""

    fed: int = 0
    valid: int = 0
    valid_bytes: int = 0
    counts: Counter[str] = field(default_factory=Counter)

    def add(self, piece: Piece[Any]) -> None:
        self.fed += len(piece.data)
        self.valid += len(piece.valid)
        self.valid_bytes += sum(piece.sizes)
        self.counts.update(dict(piece.counts))


MK_COUNTS: Final = ("crc_errors", "malformed", "overflows")
URG_COUNTS: Final = ("sum_errors", "malformed", "garbage_lines", "overflows")


def check(
    stats: MkStats | UrgStats,
    totals: Totals,
    found_bytes: int,
    buffered: int = 0,
    base: MkStats | UrgStats | None = None,
) -> list[str]:
    """A parser's counters (minus those of ``base``) against the pieces' sums; empty if they
    add up. ``found_bytes``: the wire bytes of the good frames/replies it returned;
    ``buffered``: the bytes it holds (pieces end with the parser idle: 0)."""
    got = dataclasses.asdict(stats)
    if base is not None:
        got = {k: v - dataclasses.asdict(base)[k] for k, v in got.items()}
    mk = isinstance(stats, MkStats)
    want = {
        "bytes_in": totals.fed,
        "frames" if mk else "replies": totals.valid,
        **{k: totals.counts[k] for k in (MK_COUNTS if mk else URG_COUNTS)},
        "discarded_bytes": totals.fed - totals.valid_bytes - buffered,
    }
    out = [f"{k} = {got[k]}, want {v}" for k, v in want.items() if got[k] != v]
    if found_bytes + got["discarded_bytes"] + buffered != got["bytes_in"]:
        out.append(
            f"{got['bytes_in']} bytes in != {found_bytes} good + "
            f"{got['discarded_bytes']} discarded + {buffered} buffered"
        )
    return out


def frame_bytes(frame: Frame) -> int:
    """Wire size of a decoded frame: '#', addr, cmd, 4 chars per 3 bytes, CRC, CR (§2)."""
    return 6 + len(frame.payload) * 4 // 3


def split(data: bytes, cuts: Iterable[int]) -> list[bytes]:
    """``data`` cut at the given offsets (taken modulo its length)."""
    points = sorted({c % len(data) for c in cuts} - {0}) if data else []
    return [data[a:b] for a, b in itertools.pairwise([0, *points, len(data)])]


# ================================================================= MK pieces (mk-serial.md)
_START, _END = 0x23, 0x0D
_NO_START = bytes(range(256)).replace(b"#", b"$")
_NO_START_END = _NO_START.replace(b"\r", b"\x0e")
_CHARS = bytes(range(0x3D, 0x7D))  # '='..'|': the payload alphabet (§2.2)


def _pad3(payload: bytes) -> bytes:
    return payload + bytes(-len(payload) % 3)


def mk_frame(addr: int, cmd: str, payload: bytes = b"") -> Piece[Frame]:
    """A valid frame of any address and command (the codec's generic frame)."""
    data = encode_frame(addr, cmd, payload)
    return Piece(data, (Frame(addr, cmd, _pad3(payload)),), (len(data),))


MkMessage = DebugOut | VersionInfo | ExternControl | Confirm | Ppm | Label


def mk_message(msg: MkMessage) -> Piece[Frame]:
    """A message as its ``encode()`` writes it; the frame expected from its layout (§5-6)."""
    if isinstance(msg, DebugOut):
        cmd, payload = "D", bytes(msg.status) + struct.pack("<32h", *msg.analog)
    elif isinstance(msg, VersionInfo):
        head = (msg.sw_major, msg.sw_minor, msg.proto_major, msg.proto_minor, msg.sw_patch)
        cmd, payload = "V", bytes(head) + msg.hardware_error.ljust(5, b"\0")[:5]
    elif isinstance(msg, ExternControl):
        cmd, payload = "b", msg.pack()
    elif isinstance(msg, Confirm):
        cmd, payload = "B", bytes((int(msg.frame),))
    elif isinstance(msg, Ppm):
        cmd, payload = "P", struct.pack("<26h", *msg.channels)
    else:
        cmd, payload = "A", bytes((msg.index,)) + msg.label.encode("ascii")[:16].ljust(16, b" ")
    data = msg.encode()
    return Piece(data, (Frame(msg.addr, cmd, _pad3(payload)),), (len(data),))


def mk_corrupt(valid: Piece[Frame], index: int, new: int) -> Piece[Frame]:
    """A valid frame with one byte after '#' and before CR changed: one CRC error."""
    data = valid.data
    i = 1 + index % (len(data) - 2)
    b = new % 256
    while b in (_START, _END, data[i]):
        b = (b + 1) % 256
    return Piece(data[:i] + bytes((b,)) + data[i + 1 :], counts=(("crc_errors", 1),))


def mk_truncated(frame: bytes, cut: int, then: Piece[Frame]) -> Piece[Frame]:
    """The first bytes of ``frame`` (no CR), abandoned at the '#' of ``then``."""
    assert then.data[:1] == b"#"
    return join([Piece(frame[: 1 + cut % (len(frame) - 1)]), then])


def mk_lookalike(noise: bytes, then: Piece[Frame]) -> Piece[Frame]:
    """'#' and up to 168 bytes of noise (no '#', no CR): abandoned at ``then``'s '#'."""
    assert then.data[:1] == b"#"
    return join([Piece(b"#" + noise.translate(_NO_START_END)[: MAX_FRAME_BYTES - 2]), then])


def mk_overflow(noise: bytes, extra: int) -> Piece[Frame]:
    """'#' and 169 + ``extra`` bytes without '#' or CR: one overflow, the rest garbage."""
    body = (noise or b"x").translate(_NO_START_END)
    n = MAX_FRAME_BYTES - 1 + extra % 400
    return Piece(b"#" + (body * (n // len(body) + 1))[:n], counts=(("overflows", 1),))


def mk_malformed(variant: int, noise: bytes, cmd: int) -> Piece[Frame]:
    """A frame the parser must reject although its checksum is good: one malformed frame.

    ``variant`` % 4: 0 shorter than 6 bytes; 1 a payload length not a multiple of 4; 2 a
    payload character outside '='..'|'; 3 an address byte outside 'a'..'a'+63.
    """
    kind = variant % 4
    if kind == 0:
        return Piece(b"#" + noise[:3].translate(_NO_START_END) + b"\r", counts=(("malformed", 1),))
    chars = bytes(_CHARS[b % 64] for b in noise[:156])
    c = bytes((cmd % 256,)).translate(_NO_START_END)
    whole = chars[: len(chars) // 4 * 4]
    if kind == 1:
        head = b"#b" + c + (whole + b"===")[: len(whole) + 1 + variant // 4 % 3]
    elif kind == 2:
        whole = whole or b"===="
        bad = bytes((noise[-1] if noise and noise[-1] not in _CHARS else 0x7E,))
        i = variant // 4 % len(whole)
        head = b"#b" + c + whole[:i] + bad.translate(_NO_START_END) + whole[i + 1 :]
    else:
        addr = 0xA1 + variant // 4 % 95 if variant % 8 == 3 else variant // 4 % 0x61
        head = b"#" + bytes((addr,)).translate(_NO_START_END) + c + whole
    return Piece(head + checksum(head) + b"\r", counts=(("malformed", 1),))


def mk_garbage(noise: bytes) -> Piece[Frame]:
    """Bytes without '#' (CR, LF, payload characters, anything else): all discarded."""
    return Piece(noise.translate(_NO_START))


# ================================================================= SCIP pieces (scip2.md)
_ECHO_LIKE: Final = re.compile(rb"[A-Z]{2}[ -~]{0,46}")
_STATUS_LIKE: Final = re.compile(rb"[0-9A-Z]{2}.", re.DOTALL)
_SHIFTS: Final = {2: np.array([6, 0]), 3: np.array([12, 6, 0])}


def _pairs_reply(a: bytes, b: bytes) -> bool:
    """``a`` then ``b`` is what the parser takes for an echo and its status (§2.2)."""
    if a == b"SCIP2.0" and b == b"0":
        return True
    return bool(_ECHO_LIKE.fullmatch(a)) and bool(_STATUS_LIKE.fullmatch(b))


def _summed(text: bytes) -> bytes:
    return text + bytes((sum_char(text),))


def _info_ok(line: bytes) -> bool:
    """An info line's sum holds under either rule (with or without the ';', §2.3)."""
    if len(line) < 2:
        return False
    if line[-2:-1] == b";":
        return line[-1] in (sum_char(line[:-2]), sum_char(line[:-1]))
    return sum_char(line[:-1]) == line[-1]


def _lines(lines: Iterable[bytes]) -> bytes:
    """Lines and the empty line that ends a reply."""
    return b"".join(line + LF for line in lines) + LF


@dataclass(frozen=True, slots=True)
class Scip:
    """A reply as the sensor sends it: its lines (no LF), each line's kind, what it parses to.

    Kinds: ``echo``; ``status`` (2 characters and a sum); ``bare`` (the SCIP 1.1 ``0``);
    ``summed`` (time stamp, data block, body line: the last character sums the others);
    ``info`` (``KEY:value;S``).
    """

    lines: tuple[bytes, ...]
    kinds: tuple[str, ...]
    expected: Reply

    def piece(self) -> Piece[Reply]:
        data = _lines(self.lines)
        return Piece(data, (self.expected,), (len(data),))


def scip_status(echo: str, status: str) -> Scip:
    """A reply without data: ``echo LF status sum LF LF``."""
    return Scip((echo.encode(), status_line(status)), ("echo", "status"), Reply(echo, status))


def scip1_switch() -> Scip:
    """A SCIP 1.1 sensor's answer to ``SCIP2.0``: a bare ``0`` (SC-01)."""
    return Scip((b"SCIP2.0", b"0"), ("echo", "bare"), Reply("SCIP2.0", "0"))


def scip_info(echo: str, entries: Sequence[tuple[str, int]]) -> Scip:
    """VV/PP/II lines ``(text, rule)``: rule 0 sums the text, 1 the text and ';', 2 has no ';'.

    Texts have no ';' or LF; one without ':' is an unknown extra line, ignored (§6 item 9).
    Without lines it is a status-only reply.
    """
    lines, info = [echo.encode(), status_line("00")], {}
    for text, rule in entries:
        raw = text.encode("latin-1")
        if rule % 3 == 2 and raw:
            lines.append(_summed(raw))
        else:
            lines.append(raw + b";" + bytes((sum_char(raw + b";" * (rule % 3 == 1)),)))
        key, sep, value = text.partition(":")
        if sep:
            info[key] = value
    kinds = ("echo", "status", *["info"] * (len(lines) - 2))
    expected = InfoReply(echo, "00", info=info) if entries else Reply(echo, "00")
    return Scip(tuple(lines), kinds, expected)


def scip_time(ms: int, tag: str = "") -> Scip:
    """``TM1``: the sensor's 24-bit timer."""
    echo = "TM1" + (f";{tag}" if tag else "")
    lines = (echo.encode(), status_line("00"), timestamp_line(ms))
    return Scip(lines, ("echo", "status", "summed"), TimeReply(echo, "00", timestamp_ms=ms))


def scip_body(echo: str, status: str, bodies: Sequence[bytes]) -> Scip:
    """A reply with summed lines the parser does not read (neither scan, info nor TM1)."""
    lines = [echo.encode(), status_line(status), *(_summed(b or b"x") for b in bodies)]
    return Scip(tuple(lines), ("echo", "status", *["summed"] * len(bodies)), Reply(echo, status))


def scip_scan(
    cmd: str,
    steps: tuple[int, int, int],
    values: Sequence[int] | np.ndarray[Any, Any],
    stamp_ms: int,
    *,
    interval: int = 0,
    remaining: int = 0,
    tag: str = "",
) -> Scip:
    """A GD/GS reply (status 00) or an MD/MS stream message (status 99) (§2.5, §3.2).

    ``steps`` is (start, end, cluster); ``values`` must be ``value_count`` of them.
    """
    start, end, cluster = steps
    chars = 3 if cmd[1] == "D" else 2
    stream = cmd[0] == "M"
    v = np.asarray(values, dtype=np.int64) & ((1 << (6 * chars)) - 1)
    assert len(v) == value_count(start, end, cluster)
    echo = f"{cmd}{start:04d}{end:04d}{cluster:02d}"
    echo += (f"{interval}{remaining:02d}" if stream else "") + (f";{tag}" if tag else "")
    status = "99" if stream else "00"
    text = (((v[:, None] >> _SHIFTS[chars]) & 0x3F) + 0x30).astype(np.uint8).tobytes()
    blocks = [_summed(text[i : i + 64]) for i in range(0, len(text), 64)]
    expected = ScanReply(
        echo,
        status,
        timestamp_ms=stamp_ms,
        values=tuple(v.tolist()),
        start_step=start,
        end_step=end,
        cluster=cluster,
        remaining=remaining if stream else None,
    )
    lines = (echo.encode(), status_line(status), timestamp_line(stamp_ms), *blocks)
    return Scip(lines, ("echo", "status", *["summed"] * (len(blocks) + 1)), expected)


def _no_reply_inside(lines: Sequence[bytes]) -> bool:
    """No line pair after the echo that the parser could take for another reply."""
    return not any(_pairs_reply(a, b) for a, b in itertools.pairwise(lines[1:]))


def scip_corrupt(reply: Scip, which: int, pos: int, new: int) -> Piece[Reply] | None:
    """A reply with one character of a summed line (not the echo) changed so that the sum
    fails: one sum error (SC-21). None if it has no sum, or could then hold another reply."""
    choices = [i for i, k in enumerate(reply.kinds) if k in ("status", "summed", "info")]
    if not choices:
        return None
    j = choices[which % len(choices)]
    line, kind = reply.lines[j], reply.kinds[j]
    p = 2 if kind == "status" else pos % len(line)
    for step in range(256):
        b = (new + step) % 256
        same_sum = kind == "summed" and p < len(line) - 1 and (b - line[p]) % 64 == 0
        if b in (0x0A, line[p]) or same_sum:
            continue
        bad = line[:p] + bytes((b,)) + line[p + 1 :]
        if kind == "info" and _info_ok(bad):
            continue
        lines = (*reply.lines[:j], bad, *reply.lines[j + 1 :])
        if not _no_reply_inside(lines):
            return None
        return Piece(_lines(lines), counts=(("sum_errors", 1),))
    return None


def scip_malformed(reply: Scip, which: int, pos: int, new: int) -> Piece[Reply] | None:
    """A scan or TM1 reply with a character outside '0'..'o' in its time stamp or a data
    block, under a good sum: one malformed reply. None if it could then hold another."""
    assert isinstance(reply.expected, ScanReply | TimeReply), "only scans and TM1 decode data"
    j = [i for i, k in enumerate(reply.kinds) if k == "summed"][which % (len(reply.lines) - 2)]
    line = reply.lines[j]
    p = pos % (len(line) - 1)
    b = new % 256 if not (0x30 <= new % 256 < 0x70 or new % 256 == 0x0A) else 0x7F
    bad = _summed(line[:p] + bytes((b,)) + line[p + 1 : -1])
    lines = (*reply.lines[:j], bad, *reply.lines[j + 1 :])
    if not _no_reply_inside(lines):
        return None
    return Piece(_lines(lines), counts=(("malformed", 1),))


def scip_truncated(reply: Scip, line: int, chars: int) -> Piece[Reply] | None:
    """A scan cut after ``chars`` characters of line ``line``, then ``LF LF`` (§6 item 1).

    A cut echo or status is garbage lines; a scan without its time stamp or with blocks
    missing is malformed; a cut block's last character is taken for its sum (a sum error, or
    malformed if it happens to match). None if nothing is cut or the rest could hold a reply.
    """
    assert isinstance(reply.expected, ScanReply), "only scans are cut"
    j = line % len(reply.lines)
    m = chars % (len(reply.lines[j]) + 1)
    cut = [*reply.lines[:j], *([reply.lines[j][:m]] if m else [])]
    if not cut or cut == list(reply.lines) or not _no_reply_inside(cut):
        return None
    data, last = _lines(cut), cut[-1]
    if len(cut) == 1 or len(cut[1]) != 3:
        return Piece(data, counts=(("garbage_lines", len(cut)),))
    if len(cut) <= 3 or len(cut[2]) != 5 or len(last) < 2:
        return Piece(data, counts=(("malformed", 1),))
    kind = "sum_errors" if sum_char(last[:-1]) != last[-1] else "malformed"
    return Piece(data, counts=((kind, 1),))


def _garbage(lines: Iterable[bytes], *, lookalikes: bool) -> Piece[Reply]:
    """Lines (LF removed) with their counts. Without ``lookalikes`` no line looks like an
    echo; with, only the echo/status pairs are broken up. An empty line ends a block."""
    out, counts, prev = bytearray(), Counter[str](), b""
    for raw in lines:
        line = raw.replace(LF, b"")
        harmful = _pairs_reply(prev, line) if lookalikes else _ECHO_LIKE.fullmatch(line)
        if harmful:
            line = b"~" + line
        out += line + LF
        if not line:
            prev = b""
        elif len(line) > 256:
            counts["overflows"] += 1
        else:
            counts["garbage_lines"] += 1
            prev = line
    return Piece(bytes(out), counts=tuple(sorted(counts.items())))


def scip_after_garbage(lines: Iterable[bytes], then: Piece[Reply]) -> Piece[Reply]:
    """Garbage lines, none like an echo, in front of ``then`` in its block (§6 item 2);
    ``then`` ends the block (a reply, a garbage block, or just an LF)."""
    assert then.data[-1:] == LF, "the garbage lines would still be held"
    return join([_garbage(lines, lookalikes=False), then])


def scip_garbage_block(lines: Iterable[bytes]) -> Piece[Reply]:
    """SCIP look-alike lines ended by an empty line: all garbage."""
    return join([_garbage(lines, lookalikes=True), Piece(LF)])


# ================================================================= seeded random pieces
_EDGE16: Final = (-32768, -32767, -1, 0, 1, 32766, 32767)
_MK_NOISE: Final = b"\r\n\r\n=>?@|{}~bBdDvV \x00\xff"
_TAG_CHARS: Final = "ABCXYZabcxyz0123456789 ._+@"
_LETTERS: Final = "ABCDEFHJKLNOQRSUWXYZ"  # no G, I, M, P, T, V: no scan, info or TM echo
_PRINTABLE: Final = "".join(chr(c) for c in range(0x20, 0x7F) if chr(c) != ";")
_STATUS_REPLIES: Final = (
    ("BM", "00"), ("BM", "02"), ("QT", "00"), ("RS", "00"), ("TM0", "00"), ("TM2", "00"),
    ("TM2", "03"), ("SS115200", "00"), ("SS038400", "02"), ("CR03", "00"), ("ZZ", "0E"),
    ("SCIP2.0", "0E"), ("GD0044072501", "10"), ("GD0725004401", "05"), ("GS0044080001", "04"),
    ("MD00440725010x3", "07"), ("MS0044072501100;g7", "00"), ("MD0044072501000;g3", "21"),
)  # fmt: skip
_WHO: Final = UrgIdentity()
_INFO: Final = {
    "VV": vv_lines(_WHO),
    "PP": pp_lines(_WHO),
    "II": ii_lines(_WHO, laser_on=False, timer_ms=0x6A55F8),
}
_SCIP_NOISE: Final = (
    b"MD0044072501000;g1", b"GD0044072501", b"VV", b"SCIP2.0", b"QT", b"00P", b"99b", b"0Ee",
    b"0", b"JUGnD", b"", b"", b"\r", b"DMIN:20;4", b"1Dh00C000@", b"0" * 64 + b"P", b"x" * 300,
)  # fmt: skip


def _noise(rng: random.Random, n: int, alphabet: bytes) -> bytes:
    return bytes(
        rng.choice(alphabet) if rng.random() < 0.5 else rng.randrange(256) for _ in range(n)
    )


def _length(rng: random.Random, mean: int) -> int:
    return min(int(rng.expovariate(1 / mean)), 40 * mean)


def _tag(rng: random.Random) -> str:
    if rng.random() < 0.5:
        return ""
    return "".join(rng.choice(_TAG_CHARS) for _ in range(rng.randrange(17)))


def random_debug(rng: random.Random, addr: int = 1) -> DebugOut:
    """A DebugOut with random values, a tenth of them at the int16 edges."""
    analog = tuple(
        rng.choice(_EDGE16) if rng.random() < 0.1 else rng.randint(-2000, 2000) for _ in range(32)
    )
    return DebugOut(status=(rng.randrange(256), rng.randrange(256)), analog=analog, addr=addr)


def random_mk_valid(rng: random.Random) -> Piece[Frame]:
    """A valid frame of a random kind, mostly to the FC's address."""
    a = 1 if rng.random() < 0.8 else rng.randrange(64)
    kind, u8 = rng.randrange(10), rng.randrange
    if kind == 0:
        return mk_message(random_debug(rng, a))
    if kind == 1:
        hw = bytes(5) if rng.random() < 0.7 else rng.randbytes(5)
        return mk_message(VersionInfo(u8(256), u8(256), u8(256), u8(256), u8(256), hw, a))
    if kind == 2:
        nick, roll, yaw, height = (rng.randint(-128, 127) for _ in range(4))
        ec = ExternControl(nick, roll, yaw, u8(256), height, u8(256), u8(256), (u8(256), 0))
        return mk_message(dataclasses.replace(ec, addr=a))
    if kind == 3:
        return mk_message(Confirm(u8(256), a))
    if kind == 4:
        return mk_message(Ppm(tuple(rng.randint(-32768, 32767) for _ in range(26)), a))
    if kind == 5:
        text = "".join(rng.choice("AngleNick Voltage[0.1V]") for _ in range(u8(17)))
        return mk_message(Label(u8(32), text, a))
    if kind == 6:
        cmd = rng.choice("vdapb")
        return mk_frame(1, cmd, rng.randbytes({"v": 0, "p": 0, "b": 11}.get(cmd, 1)))
    if kind == 7:
        return mk_frame(3, "k", rng.randbytes(8))
    cmd = chr(rng.choice([c for c in range(0x20, 0x7F) if c != _START]))
    return mk_frame(a, cmd, rng.randbytes(u8(124)))


def random_mk_piece(
    rng: random.Random, valid: Callable[[], Piece[Frame]], budget: int
) -> tuple[Piece[Frame], int]:
    """Maybe a garbage run, then a frame piece, valid or not; and how many frames it tried
    (a truncated frame and the frame that abandons it are two, if ``budget`` allows)."""
    head: Piece[Frame] = Piece(b"")
    if rng.random() < 0.5:
        head = mk_garbage(_noise(rng, _length(rng, 20), _MK_NOISE))
    r, frame = rng.random(), random_mk_valid(rng)
    if r < 0.55:
        return join([head, valid()]), 1
    if r < 0.70:
        return join([head, mk_corrupt(frame, rng.randrange(1 << 16), rng.randrange(256))]), 1
    if r < 0.78 and budget >= 2:
        return join([head, mk_truncated(frame.data, rng.randrange(1 << 16), valid())]), 2
    if r < 0.82:
        noise = _noise(rng, rng.randrange(169), _MK_NOISE)
        return join([head, mk_lookalike(noise, valid())]), 1
    if r < 0.97:
        noise = _noise(rng, rng.randrange(1, 200), _MK_NOISE)
        return join([head, mk_malformed(rng.randrange(1 << 16), noise, rng.randrange(256))]), 1
    noise = _noise(rng, rng.randrange(1, 40), _MK_NOISE)
    return join([head, mk_overflow(noise, rng.randrange(400))]), 1


def random_values(np_rng: np.random.Generator, n: int, chars: int) -> np.ndarray[Any, Any]:
    """Ranges as a URG sends them: mostly 20..5600 mm, some error codes, some up to the max."""
    u = np_rng.random(n)
    values = np.where(u < 0.1, np_rng.integers(0, 20, n), np_rng.integers(20, 5601, n))
    return np.where(u > 0.97, np_rng.integers(0, 1 << (6 * chars), n), values)


def random_scan(rng: random.Random, np_rng: np.random.Generator) -> Scip:
    """A GD/GS/MD/MS scan: a fifth full (steps 44-725), the rest random ranges and clusters."""
    cmd = rng.choice(("MD", "MD", "MS", "GD", "GD", "GS"))
    if rng.random() < 0.2:
        steps = (44, 725, 1)
    else:
        start = rng.randrange(769)
        steps = (start, min(768, start + _length(rng, 60)), rng.choice((0, 1, 1, 2, 3, 99)))
    n = value_count(*steps)
    return scip_scan(
        cmd,
        steps,
        random_values(np_rng, n, 3 if cmd[1] == "D" else 2),
        rng.randrange(1 << 24),
        interval=rng.randrange(10),
        remaining=rng.randrange(100),
        tag=_tag(rng),
    )


def random_other_reply(rng: random.Random) -> Scip:
    """A reply that is not a scan: status only, SCIP 1.1 ``0``, VV/PP/II, TM1, summed body."""
    kind = rng.randrange(6)
    if kind == 0:
        return scip_status(*rng.choice(_STATUS_REPLIES))
    if kind == 1:
        return scip1_switch()
    if kind == 2:
        cmd = rng.choice(("VV", "PP", "II"))
        entries = [(f"{k}:{v}", rng.randrange(3)) for k, v in _INFO[cmd]]
        for _ in range(rng.randrange(3)):
            text = "".join(rng.choice(_PRINTABLE) for _ in range(rng.randrange(1, 40)))
            entries.append((text, rng.randrange(3)))
        rng.shuffle(entries)
        return scip_info(cmd, entries)
    if kind == 3:
        return scip_time(rng.randrange(1 << 24), _tag(rng))
    echo = "".join(rng.choice(_LETTERS) for _ in range(2))
    echo += "".join(rng.choice(_PRINTABLE) for _ in range(rng.randrange(10)))
    status = rng.choice(("00", "0E", "01", "10", "99", "5A"))
    if kind == 4:
        return scip_status(echo, status)
    bodies = [rng.randbytes(rng.randrange(1, 40)).replace(LF, b".") for _ in range(3)]
    return scip_body(echo, status, bodies)


def random_garbage_lines(rng: random.Random, mean: int) -> list[bytes]:
    """SCIP look-alike and random lines (some empty, some over 256 bytes)."""
    return [
        rng.choice(_SCIP_NOISE) if rng.random() < 0.6 else rng.randbytes(_length(rng, 30))
        for _ in range(_length(rng, mean))
    ]


def random_bad_scan(rng: random.Random, scan: Scip) -> Piece[Reply] | None:
    """``scan`` with a bad sum, cut short, or with a bad character under a good sum (None
    if the draw cannot be)."""
    r, which, pos, new = rng.random(), rng.randrange(64), rng.randrange(64), rng.randrange(256)
    if r < 0.45:
        return scip_corrupt(scan, which, pos, new)
    if r < 0.9:
        return scip_truncated(scan, rng.randrange(len(scan.lines)), rng.randrange(70))
    return scip_malformed(scan, which, pos, new)


def _maybe_after_garbage(rng: random.Random, piece: Piece[Reply]) -> Piece[Reply]:
    if rng.random() < 0.3:
        lines = [rng.randbytes(_length(rng, 20)) for _ in range(rng.randrange(4))]
        return scip_after_garbage(lines, piece)
    return piece


def random_scan_piece(rng: random.Random, scan: Scip) -> Piece[Reply]:
    """``scan`` valid (60 %), with a bad sum or cut short; maybe after garbage lines."""
    bad = random_bad_scan(rng, scan) if rng.random() < 0.4 else None
    return _maybe_after_garbage(rng, bad or scan.piece())


def random_urg_extras(rng: random.Random) -> Piece[Reply]:
    """What comes between scans: maybe a block of look-alikes, maybe another reply."""
    parts: list[Piece[Reply]] = []
    if rng.random() < 0.3:
        parts.append(scip_garbage_block(random_garbage_lines(rng, 4)))
    if rng.random() < 0.15:
        parts.append(random_other_reply(rng).piece())
    if rng.random() < 0.02:  # a TM1 time with a bad character under a good sum
        tm = scip_time(rng.randrange(1 << 24))
        parts.append(scip_malformed(tm, 0, rng.randrange(4), rng.randrange(256)) or tm.piece())
    return join(parts)


def random_chunks(rng: random.Random, data: bytes, most: int = 4096) -> Iterator[bytes]:
    """``data`` in reads of 1 byte to ``most`` bytes (mostly small, like a serial port's)."""
    pos = 0
    while pos < len(data):
        r = rng.random()
        n = (
            rng.randint(1, 8)
            if r < 0.1
            else rng.randint(1, 128)
            if r < 0.8
            else rng.randint(129, most)
        )
        yield data[pos : pos + n]
        pos += n


# ================================================================= results
@dataclass(slots=True)
class PassResult:
    """The figures of one pass."""

    name: str
    tried: int = 0
    valid: int = 0
    found: int = 0
    missed: int = 0
    exceptions: int = 0
    mismatches: int = 0
    out_of_limit: int | None = None
    seconds: float = 0.0
    notes: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        return bool(self.missed or self.exceptions or self.mismatches or self.out_of_limit)

    def mismatch(self, where: str, what: Sequence[str]) -> None:
        self.mismatches += len(what)
        self.problems.extend(f"{where}: {w}" for w in what[: max(0, 10 - len(self.problems))])

    def exception(self, err: BaseException, data: bytes) -> None:
        self.exceptions += 1
        if len(self.problems) < 10:
            self.problems.append(f"{err!r} escaped, fed {data[:120]!r}")

    def as_dict(self) -> dict[str, Any]:
        return {
            "pass": self.name,
            "tried": self.tried,
            "valid": self.valid,
            "found": self.found,
            "missed": self.missed,
            "exceptions": self.exceptions,
            "counter_mismatches": self.mismatches,
            "out_of_limit_commands": self.out_of_limit,
            "seconds": round(self.seconds, 2),
            "notes": self.notes,
            "problems": self.problems,
        }


class Matcher(Generic[T]):
    """Found items against the expected ones, in order: found, missed, unexpected."""

    def __init__(self, window: int = 64) -> None:
        self._expected: deque[tuple[T, int]] = deque()
        self._window = window
        self.found = self.missed = self.unexpected = self.found_bytes = 0

    def expect(self, piece: Piece[T]) -> None:
        self._expected.extend(zip(piece.valid, piece.sizes, strict=True))

    def saw(self, item: T) -> None:
        for j, (want, size) in enumerate(itertools.islice(self._expected, self._window)):
            if want == item:
                self.missed += j
                for _ in range(j + 1):
                    self._expected.popleft()
                self.found += 1
                self.found_bytes += size
                return
        self.unexpected += 1

    def finish(self) -> None:
        self.missed += len(self._expected)
        self._expected.clear()


# ================================================================= the pure passes
def _feed_pass(
    name: str,
    parser: FrameParser | ReplyParser,
    batches: Iterator[tuple[Piece[Any], int]],
    rng: random.Random,
    advance: Advance,
) -> PassResult:
    """Feed each batch in random reads; match what comes out; check the counters per batch."""
    result = PassResult(name)
    started = time.perf_counter()
    match: Matcher[Any] = Matcher()
    totals = Totals()
    kinds: Counter[str] = Counter()
    for piece, tried in batches:
        kinds.update(f"valid {type(v).__name__}" for v in piece.valid)
        before = dataclasses.replace(parser.stats)
        bytes_before, batch = match.found_bytes, Totals()
        batch.add(piece)
        totals.add(piece)
        match.expect(piece)
        for chunk in random_chunks(rng, piece.data):
            try:
                out: Sequence[Any] = parser.feed(chunk)
            except Exception as err:  # the figure this pass is for
                result.exception(err, chunk)
                continue
            for item in out:
                match.saw(item)
        found_bytes = match.found_bytes - bytes_before
        result.mismatch(name, check(parser.stats, batch, found_bytes, parser.buffered, before))
        result.tried += tried
        advance(tried)
    match.finish()
    if match.unexpected:
        result.mismatch(name, [f"{match.unexpected} found that were not embedded"])
    result.mismatch(name, check(parser.stats, totals, match.found_bytes, parser.buffered))
    result.valid, result.found, result.missed = totals.valid, match.found, match.missed
    result.notes = {k: v for k, v in dataclasses.asdict(parser.stats).items() if v}
    if len(kinds) > 1:
        result.notes.update(sorted(kinds.items()))
    result.seconds = time.perf_counter() - started
    return result


def run_mk_parser(n: int, rng: random.Random, advance: Advance = lambda k: None) -> PassResult:
    """``n`` frame pieces (valid, corrupted, truncated, malformed ...) through FrameParser."""

    def batches() -> Iterator[tuple[Piece[Frame], int]]:
        left = n
        while left > 0:
            pieces: list[Piece[Frame]] = []
            tried = 0
            while left - tried > 0 and len(pieces) < 200:
                piece, k = random_mk_piece(rng, lambda: random_mk_valid(rng), left - tried)
                pieces.append(piece)
                tried += k
            left -= tried
            yield join(pieces), tried

    return _feed_pass("MK parser", FrameParser(), batches(), rng, advance)


def run_urg_parser(n: int, rng: random.Random, advance: Advance = lambda k: None) -> PassResult:
    """``n`` scan pieces (valid, a bad sum, cut short) and other replies through ReplyParser."""
    np_rng = np.random.default_rng(rng.getrandbits(64))

    def batches() -> Iterator[tuple[Piece[Reply], int]]:
        for first in range(0, n, 100):
            k = min(100, n - first)
            pieces = [
                join([random_urg_extras(rng), random_scan_piece(rng, random_scan(rng, np_rng))])
                for _ in range(k)
            ]
            yield join(pieces), k

    return _feed_pass("URG parser", ReplyParser(), batches(), rng, advance)


# ================================================================= the pty passes
class Wire:
    """The device end of a pty: counts what it writes and what the client has read."""

    def __init__(self, device: PtyDevice) -> None:
        self.device = device
        self.written = 0
        self.read = 0
        self._event = asyncio.Event()

    def tap(self, direction: str, t_ns: int, data: bytes) -> None:
        """The client's tap: it has read ``data``."""
        if direction == "r":
            self.read += len(data)
            self._event.set()

    def write(self, data: bytes) -> None:
        self.device.write(data)
        self.written += len(data)

    async def delivered(self, timeout_s: float = 5.0) -> None:
        """Wait until the client has read everything written (and not dropped)."""
        async with asyncio.timeout(timeout_s):
            while self.read < self.written - self.device.dropped_bytes:
                self._event.clear()
                await self._event.wait()

    async def send(self, rng: random.Random, data: bytes) -> None:
        """Write ``data`` in random chunks, each read by the client before the next."""
        for chunk in random_chunks(rng, data, most=2048):
            self.write(chunk)
            await self.delivered()


_WIRE_RANGES: Final = {
    "nick": (-128, 127), "roll": (-128, 127), "yaw": (-128, 127), "height": (-128, 127),
    "gas": (0, 255), "frame": (0, 255), "config": (0, 255), "free": (0, 255),
    "remote_buttons": (0, 255),
}  # fmt: skip


def within_limits(cmd: ExternControl, settings: LinkSettings) -> bool:
    """Whether the link may send ``cmd``: whole, finite, in its wire range (``mk-serial.md``
    §5.2), nick/roll/yaw within the stick limit and gas within [0, gas_max] (SPEC §4)."""
    for name, (lo, hi) in _WIRE_RANGES.items():
        v = getattr(cmd, name)
        if isinstance(v, float) and not (math.isfinite(v) and v.is_integer()):
            return False
        if not lo <= v <= hi:
            return False
    sticks = (cmd.nick, cmd.roll, cmd.yaw)
    return max(map(abs, sticks)) <= settings.stick_max_counts and cmd.gas <= settings.gas_max


def random_command(rng: random.Random) -> ExternControl:
    """An ExternControl a buggy controller might compute: mostly fine, some not."""
    odd: tuple[float, ...] = (128, -128, 200, -300, 12.0, -12.5, math.nan, math.inf, -math.inf)

    def stick() -> int | float:
        return rng.randint(-127, 127) if rng.random() < 0.8 else rng.choice(odd)

    gas = (
        rng.randint(0, 130)
        if rng.random() < 0.8
        else rng.choice((131, 255, -1, 100.0, 99.5, math.nan))
    )
    return ExternControl(
        nick=stick(),
        roll=stick(),
        yaw=stick(),
        gas=gas,
        height=rng.randint(-128, 127) if rng.random() < 0.95 else math.nan,
        config=rng.choice((0, 1, 1, 1, 3, 256)),
        frame=rng.randrange(256),
    )


def link_category(frame: Frame) -> str:
    """The link counter a valid frame must move (``MkLink._dispatch``, mk-serial.md §2.1)."""
    if frame.addr != 1:
        return "foreign_frames"
    need = {"D": 66, "B": 1, "V": 10, "P": 52, "A": 17}.get(frame.cmd)
    if need is None:
        return "unknown_frames"
    if len(frame.payload) < need:
        return "bad_messages"
    return {"D": "samples", "V": "versions"}.get(frame.cmd, f"answers {frame.cmd}")


class CommandSink:
    """The FC's end of the link: parses every byte the link writes, checks every command."""

    def __init__(self, device: PtyDevice, settings: LinkSettings) -> None:
        self._device = device
        self._settings = settings
        self.parser = FrameParser()
        self.frames: Counter[str] = Counter()
        self.violations: list[str] = []
        self._event = asyncio.Event()

    async def run(self) -> None:
        with contextlib.suppress(LinkError):
            while True:
                for frame in self.parser.feed(await self._device.read()):
                    self._check(frame)
                self._event.set()

    def _check(self, frame: Frame) -> None:
        self.frames[frame.cmd] += 1
        bad = frame.addr != 1 or frame.cmd in FORBIDDEN_COMMANDS or frame.cmd not in "vdbpa"
        if frame.cmd == "b":
            ec = ExternControl.decode(frame)
            bad = bad or not (within_limits(ec, self._settings) and ec.config in (0, 1, 3))
        if bad:
            self.violations.append(f"the link wrote {frame}")

    async def received(self, n: int, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while self.parser.stats.bytes_in < n:
                self._event.clear()
                await self._event.wait()


def link_valid(rng: random.Random) -> Piece[Frame]:
    """A valid frame for the link's stream that is neither a sample (one DebugOut a unit,
    so that each can be checked) nor a confirm it could be waiting for."""
    piece = random_mk_valid(rng)
    frame = piece.valid[0]
    if link_category(frame) == "samples":
        return mk_message(random_debug(rng, addr=0))
    if link_category(frame) == "answers B":
        return mk_message(Confirm(0))  # Frame numbers 1..255 only: never awaited
    return piece


async def run_mk_link(n: int, rng: random.Random, advance: Advance = lambda k: None) -> PassResult:
    """``n`` frame pieces through a real MkLink on a pty, a valid DebugOut in every unit."""
    result = PassResult("MK link (pty)")
    started = time.perf_counter()
    settings = LinkSettings()
    device = PtyDevice("fuzz-fc")
    wire = Wire(device)
    sink = CommandSink(device, settings)
    sink_task = asyncio.create_task(sink.run())
    serial = await open_serial(device.path, settings.baudrate)
    link = MkLink(serial, settings, DEFAULT_CALIBRATION, tap=wire.tap)
    link.start()
    totals, want, sent = Totals(), Counter[str](), Counter[str]()
    samples = out_of_limit = 0
    try:
        while result.tried < n:
            debug = random_debug(rng)
            pieces, tried = [mk_message(debug)], 1
            for _ in range(rng.randrange(4)):
                if tried < n - result.tried:
                    budget = n - result.tried - tried
                    piece, k = random_mk_piece(rng, lambda: link_valid(rng), budget)
                    pieces.append(piece)
                    tried += k
            rng.shuffle(pieces)
            unit = join(pieces)
            totals.add(unit)
            want.update(link_category(f) for f in unit.valid)
            await wire.send(rng, unit.data)
            sample = await link.next_sample(timeout_s=2.0)
            samples += sample == imu_from_debug(debug, sample.t_ns, DEFAULT_CALIBRATION)
            command = random_command(rng)
            ok = within_limits(command, settings)
            try:
                link.send_extern_control(command)
                sent["commands accepted"] += 1
                out_of_limit += not ok
                if rng.random() < 0.2:  # let it reach the wire (else a newer one replaces it)
                    await link.drain()
            except CommandRangeError:
                sent["commands refused"] += 1
                if ok:
                    result.mismatch("MK link", [f"refused {command}"])
            result.tried += tried
            advance(tried)
        await link.close()
        await sink.received(link.stats.bytes_written)
    except Exception as err:  # out of the link, or a timeout: the figure this pass is for
        result.exception(err, b"")
    finally:
        await link.close(release=False)
        sink_task.cancel()
        await device.close()
    s = link.stats
    # The link keeps no frames, only counters: its parser's are checked against the pieces',
    # the frames by kind against the link's own counters.
    result.mismatch("MK link", check(s.parser, totals, totals.valid_bytes))
    kinds = ("samples", "foreign_frames", "unknown_frames", "bad_messages", "versions")
    got = {k: getattr(s, k) for k in kinds}
    got["answers"] = s.parser.frames - sum(got.values())  # confirms, PPM, labels
    want["answers"] = totals.valid - sum(want[k] for k in kinds)
    result.mismatch(
        "MK link", [f"{k} = {v}, want {want[k]}" for k, v in got.items() if v != want[k]]
    )
    result.mismatch(
        "MK link",
        [
            f"{k} = {getattr(s, k)}, want 0"
            for k in ("samples_dropped", "confirms")
            if getattr(s, k)
        ],
    )
    written = sink.parser.stats
    if written.discarded_bytes or written.bytes_in != s.bytes_written:
        what = f"wrote {s.bytes_written} bytes, the FC read {written.bytes_in}"
        what += f", {written.discarded_bytes} outside frames"
        result.mismatch("MK link", [what])
    result.out_of_limit = out_of_limit + len(sink.violations)
    result.problems.extend(sink.violations[:5])
    result.valid = totals.valid
    result.found = samples + sum(min(v, want[k]) for k, v in got.items() if k != "samples")
    result.missed = result.valid - result.found
    result.notes = {**sent, **{f"written {k!r}": v for k, v in sorted(sink.frames.items())}}
    result.notes.update({k: v for k, v in dataclasses.asdict(s.parser).items() if v})
    result.seconds = time.perf_counter() - started
    return result


class ScriptedUrg:
    """The sensor's end of the driver: answers its commands as a URG-04LX in SCIP 2.0."""

    def __init__(self, wire: Wire, totals: Totals) -> None:
        self._wire = wire
        self._totals = totals
        self.answers = 0
        self.md: str | None = None

    async def run(self) -> None:
        pending = b""
        with contextlib.suppress(LinkError):
            while True:
                pending += await self._wire.device.read()
                *lines, pending = pending.split(LF)
                for line in lines:
                    self._answer(line.decode("ascii", "replace"))

    def _answer(self, command: str) -> None:
        name = command[:2]
        if command == "SCIP2.0":
            reply = scip_status(command, "0E")
        elif name in _INFO:
            reply = scip_info(name, [(f"{k}:{v}", 0) for k, v in _INFO[name]])
        elif name in ("QT", "RS", "BM", "TM", "MD"):
            reply = scip_status(command, "00")
            self.md = command if name == "MD" else self.md
        else:
            reply = scip_status(command, "0E")
        piece = reply.piece()
        self._totals.add(piece)
        self._wire.write(piece.data)
        self.answers += 1


async def run_urg_driver(
    n: int, rng: random.Random, advance: Advance = lambda k: None
) -> PassResult:
    """``n`` scan pieces through a real UrgDriver on a pty, a valid scan of its stream in every
    unit; the others have a bad sum, are cut short, or belong to a stream it replaced."""
    result = PassResult("URG driver (pty)")
    started = time.perf_counter()
    np_rng = np.random.default_rng(rng.getrandbits(64))
    device = PtyDevice("fuzz-urg")
    wire, totals = Wire(device), Totals()
    sensor = ScriptedUrg(wire, totals)
    sensor_task = asyncio.create_task(sensor.run())
    driver = UrgDriver(await open_serial(device.path, 115200), UrgSettings(), tap=wire.tap)
    units = scans = stale = 0
    stamp = rng.randrange(1 << 24)
    try:
        await driver.connect()
        await driver.start_stream()
        assert sensor.md is not None
        tag = sensor.md.partition(";")[2]
        while result.tried < n:
            stamp = (stamp + 100) % (1 << 24)
            values = random_values(np_rng, 682, 3)
            current = scip_scan("MD", (44, 725, 1), values, stamp, tag=tag)
            pieces, tried = [_maybe_after_garbage(rng, current.piece())], 1
            for _ in range(rng.randrange(4)):
                if tried < n - result.tried:
                    bad = random_bad_scan(rng, current) if rng.random() < 0.8 else None
                    if bad is None:  # a scan of the stream before
                        bad = scip_scan("MD", (44, 725, 1), values, stamp, tag=tag + "0").piece()
                        stale += 1
                    pieces.append(_maybe_after_garbage(rng, bad))
                    tried += 1
                pieces.append(random_urg_extras(rng))
            rng.shuffle(pieces)
            unit = join(pieces)
            totals.add(unit)
            await wire.send(rng, unit.data)
            units += 1
            scan = await driver.next_scan(timeout_s=2.0)
            ranges = np.where((values >= 20) & (values <= 5600), values / 1000.0, np.nan)
            scans += scan.first_step == 44 and np.array_equal(scan.ranges_m, ranges, equal_nan=True)
            result.tried += tried
            advance(tried)
        await driver.close()
    except Exception as err:  # out of the driver, or a timeout: the figure this pass is for
        result.exception(err, b"")
    finally:
        await driver.close()
        sensor_task.cancel()
        await device.close()
    s = driver.stats
    # The driver keeps no replies, only counters: its parser's are checked against the
    # pieces' (its answers to the start-up commands included), the scans by its own.
    result.mismatch("URG driver", check(s.parser, totals, totals.valid_bytes))
    want = {"scans": units, "stale_stream_scans": stale, "scans_dropped": 0, "restarts": 0}
    want.update(stalls=0, stream_errors=0)
    result.mismatch(
        "URG driver",
        [f"{k} = {getattr(s, k)}, want {v}" for k, v in want.items() if getattr(s, k) != v],
    )
    others = totals.valid - sensor.answers - units - stale
    got_others = s.parser.replies - sensor.answers - s.scans - s.stale_stream_scans
    result.valid = totals.valid - sensor.answers
    result.found = scans + min(s.stale_stream_scans, stale) + min(got_others, others)
    result.missed = result.valid - result.found
    result.notes = {k: v for k, v in dataclasses.asdict(s.parser).items() if v}
    result.notes.update(scans=s.scans, stale_stream_scans=s.stale_stream_scans)
    result.notes["start-up replies"] = sensor.answers
    result.seconds = time.perf_counter() - started
    return result


# ================================================================= the command
MUST_BE_ZERO: Final = ("missed", "exceptions", "counter_mismatches", "out_of_limit_commands")


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        msg = f"{value} < 0"
        raise argparse.ArgumentTypeError(msg)
    return value


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument(
        "--frames", type=_count, default=100_000, help="MK frame pieces (pure pass)"
    )
    parser.add_argument(
        "--scans", type=_count, default=100_000, help="SCIP scan pieces (pure pass)"
    )
    parser.add_argument("--seed", type=int, default=1, help="seed of every random stream")
    parser.add_argument(
        "--pty-frames", type=_count, help="MK link pass (default min(frames, 20000))"
    )
    parser.add_argument(
        "--pty-scans", type=_count, help="URG driver pass (default min(scans, 5000))"
    )
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    if args.pty_frames is None:
        args.pty_frames = min(args.frames, 20_000)
    if args.pty_scans is None:
        args.pty_scans = min(args.scans, 5000)
    return args


def run(args: argparse.Namespace) -> list[PassResult]:
    """The four passes, each with its own stream of the seed."""
    total = args.frames + args.scans + args.pty_frames + args.pty_scans

    def rng(name: str) -> random.Random:
        return random.Random(f"{args.seed}:{name}")

    with tty_bar(total, "pieces") as bar:
        advance: Advance = bar.update if bar is not None else lambda k: None
        return [
            run_mk_parser(args.frames, rng("mk"), advance),
            run_urg_parser(args.scans, rng("urg"), advance),
            asyncio.run(run_mk_link(args.pty_frames, rng("mk-link"), advance)),
            asyncio.run(run_urg_driver(args.pty_scans, rng("urg-driver"), advance)),
        ]


def report(
    args: argparse.Namespace, results: Sequence[PassResult], seconds: float
) -> dict[str, Any]:
    passes = [r.as_dict() for r in results]
    return {
        "seed": args.seed,
        "frames": args.frames,
        "scans": args.scans,
        "pty_frames": args.pty_frames,
        "pty_scans": args.pty_scans,
        "passes": passes,
        "seconds": round(seconds, 1),
        "ok": not any(p[k] for p in passes for k in MUST_BE_ZERO),
    }


def format_table(rep: Mapping[str, Any]) -> str:
    head = (
        "pass",
        "tried",
        "valid",
        "found",
        "missed",
        "exceptions",
        "mismatches",
        "out-of-limit",
        "seconds",
    )
    rows = [head]
    for p in rep["passes"]:
        oof = p["out_of_limit_commands"]
        figures = (
            p["tried"],
            p["valid"],
            p["found"],
            p["missed"],
            p["exceptions"],
            p["counter_mismatches"],
        )
        rows.append(
            (p["pass"], *map(str, figures), "-" if oof is None else str(oof), f"{p['seconds']:.1f}")
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = [
        f"fuzz, seed {rep['seed']}: {rep['frames']} frames, {rep['scans']} scans; "
        f"through the link and the driver on ptys: {rep['pty_frames']} frames, "
        f"{rep['pty_scans']} scans",
        "",
    ]
    for r in rows:
        lines.append(
            "  ".join(
                [
                    r[0].ljust(widths[0]),
                    *(c.rjust(w) for c, w in zip(r[1:], widths[1:], strict=True)),
                ]
            )
        )
    lines.append("")
    for p in rep["passes"]:
        notes = ", ".join(f"{k} {v}" for k, v in p["notes"].items())
        lines.append(f"{p['pass']}: {notes}")
        lines.extend(f"  ! {problem}" for problem in p["problems"])
    verdict = (
        "OK: every must-be-0 figure is 0" if rep["ok"] else "FAILED: a must-be-0 figure is not 0"
    )
    lines.append(f"{verdict} ({rep['seconds']:.1f} s)")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    configure_events("warning")
    started = time.perf_counter()
    rep = report(args, run(args), time.perf_counter() - started)
    print(json.dumps(rep, indent=1) if args.json else format_table(rep))
    return 0 if rep["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
