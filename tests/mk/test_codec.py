"""Frames, checksum and the incremental parser (``mk-serial.md`` §2-3, vectors §9.1-9.2).

The vectors are the in-project literals of ``tests/mk/vectors.py``; the tests marked ``shared``
also check those literals against the document itself when ``../shared`` is there
(``tests/conftest.py``), and are deselected on a clone without it.
"""

from __future__ import annotations

import ast
import dataclasses
import itertools
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.mk.codec import (
    MAX_FRAME_BYTES,
    Frame,
    FrameEncoder,
    FrameParser,
    ParserStats,
    checksum,
    decode_payload,
    encode_frame,
    encode_payload,
)

from .vectors import (
    ALL_VECTORS,
    FRAME_VECTORS,
    KIND_OF,
    SINGLE_FRAME_VECTORS,
    STREAM_VECTORS,
    ConfirmVector,
    DebugOutVector,
    DebugRequestVector,
    ExternControlVector,
    FrameLike,
    FrameVector,
    LabelVector,
    PpmVector,
    StreamVector,
    VersionInfoVector,
)

#: The document the vectors are transcribed from, relative to the shared folder.
MK_SERIAL_MD = "protocols/mk-serial.md"

# The command character each kind of §9.1 vector travels with (§4).
CMD_OF_KIND: dict[type[FrameLike], str] = {
    VersionInfoVector: "V",
    DebugRequestVector: "d",
    DebugOutVector: "D",
    ExternControlVector: "b",
    ConfirmVector: "B",
    PpmVector: "P",
    LabelVector: "A",
}

# --- helpers -----------------------------------------------------------------------------


def split(data: bytes, cuts: Iterable[int]) -> list[bytes]:
    """Cut ``data`` at the given offsets (any order, duplicates and out-of-range clipped)."""
    points = sorted({min(max(c, 0), len(data)) for c in cuts})
    bounds = [0, *points, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(bounds)]


def feed_all(chunks: Sequence[bytes]) -> tuple[list[Frame], ParserStats]:
    """Feed ``chunks`` one by one into a fresh parser; return every frame and the stats."""
    parser = FrameParser()
    frames: list[Frame] = []
    for chunk in chunks:
        frames += parser.feed(chunk)
    return frames, parser.stats


def padded(payload: bytes) -> bytes:
    """What the decoder returns for ``payload``: zero-padded to a multiple of 3 (§2.2)."""
    return payload + bytes(-len(payload) % 3)


def wire_length(frame: Frame) -> int:
    """Bytes a delivered frame occupied on the wire: 6 + 4 per 3 decoded payload bytes."""
    return 6 + 4 * len(frame.payload) // 3


def buffered_bytes(parser: FrameParser) -> int:
    """Bytes held in an incomplete trailing frame, measured through the public interface.

    A '#' always abandons the frame being collected and counts it as discarded (§3 rule
    2), so the growth of ``discarded_bytes`` when one '#' is fed is exactly what was held.
    """
    before = parser.stats.discarded_bytes
    assert parser.feed(b"#") == []
    return parser.stats.discarded_bytes - before


# --- strategies --------------------------------------------------------------------------

addrs = st.integers(0, 63)
cmds = st.characters(min_codepoint=0x20, max_codepoint=0x7E).filter(lambda c: c != "#")
payloads = st.binary(max_size=123)
frame_args = st.tuples(addrs, cmds, payloads)
garbage = st.binary(max_size=40).map(lambda b: b.replace(b"#", b""))


@st.composite
def valid_frames(draw: st.DrawFn) -> bytes:
    """One valid, encoded frame with a random address, command and payload."""
    addr, cmd, payload = draw(frame_args)
    return encode_frame(addr, cmd, payload)


@st.composite
def damaged_frames(draw: st.DrawFn) -> bytes:
    """A valid frame with one byte replaced, or cut short."""
    frame = bytearray(draw(valid_frames()))
    if draw(st.booleans()):
        i = draw(st.integers(0, len(frame) - 1))
        frame[i] = draw(st.integers(0, 255))
        return bytes(frame)
    return bytes(frame[: draw(st.integers(0, len(frame) - 1))])


