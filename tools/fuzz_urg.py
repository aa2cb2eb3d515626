"""Fuzzing SCIP streams (``scip2.md``): reply pieces, their seeded random draws, the pure pass.

The pieces, each with what ``ReplyParser`` must make of it (§2, §6): valid replies of every
kind the parser returns (GD/GS/MD/MS scans, status-only replies, the SCIP 1.1 ``0``, VV/PP/II
with either sum rule, TM1, summed bodies); replies with one bad sum; scans cut short (then
``LF LF``); garbage lines in front of a reply; blocks of SCIP look-alikes (echoes, statuses,
time stamps, data blocks, empty and over-long lines). Look-alikes never put an echo line right
before a status line: SCIP has no start byte, and such a pair *is* a reply.
:func:`run_urg_parser` feeds them through a ``ReplyParser``.
"""

from __future__ import annotations

import itertools
import random
import re
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from fuzz_pieces import Advance, PassResult, Piece, feed_pass, join, random_length

from mkflight.sim.urg_answers import UrgIdentity, ii_lines, pp_lines, vv_lines
from mkflight.urg.codec import status_line, sum_char, timestamp_line, value_count
from mkflight.urg.replies import InfoReply, Reply, ReplyParser, ScanReply, TimeReply

LF: Final = b"\n"


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
        values_mm=v,
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
INFO_LINES: Final = {  # a URG-04LX's VV/PP/II lines (also what ScriptedUrg answers)
    "VV": vv_lines(_WHO),
    "PP": pp_lines(_WHO),
    "II": ii_lines(_WHO, laser_on=False, timer_ms=0x6A55F8),
}
_SCIP_NOISE: Final = (
    b"MD0044072501000;g1", b"GD0044072501", b"VV", b"SCIP2.0", b"QT", b"00P", b"99b", b"0Ee",
    b"0", b"JUGnD", b"", b"", b"\r", b"DMIN:20;4", b"1Dh00C000@", b"0" * 64 + b"P", b"x" * 300,
)  # fmt: skip


def _tag(rng: random.Random) -> str:
    if rng.random() < 0.5:
        return ""
    return "".join(rng.choice(_TAG_CHARS) for _ in range(rng.randrange(17)))


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
        steps = (start, min(768, start + random_length(rng, 60)), rng.choice((0, 1, 1, 2, 3, 99)))
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
        entries = [(f"{k}:{v}", rng.randrange(3)) for k, v in INFO_LINES[cmd]]
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
        rng.choice(_SCIP_NOISE) if rng.random() < 0.6 else rng.randbytes(random_length(rng, 30))
        for _ in range(random_length(rng, mean))
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


def maybe_after_garbage(rng: random.Random, piece: Piece[Reply]) -> Piece[Reply]:
    """``piece``, 30 % of the time after up to 3 random garbage lines."""
    if rng.random() < 0.3:
        lines = [rng.randbytes(random_length(rng, 20)) for _ in range(rng.randrange(4))]
        return scip_after_garbage(lines, piece)
    return piece


def random_scan_piece(rng: random.Random, scan: Scip) -> Piece[Reply]:
    """``scan`` valid (60 %), with a bad sum or cut short; maybe after garbage lines."""
    bad = random_bad_scan(rng, scan) if rng.random() < 0.4 else None
    return maybe_after_garbage(rng, bad or scan.piece())


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


# ================================================================= the pure pass
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

    return feed_pass("URG parser", ReplyParser(), batches(), rng, advance)
