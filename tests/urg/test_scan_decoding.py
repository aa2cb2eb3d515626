"""The scan decoder against a plain per-beam reference, on random valid and damaged scans.

The parser decodes a scan's data without a Python step per beam (block sums as numpy rows,
values by a table lookup and one product, ranges by one lookup). The reference below is the
straightforward reading of ``protocols/scip2.md`` §2.3-2.5 and §5, one block and one value
at a time: on any scan, valid or damaged, both must give the same reply with the same values,
or drop it for the same reason (a bad sum or a malformed body), and the same ranges in metres,
NaN where the reference has NaN.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from mkflight.scanmatch.kernels import load_kernel
from mkflight.urg.codec import decode_array, decode_values
from mkflight.urg.replies import BlockDecoder, ReplyParser, ScanReply
from mkflight.urg.stamping import ScanStamper
from mkflight.urg.units import URG_04LX, SensorParams

PROPERTY = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LF = 0x0A
ECHO = re.compile(rb"[A-Z]{2}[ -~]{0,46}")
SCAN_ECHO = re.compile(r"(G[DS]|M[DS])(\d{4})(\d{4})(\d{2})(?:(\d)(\d{2}))?(;.*)?")


# --- the reference: one block, one character, one value at a time -----------------------------
def ref_sum(text: bytes) -> int:
    total = 0
    for byte in text:
        total += byte
    return (total % 64) + 0x30


def ref_encode(value: int, chars: int) -> bytes:
    return bytes(0x30 + (value >> (6 * i)) % 64 for i in reversed(range(chars)))


def ref_value(text: bytes) -> int | None:
    value = 0
    for byte in text:
        if not 0x30 <= byte <= 0x6F:
            return None
        value = value * 64 + (byte - 0x30)
    return value


@dataclass(frozen=True)
class RefScan:
    timestamp_ms: int
    values: list[int]
    start: int
    end: int
    cluster: int
    remaining: int | None


def ref_parse_scan(echo: str, body: list[bytes], chars: int) -> RefScan | str:
    """``"sum"``, ``"malformed"`` or the scan, as §2.3-2.5 describe it."""
    stamp = body[0]
    if len(stamp) != 5:
        return "malformed"
    if ref_sum(stamp[:4]) != stamp[4]:
        return "sum"
    data = b""
    for k, block in enumerate(body[1:], start=1):
        size = len(block) - 1
        if size < 1 or size > 64 or (k < len(body) - 1 and size != 64):
            return "malformed"
        if ref_sum(block[:-1]) != block[-1]:
            return "sum"
        data += block[:-1]
    m = SCAN_ECHO.fullmatch(echo)
    if m is None or (m[5] is None) != (echo[0] == "G"):
        return "malformed"
    if len(data) % chars:
        return "malformed"
    values: list[int] = []
    for i in range(0, len(data), chars):
        value = ref_value(data[i : i + chars])
        if value is None:
            return "malformed"
        values.append(value)
    timestamp_ms = ref_value(stamp[:4])
    start, end, cluster = int(m[2]), int(m[3]), int(m[4])
    if timestamp_ms is None or end < start:
        return "malformed"
    if len(values) != (end - start + 1 + max(cluster, 1) - 1) // max(cluster, 1):
        return "malformed"
    return RefScan(timestamp_ms, values, start, end, cluster, int(m[6]) if m[6] else None)


def ref_ranges_m(values: list[int], params: SensorParams) -> np.ndarray:
    metres = [v / 1000 if params.dmin_mm <= v <= params.dmax_mm else math.nan for v in values]
    return np.array(metres, dtype=np.float64)


# --- random scans and the ways they break ---------------------------------------------------
@dataclass(frozen=True)
class ScanText:
    echo: str
    body: list[bytes]
    chars: int


@st.composite
def valid_scans(draw: st.DrawFn) -> ScanText:
    cmd = draw(st.sampled_from(["MD", "MS", "GD", "GS"]))
    chars = 3 if cmd[1] == "D" else 2
    start = draw(st.integers(0, 768))
    end = draw(st.integers(start, 768))
    cluster = draw(st.integers(0, 99) | st.just(1))
    n = (end - start + max(cluster, 1)) // max(cluster, 1)
    top = (1 << (6 * chars)) - 1
    beam = st.integers(0, 19) | st.integers(20, 5600) | st.integers(min(5601, top), top)
    values = draw(st.lists(beam, min_size=n, max_size=n))
    echo = f"{cmd}{start:04d}{end:04d}{cluster:02d}"
    if cmd[0] == "M":
        echo += f"{draw(st.integers(0, 9))}{draw(st.integers(0, 99)):02d}"
    stamp = ref_encode(draw(st.integers(0, (1 << 24) - 1)), 4)
    data = b"".join(ref_encode(v, chars) for v in values)
    blocks = [
        data[i : i + 64] + bytes((ref_sum(data[i : i + 64]),)) for i in range(0, len(data), 64)
    ]
    return ScanText(echo, [stamp + bytes((ref_sum(stamp),)), *blocks], chars)


def _no_lf(byte: int) -> int:
    return 0x2E if byte == LF else byte


@st.composite
def damaged_scans(draw: st.DrawFn) -> ScanText:
    scan = draw(valid_scans())
    body = list(scan.body)
    echo = scan.echo
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from([0, 1, 2, 3, 4, 5, 6, 7, 7, 7]))  # 7 may leave it valid
        line = draw(st.integers(0, len(body) - 1))
        text = bytearray(body[line])
        at = draw(st.integers(0, len(text) - 1))
        if kind == 0:  # any byte replaced: usually a bad sum, or a bad sum character
            text[at] = _no_lf(draw(st.integers(0, 255)))
        elif kind == 1 and len(text) > 1:  # a character outside '0'..'o' under a good sum
            text[min(at, len(text) - 2)] = draw(st.sampled_from([0x20, 0x2F, 0x70, 0x7E, 0xFF]))
            text[-1] = ref_sum(bytes(text[:-1]))
        elif kind == 2:  # a line cut short (a block loses characters)
            del text[max(at, 1) :]
        elif kind == 3 and len(body) > 1:  # a whole line lost
            del body[line]
            continue
        elif kind == 4:  # a line made longer, its sum still good
            extra = draw(st.binary(min_size=1, max_size=8).map(lambda b: bytes(map(_no_lf, b))))
            text = bytearray(text[:-1] + extra)
            text.append(ref_sum(bytes(text)))
        elif kind == 5:  # a line twice
            body.insert(line, bytes(text))
        elif kind == 6:  # a wrong step count or a broken echo
            echo = draw(st.sampled_from([echo[:-1], echo + "0", echo.replace("0", "1", 1), "MD;x"]))
        else:  # the sum of a line recomputed after a replaced byte: a valid-looking block
            text[at] = _no_lf(draw(st.integers(0x30, 0x6F)))
            if len(text) > 1:
                text[-1] = ref_sum(bytes(text[:-1]))
        body[line] = bytes(text)
    body = [line for line in body if line]
    assume(body)
    return ScanText(echo, body, scan.chars)


#: The compiled decoder of a scan's blocks (mkflight.urg.kernel_numba): every property
#: below holds with it as with the numpy path.
COMPILED = load_kernel("numba").scan_blocks
DECODERS = (None, COMPILED)


def feed(
    scan: ScanText, decode_blocks: BlockDecoder | None = None
) -> tuple[list[ScanReply], ReplyParser]:
    parser = ReplyParser(decode_blocks)
    status = b"99b" if scan.echo[0] == "M" else b"00P"
    lines = [scan.echo.encode(), status, *scan.body]
    replies = parser.feed(b"\n".join(lines) + b"\n\n")
    return [r for r in replies if isinstance(r, ScanReply)], parser


def assert_decoded_alike(scan: ScanText) -> None:
    # only the echo line may start a reply: another candidate would test _finish, not decoding
    assume(not any(ECHO.fullmatch(line) for line in scan.body[:-1]))
    assume(all(len(line) <= 256 for line in scan.body) and len(scan.body) <= 62)
    for decode_blocks in DECODERS:
        assert_decoded_as_expected(scan, decode_blocks)


def assert_decoded_as_expected(scan: ScanText, decode_blocks: BlockDecoder | None) -> None:
    expected = ref_parse_scan(scan.echo, scan.body, scan.chars)
    replies, parser = feed(scan, decode_blocks)
    if isinstance(expected, str):
        assert replies == []
        assert (parser.stats.sum_errors, parser.stats.malformed) == (
            (1, 0) if expected == "sum" else (0, 1)
        )
        return
    (reply,) = replies
    assert reply.values == tuple(expected.values)
    assert reply.values_mm.dtype == np.int64
    assert not reply.values_mm.flags.writeable
    assert reply.values_mm.tolist() == expected.values
    fields = (reply.timestamp_ms, reply.start_step, reply.end_step, reply.cluster, reply.remaining)
    assert fields == (
        expected.timestamp_ms,
        expected.start,
        expected.end,
        expected.cluster,
        expected.remaining,
    )
    scan_record = ScanStamper(0.0).stamp(reply, 10**12, URG_04LX, seq=1)
    assert scan_record.ranges_m.tobytes() == ref_ranges_m(expected.values, URG_04LX).tobytes()


@PROPERTY
@given(valid_scans())
def test_a_valid_scan_decodes_as_the_reference_decodes_it(scan: ScanText) -> None:
    assert_decoded_alike(scan)
    assert ref_parse_scan(scan.echo, scan.body, scan.chars) != "sum"


@PROPERTY
@given(damaged_scans())
def test_a_damaged_scan_is_decoded_or_dropped_as_the_reference_says(scan: ScanText) -> None:
    assert_decoded_alike(scan)


@PROPERTY
@given(
    st.binary(max_size=300)
    | st.lists(st.integers(0x30, 0x6F), max_size=300).map(bytes)
    | st.lists(st.integers(0x2E, 0x71), max_size=300).map(bytes),
    st.sampled_from([2, 3]),
)
def test_values_decode_as_the_reference_decodes_them(data: bytes, chars: int) -> None:
    expected: list[int] | None = []
    if len(data) % chars:
        expected = None
    else:
        for i in range(0, len(data), chars):
            value = ref_value(data[i : i + chars])
            if value is None:
                expected = None
                break
            assert expected is not None
            expected.append(value)
    assert decode_values(data, chars) == expected
    array = decode_array(data, chars)
    assert (None if array is None else array.tolist()) == expected


@PROPERTY
@given(
    st.lists(st.integers(0, (1 << 18) - 1) | st.integers(0, 30), max_size=700),
    st.integers(0, 100),
    st.integers(101, 1 << 18),
)
def test_ranges_are_the_reference_metres_bit_for_bit(
    values: list[int], dmin_mm: int, dmax_mm: int
) -> None:
    params = SensorParams(dmin_mm, dmax_mm, 1024, 0, 768, 384, 600)
    reply = ScanReply("MD", "99", values_mm=np.array(values, dtype=np.int64), end_step=768)
    ranges = ScanStamper(0.0).stamp(reply, 10**12, params, seq=1).ranges_m
    assert ranges.dtype == np.float64
    assert ranges.tobytes() == ref_ranges_m(values, params).tobytes()


@pytest.mark.parametrize("decode_blocks", DECODERS, ids=("numpy", "compiled"))
def test_blocks_whose_line_ends_fall_where_a_full_block_would_end_are_malformed(
    decode_blocks: BlockDecoder | None,
) -> None:
    """Two short blocks of 30 and 34 bytes put an LF 65 bytes after the first one's start."""
    data = b"".join(ref_encode(v, 3) for v in range(100, 140))
    blocks = [data[:29], data[29:62], data[62:126], data[126:]]
    body = [block + bytes((ref_sum(block),)) for block in blocks]
    assert [len(line) for line in body[:2]] == [30, 34]
    stamp = ref_encode(5, 4)
    scan = ScanText("MD0044008301000", [stamp + bytes((ref_sum(stamp),)), *body], 3)
    replies, parser = feed(scan, decode_blocks)
    assert replies == []
    assert (parser.stats.sum_errors, parser.stats.malformed) == (0, 1)


def test_the_properties_see_every_outcome() -> None:
    """The damaged-scan strategy reaches good scans, bad sums and malformed bodies alike."""
    seen: set[str] = set()

    @settings(max_examples=300, deadline=None, database=None, derandomize=True)
    @given(damaged_scans())
    def collect(scan: ScanText) -> None:
        result = ref_parse_scan(scan.echo, scan.body, scan.chars)
        seen.add(result if isinstance(result, str) else "scan")

    collect()
    assert seen == {"scan", "sum", "malformed"}