noisy_streams = st.lists(
    st.one_of(
        valid_frames(),
        damaged_frames(),
        st.binary(max_size=40),
        st.sampled_from(
            [
                b"#",
                b"\r",
                b"#\r",
                b"#bB",
                b"#bB\r",
                b"=" * 200,
                b"#" + b"=" * 175,
                b"#" + b"=" * 168 + b"\r",
                b"#" + b"=" * 169 + b"\r",
            ]
        ),
    ),
    max_size=12,
).map(b"".join)

cut_lists = st.lists(st.integers(0, 2000), max_size=20)


# --- §9 tables of the shared document ----------------------------------------------------

_ROW = re.compile(r"^\|\s*(MK-\d\d)\s*\|.*\|\s*`([A-Za-z]+\(.*\))`\s*\|\s*`(b'.*')`\s*\|\s*$")


def _tuples(value: Any) -> Any:
    """Lists -> tuples, recursively (the document writes lists where the records use tuples)."""
    if isinstance(value, list | tuple):
        return tuple(_tuples(v) for v in value)
    return value


def _doc_rows(text: str) -> dict[str, tuple[str, dict[str, Any], bytes]]:
    """Parse the §9.1/§9.2 rows: id -> (kind, keyword fields, bytes)."""
    rows: dict[str, tuple[str, dict[str, Any], bytes]] = {}
    for line in text.splitlines():
        m = _ROW.match(line)
        if not m:
            continue
        vid, call_src, bytes_src = m.groups()
        call = ast.parse(call_src, mode="eval").body
        assert isinstance(call, ast.Call), vid
        assert isinstance(call.func, ast.Name), vid
        assert not call.args, f"{vid}: positional fields"
        fields = {kw.arg: ast.literal_eval(kw.value) for kw in call.keywords if kw.arg}
        data = ast.literal_eval(bytes_src)
        assert isinstance(data, bytes), vid
        assert vid not in rows, f"{vid} appears twice"
        rows[vid] = (call.func.id, fields, data)
    return rows


@pytest.fixture(scope="module")
def doc_rows(shared_dir: Path) -> dict[str, tuple[str, dict[str, Any], bytes]]:
    """The §9 rows of the shared document (only tests marked ``shared(MK_SERIAL_MD)`` use it)."""
    return _doc_rows((shared_dir / MK_SERIAL_MD).read_text(encoding="utf-8"))


def test_vector_ids_are_mk01_to_mk24() -> None:
    assert list(ALL_VECTORS) == [f"MK-{i:02d}" for i in range(1, 25)]
    assert len(SINGLE_FRAME_VECTORS) == 19
    assert len(STREAM_VECTORS) == 5


@pytest.mark.shared(MK_SERIAL_MD)
def test_document_lists_exactly_our_vectors(
    doc_rows: dict[str, tuple[str, dict[str, Any], bytes]],
) -> None:
    assert sorted(doc_rows) == list(ALL_VECTORS)


@pytest.mark.shared(MK_SERIAL_MD)
@pytest.mark.parametrize("vid", list(ALL_VECTORS))
def test_vector_bytes_equal_document(
    vid: str, doc_rows: dict[str, tuple[str, dict[str, Any], bytes]]
) -> None:
    _kind, _fields, data = doc_rows[vid]
    assert ALL_VECTORS[vid].data == data


@pytest.mark.shared(MK_SERIAL_MD)
@pytest.mark.parametrize("vid", list(ALL_VECTORS))
def test_vector_fields_equal_document(
    vid: str, doc_rows: dict[str, tuple[str, dict[str, Any], bytes]]
) -> None:
    kind, fields, data = doc_rows[vid]
    ours = ALL_VECTORS[vid]
    assert type(ours) is KIND_OF[kind]
    normalised: dict[str, Any] = {
        k: v if isinstance(v, dict) else _tuples(v) for k, v in fields.items()
    }
    assert KIND_OF[kind](id=vid, data=data, **normalised) == ours


# --- checksum and payload encoding (§2.2-2.3) --------------------------------------------


def test_checksum_worked_example() -> None:
    assert sum(b"#bv") == 251
    assert checksum(b"#bv") == b"@x"


def test_checksum_wraps_at_4096() -> None:
    data = b"\xff" * 17  # 4335 = 4096 + 239 = 3*64 + 47
    assert checksum(data) == bytes((0x3D + 3, 0x3D + 47))
    assert checksum(b"") == b"=="


def test_single_byte_payload_example() -> None:
    assert encode_payload(b"\x05") == b">M=="
    assert decode_payload(b">M==") == b"\x05\x00\x00"


@given(payloads)
def test_payload_characters_stay_in_range(payload: bytes) -> None:
    chars = encode_payload(payload)
    assert len(chars) == 4 * -(-len(payload) // 3)
    assert all(0x3D <= c <= 0x7C for c in chars)
    assert decode_payload(chars) == padded(payload)


@pytest.mark.parametrize(
    "chars",
    [b"=", b"===", b"=====", b"<===", b"===}", b"\x00\x00\x00\x00", b"#==="],
    ids=["len1", "len3", "len5", "below", "above", "nul", "hash"],
)
def test_decode_payload_rejects_bad_input(chars: bytes) -> None:
    assert decode_payload(chars) is None


# --- encode_frame (§2) -------------------------------------------------------------------


@pytest.mark.parametrize("vector", FRAME_VECTORS, ids=lambda v: v.id)
def test_frame_vectors_encode(vector: FrameVector) -> None:
    assert encode_frame(vector.addr, vector.cmd, vector.payload) == vector.data


@pytest.mark.parametrize("vector", FRAME_VECTORS, ids=lambda v: v.id)
def test_frame_vectors_decode(vector: FrameVector) -> None:
    frames, stats = feed_all([vector.data])
    assert frames == [Frame(vector.addr, vector.cmd, padded(vector.payload))]
    assert (stats.frames, stats.discarded_bytes, stats.crc_errors) == (1, 0, 0)


@pytest.mark.parametrize("vector", SINGLE_FRAME_VECTORS, ids=lambda v: v.id)
def test_every_frame_vector_parses_alone(vector: FrameLike) -> None:
    frames, stats = feed_all([vector.data])
    assert len(frames) == 1
    frame = frames[0]
    assert frame.addr == vector.addr
    if not isinstance(vector, FrameVector):
        assert frame.cmd == CMD_OF_KIND[type(vector)]
    assert wire_length(frame) == len(vector.data) == stats.bytes_in
    # Re-encoding what was decoded gives the same bytes (padding included).
    assert encode_frame(frame.addr, frame.cmd, frame.payload) == vector.data
    assert stats == ParserStats(bytes_in=len(vector.data), frames=1)


@pytest.mark.parametrize(
    ("payload_len", "frame_len"), [(0, 6), (1, 10), (10, 22), (11, 22), (52, 78), (66, 94)]
)
def test_frame_lengths(payload_len: int, frame_len: int) -> None:
    assert len(encode_frame(1, "x", bytes(payload_len))) == frame_len


def test_longest_frame_is_170_bytes_and_parses() -> None:
    data = encode_frame(1, "Q", bytes(range(123)))
    assert len(data) == MAX_FRAME_BYTES
    frames, stats = feed_all([data])
    assert frames == [Frame(1, "Q", bytes(range(123)))]
    assert stats.overflows == 0


@pytest.mark.parametrize(
    ("addr", "cmd", "payload", "match"),
    [
        (64, "v", b"", "address 64"),
        (-1, "v", b"", "address -1"),
        (1, "#", b"", "command '#'"),
        (1, "\r", b"", "command"),
        (1, "", b"", "command ''"),
        (1, "vv", b"", "command 'vv'"),
        (1, "\x7f", b"", "command"),
        (1, "\x1f", b"", "command"),
        (1, "é", b"", "command"),
        (1, "Q", bytes(124), "174 bytes exceeds"),
    ],
)
def test_encode_frame_rejects(addr: int, cmd: str, payload: bytes, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        encode_frame(addr, cmd, payload)


# --- stream vectors (§9.2) ---------------------------------------------------------------


@pytest.mark.parametrize("vector", STREAM_VECTORS, ids=lambda v: v.id)
def test_stream_vectors(vector: StreamVector) -> None:
    frames, stats = feed_all(split(vector.data, vector.split_at))
    assert [(f.addr, f.cmd, f.payload.hex()) for f in frames] == list(vector.frames)
    assert stats.crc_errors == vector.crc_errors
    assert stats.discarded_bytes == vector.discarded
    assert stats.frames == len(vector.frames)
    assert stats.bytes_in == len(vector.data)


@pytest.mark.parametrize("vector", STREAM_VECTORS, ids=lambda v: v.id)
def test_stream_vectors_byte_by_byte(vector: StreamVector) -> None:
    frames, stats = feed_all([vector.data[i : i + 1] for i in range(len(vector.data))])
    whole_frames, whole_stats = feed_all([vector.data])
    assert frames == whole_frames
    assert stats == whole_stats


def test_split_stream_delivers_only_on_completion() -> None:
    parser = FrameParser()
    assert parser.feed(b"#bB>") == []
    assert parser.feed(b"m==Di\r") == [Frame(1, "B", b"\x07\x00\x00")]


def test_short_frame_is_malformed_not_crc() -> None:
    frames, stats = feed_all([b"#b\r#\r#bB>m==Di\r"])
    assert frames == [Frame(1, "B", b"\x07\x00\x00")]
    assert stats.malformed == 2
    assert stats.crc_errors == 0
    assert stats.discarded_bytes == 5


def test_good_checksum_bad_payload_length_is_malformed() -> None:
    head = b"#bB>m="
    data = head + checksum(head) + b"\r"
    frames, stats = feed_all([data])
    assert frames == []
    assert stats.malformed == 1
    assert stats.discarded_bytes == len(data)


def test_parser_accepts_bytearray_and_memoryview() -> None:
    parser = FrameParser()
    assert parser.feed(bytearray(b"#bB>m=")) == []
    assert parser.feed(memoryview(b"=Di\r")) == [Frame(1, "B", b"\x07\x00\x00")]


# --- properties: round trip (b) ----------------------------------------------------------


@given(frame_args)
def test_encode_frame_parse_round_trip(args: tuple[int, str, bytes]) -> None:
    addr, cmd, payload = args
    data = encode_frame(addr, cmd, payload)
    assert len(data) == 6 + 4 * -(-len(payload) // 3) <= MAX_FRAME_BYTES
    assert data[0:1] == b"#"
    assert data[-1:] == b"\r"
    assert b"#" not in data[1:]
    assert b"\r" not in data[:-1]
    frames, stats = feed_all([data])
    assert len(frames) == 1
    frame = frames[0]
    assert (frame.addr, frame.cmd) == (addr, cmd)
    assert frame.payload.startswith(payload)
    assert frame.payload == padded(payload)
    assert len(frame.payload) % 3 == 0
    assert stats == ParserStats(bytes_in=len(data), frames=1)


# --- properties: robustness (c) ----------------------------------------------------------


@given(st.binary(max_size=600), cut_lists)
def test_parser_never_raises_on_random_bytes(data: bytes, cuts: list[int]) -> None:
    frames, stats = feed_all(split(data, cuts))
    whole_frames, whole_stats = feed_all([data])
    assert frames == whole_frames
    assert stats == whole_stats
    assert stats.bytes_in == len(data)


@settings(max_examples=300)
@given(noisy_streams, cut_lists)
def test_parser_result_does_not_depend_on_chunking(data: bytes, cuts: list[int]) -> None:
    frames, stats = feed_all(split(data, cuts))
    whole_frames, whole_stats = feed_all([data])
    byte_frames, byte_stats = feed_all([data[i : i + 1] for i in range(len(data))])
    assert frames == whole_frames == byte_frames
    assert stats == whole_stats == byte_stats


# --- properties: frames in garbage (d) ---------------------------------------------------


@given(st.lists(st.tuples(garbage, frame_args), max_size=8), garbage, cut_lists)
def test_every_frame_in_hashless_garbage_is_found(
    pieces: list[tuple[bytes, tuple[int, str, bytes]]], tail: bytes, cuts: list[int]
) -> None:
    data = b"".join(g + encode_frame(*args) for g, args in pieces) + tail
    frames, stats = feed_all(split(data, cuts))
    assert frames == [Frame(a, c, padded(p)) for _g, (a, c, p) in pieces]
    assert stats.frames == len(pieces)
    assert stats.discarded_bytes == sum(len(g) for g, _args in pieces) + len(tail)
    assert stats.crc_errors == stats.malformed == stats.overflows == 0


# --- properties: counters add up (e) -----------------------------------------------------


@given(st.lists(frame_args, max_size=10), cut_lists)
def test_clean_concatenation_discards_nothing(
    frame_list: list[tuple[int, str, bytes]], cuts: list[int]
) -> None:
    data = b"".join(encode_frame(*args) for args in frame_list)
    parser = FrameParser()
    frames: list[Frame] = []
    for chunk in split(data, cuts):
        frames += parser.feed(chunk)
    assert len(frames) == parser.stats.frames == len(frame_list)
    assert parser.stats.discarded_bytes == 0
    assert sum(wire_length(f) for f in frames) == parser.stats.bytes_in == len(data)
    assert buffered_bytes(parser) == 0


@settings(max_examples=300)
@given(noisy_streams, cut_lists)
def test_counters_add_up(data: bytes, cuts: list[int]) -> None:
    parser = FrameParser()
    frames: list[Frame] = []
    for chunk in split(data, cuts):
        frames += parser.feed(chunk)
    stats = dataclasses.replace(parser.stats)  # snapshot before the probe below
    reported = parser.buffered
    held = buffered_bytes(parser)
    assert reported == held
    assert stats.frames == len(frames)
    assert stats.bytes_in == len(data)
    assert stats.bytes_in == sum(wire_length(f) for f in frames) + stats.discarded_bytes + held
    # What is held is an incomplete trailing frame: one '#', no '\r', shorter than the limit.
    assert 0 <= held < MAX_FRAME_BYTES
    if held:
        tail = data[-held:]
        assert tail[:1] == b"#"
        assert b"#" not in tail[1:]
        assert b"\r" not in tail
    else:
        assert b"#" not in data[-1:]


def test_counters_add_up_with_partial_tail() -> None:
    confirm = encode_frame(1, "B", b"\x07")
    data = b"xx" + confirm + b"#bD=m?B"
    parser = FrameParser()
    frames = parser.feed(data)
    assert len(frames) == 1
    assert parser.stats.discarded_bytes == 2
    assert parser.buffered == 7
    assert buffered_bytes(parser) == 7
    assert parser.stats.bytes_in == len(data) + 1


def test_reset_counts_the_partial_frame_as_discarded() -> None:
    parser = FrameParser()
    assert parser.feed(b"ab#bD=m?B") == []
    assert parser.buffered == 7
    parser.reset()
    assert parser.buffered == 0
    assert parser.stats.discarded_bytes == 9 == parser.stats.bytes_in
    # The rest of the abandoned frame is now garbage; the next frame parses normally.
    assert parser.feed(b"\x7coq\r#bB>m==Di\r") == [Frame(1, "B", b"\x07\x00\x00")]
    assert parser.stats.discarded_bytes == 13


# --- overflow (f) ------------------------------------------------------------------------

no_end = st.binary(min_size=169, max_size=400).map(
    lambda b: b.replace(b"#", b"=").replace(b"\r", b"=")
)


@given(no_end, cut_lists)
def test_frame_without_end_overflows(body: bytes, cuts: list[int]) -> None:
    confirm = encode_frame(1, "B", b"\x07")
    data = b"#" + body + confirm
    frames, stats = feed_all(split(data, cuts))
    assert frames == [Frame(1, "B", b"\x07\x00\x00")]
    assert stats.overflows == 1
    assert stats.discarded_bytes == 1 + len(body)
    assert stats.crc_errors == stats.malformed == 0


def test_overflow_boundary() -> None:
    # 170 bytes with '\r' as the 170th: a (bad) frame, not an overflow.
    _frames, at_limit = feed_all([b"#" + b"=" * 168 + b"\r"])
    assert (at_limit.overflows, at_limit.crc_errors) == (0, 1)
    # 170 bytes without '\r': dropped as an overflow; the '\r' after it is garbage.
    _frames, over = feed_all([b"#" + b"=" * 169 + b"\r"])
    assert (over.overflows, over.crc_errors, over.malformed) == (1, 0, 0)
    assert over.discarded_bytes == 171


@given(frame_args)
def test_a_frame_encoder_gives_encode_frames_bytes(args: tuple[int, str, bytes]) -> None:
    addr, cmd, payload = args
    assert FrameEncoder(addr, cmd)(payload) == encode_frame(addr, cmd, payload)


def test_a_frame_encoder_refuses_what_encode_frame_refuses() -> None:
    with pytest.raises(ValueError, match=r"outside 0\.\.63"):
        FrameEncoder(64, "b")
    with pytest.raises(ValueError, match="buffer"):
        FrameEncoder(1, "b")(bytes(124))
