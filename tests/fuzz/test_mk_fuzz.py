"""Fuzzing the MK frame parser and the link (``mk-serial.md`` §2-3, §9).

Streams of pieces (``tools/fuzz.py``) cut into arbitrary reads: every embedded valid frame is
found, in order, and every counter is exactly the pieces' sum; arbitrary bytes decode as an
independent one-byte-at-a-time decoder of §3 says; one flipped bit costs at most its own
frame. Then the real link on a real pty: every embedded DebugOut arrives, the counters add
up, and nothing it writes is out of limits.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Callable
from typing import TypeVar

import pytest
from fuzz import (
    Piece,
    Totals,
    check,
    frame_bytes,
    join,
    mk_corrupt,
    mk_frame,
    mk_garbage,
    mk_lookalike,
    mk_malformed,
    mk_message,
    mk_overflow,
    mk_truncated,
    run_mk_link,
    split,
)
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mkflight.mk.codec import Frame, FrameParser
from mkflight.mk.messages import (
    Confirm,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
    VersionInfo,
    debug_request,
    label_request,
    ppm_request,
    version_request,
)
from tests.mk.vectors import (
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

FUZZ = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --- the document's frames as pieces ---------------------------------------------------------
def vector_piece(v: FrameLike) -> Piece[Frame]:
    """A §9.1 vector rebuilt from its fields by the fuzz builders."""
    if isinstance(v, FrameVector):
        return mk_frame(v.addr, v.cmd, v.payload)
    if isinstance(v, DebugRequestVector):
        return mk_frame(v.addr, "d", bytes((v.interval,)))
    if isinstance(v, VersionInfoVector):
        head = (v.sw_major, v.sw_minor, v.proto_major, v.proto_minor, v.sw_patch)
        return mk_message(VersionInfo(*head, v.hardware_error, v.addr))
    if isinstance(v, DebugOutVector):
        return mk_message(DebugOut.from_values(v.analog, v.status, v.addr))
    if isinstance(v, ExternControlVector):
        wire = (v.nick, v.roll, v.yaw, v.gas, v.height, v.frame, v.config, v.digital)
        return mk_message(ExternControl(*wire, v.remote_buttons, v.free, v.addr))
    if isinstance(v, ConfirmVector):
        return mk_message(Confirm(v.frame, v.addr))
    if isinstance(v, PpmVector):
        return mk_message(Ppm.from_channels(v.channels, v.addr))
    assert isinstance(v, LabelVector)
    return mk_message(Label(v.index, v.label, v.addr))


VECTORS = {v.id: vector_piece(v) for v in SINGLE_FRAME_VECTORS}


def test_the_builders_write_the_documents_bytes() -> None:
    for v in SINGLE_FRAME_VECTORS:
        assert VECTORS[v.id].data == v.data, v.id
    assert mk_frame(1, "v").data == version_request()
    assert mk_frame(1, "d", b"\x05").data == debug_request(5)
    assert mk_frame(1, "a", b"\x07").data == label_request(7)
    assert mk_frame(1, "p").data == ppm_request()


# --- strategies: every frame the link knows, and the ways frames go wrong --------------------
u8 = st.integers(0, 255)
s8 = st.integers(-128, 127)
s16 = st.integers(-32768, 32767)
addrs = st.integers(0, 63) | st.just(1)
messages = st.one_of(
    st.builds(DebugOut, status=st.tuples(u8, u8), analog=st.tuples(*[s16] * 32), addr=addrs),
    st.builds(VersionInfo, u8, u8, u8, u8, u8, st.binary(min_size=5, max_size=5), addrs),
    st.builds(
        ExternControl,
        nick=s8,
        roll=s8,
        yaw=s8,
        gas=u8,
        height=s8,
        frame=u8,
        config=u8,
        digital=st.tuples(u8, u8),
        remote_buttons=u8,
        free=u8,
        addr=addrs,
    ),
    st.builds(Confirm, u8, addrs),
    st.builds(Ppm, st.tuples(*[s16] * 26), addrs),
    st.builds(
        Label, u8, st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=20), addrs
    ),
).map(mk_message)
requests = st.one_of(
    st.sampled_from([mk_frame(1, "v"), mk_frame(0, "v"), mk_frame(1, "p")]),
    st.tuples(st.sampled_from("da"), u8).map(lambda t: mk_frame(1, t[0], bytes((t[1],)))),
    st.binary(min_size=8, max_size=8).map(lambda p: mk_frame(3, "k", p)),  # MK3MAG, §7.6
)
commands = st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters="#")
payloads = st.binary(max_size=123) | st.binary(min_size=121, max_size=123)  # up to 170 bytes
any_frames = st.builds(mk_frame, st.integers(0, 63), commands, payloads)
valid = st.one_of(messages, requests, any_frames)
noise = st.binary(max_size=200) | st.lists(st.sampled_from(b"#\r\n=>|bDd~\x00\xff")).map(bytes)
big = st.integers(0, 1 << 16)
broken = st.one_of(
    st.builds(mk_corrupt, valid, big, u8),
    st.builds(lambda f, cut, then: mk_truncated(f.data, cut, then), valid, big, valid),
    st.builds(mk_lookalike, noise, valid),
    st.builds(mk_overflow, noise, st.integers(0, 400)),
    st.builds(mk_malformed, big, noise, u8),
    st.builds(mk_garbage, noise),
)
streams = st.lists(valid | broken, max_size=10).map(join)
# Reads: cut anywhere, or every k bytes (k = 1: byte by byte).
cuts = st.lists(st.integers(0, 1 << 16), max_size=30) | st.integers(1, 24).map(
    lambda k: list(range(0, 1 << 13, k))
)


def feed(parser: FrameParser, data: bytes, at: list[int]) -> list[Frame]:
    return [f for chunk in split(data, at) for f in parser.feed(chunk)]


@FUZZ
@given(stream=streams, at=cuts)
@example(stream=join(VECTORS.values()), at=[])
@example(stream=join(VECTORS.values()), at=list(range(0, 2000, 3)))
@example(stream=join([mk_corrupt(VECTORS["MK-03"], 20, ord("I")), VECTORS["MK-13"]]), at=[4])
@example(stream=mk_truncated(VECTORS["MK-04"].data, 4, VECTORS["MK-13"]), at=[])  # MK-23
@example(
    stream=join([mk_garbage(b"\x00\xff\r\nAT+X\r"), VECTORS["MK-19"], VECTORS["MK-13"]]), at=[]
)
def test_every_embedded_frame_is_found_and_the_counters_add_up(
    stream: Piece[Frame], at: list[int]
) -> None:
    parser = FrameParser()
    frames = feed(parser, stream.data, at)
    assert frames == list(stream.valid)
    totals = Totals()
    totals.add(stream)
    assert check(parser.stats, totals, sum(map(frame_bytes, frames)), parser.buffered) == []
    assert parser.buffered == 0


# --- arbitrary bytes against an independent decoder -------------------------------------------
def reference(data: bytes) -> tuple[list[Frame], Counter[str], int]:
    """§3 one byte at a time, §2.2-2.3 by their formulas: frames, counters, bytes held."""
    frames: list[Frame] = []
    n: Counter[str] = Counter()
    buf: bytearray | None = None
    for b in data:
        if b == ord("#"):
            n["discarded_bytes"] += len(buf or b"")
            buf = bytearray(b"#")
        elif buf is None:
            n["discarded_bytes"] += 1
        else:
            buf.append(b)
            if b == ord("\r"):
                frame = _decode(bytes(buf), n)
                if frame is None:
                    n["discarded_bytes"] += len(buf)
                else:
                    frames.append(frame)
                buf = None
            elif len(buf) == 170:
                n["overflows"] += 1
                n["discarded_bytes"] += 170
                buf = None
    return frames, n, len(buf or b"")


def _decode(raw: bytes, n: Counter[str]) -> Frame | None:
    if len(raw) < 6:
        n["malformed"] += 1
        return None
    crc = sum(raw[:-3]) % 4096
    if raw[-3:-1] != bytes((61 + crc // 64, 61 + crc % 64)):
        n["crc_errors"] += 1
        return None
    chars = [c - 61 for c in raw[3:-3]]
    if len(chars) % 4 or any(not 0 <= v < 64 for v in chars) or not 0 <= raw[1] - 97 < 64:
        n["malformed"] += 1
        return None
    payload = bytearray()
    for v1, v2, v3, v4 in zip(*[iter(chars)] * 4, strict=True):
        payload += bytes(
            ((v1 << 2) | (v2 >> 4), ((v2 & 15) << 4) | (v3 >> 2), ((v3 & 3) << 6) | v4)
        )
    return Frame(raw[1] - 97, chr(raw[2]), bytes(payload))


Test = TypeVar("Test", bound=Callable[..., None])


def _stream_examples(test: Test) -> Test:
    for v in STREAM_VECTORS:  # MK-20..24, split where the document splits them
        test = example(data=v.data, at=list(v.split_at))(test)
    return test


near_full = st.tuples(st.integers(160, 180), st.sampled_from([b"", b"\r", b"#"]))
framey = st.lists(
    st.binary(max_size=12)
    | valid.map(lambda p: p.data)
    | noise
    | near_full.map(lambda t: b"#" + b"=" * t[0] + t[1]),
    max_size=12,
)


@FUZZ
@given(data=framey.map(b"".join) | st.binary(max_size=600), at=cuts)
@_stream_examples
def test_any_bytes_in_any_reads_decode_as_the_reference_says(data: bytes, at: list[int]) -> None:
    parser = FrameParser()
    frames = feed(parser, data, at)
    want_frames, want, held = reference(data)
    assert frames == want_frames
    s = parser.stats
    assert (s.bytes_in, s.frames, parser.buffered) == (len(data), len(want_frames), held)
    assert (s.crc_errors, s.malformed, s.overflows) == (
        want["crc_errors"],
        want["malformed"],
        want["overflows"],
    )
    assert s.discarded_bytes == want["discarded_bytes"]
    assert sum(map(frame_bytes, frames)) + s.discarded_bytes + parser.buffered == s.bytes_in


@pytest.mark.parametrize("vector", STREAM_VECTORS, ids=lambda v: v.id)
def test_the_reference_agrees_with_the_documents_streams(vector: StreamVector) -> None:
    v = vector
    frames, n, _ = reference(v.data)
    assert [(f.addr, f.cmd, f.payload.hex()) for f in frames] == list(v.frames)
    assert (n["crc_errors"], n["discarded_bytes"]) == (v.crc_errors, v.discarded)


# --- flipped bits and cut frames --------------------------------------------------------------
@FUZZ
@given(frame=valid, index=big, bit=st.integers(0, 7), then=valid, at=cuts)
def test_a_flipped_bit_costs_at_most_its_own_frame(
    frame: Piece[Frame], index: int, bit: int, then: Piece[Frame], at: list[int]
) -> None:
    i = index % len(frame.data)
    flipped = frame.data[i] ^ (1 << bit)
    data = frame.data[:i] + bytes((flipped,)) + frame.data[i + 1 :] + then.data
    parser = FrameParser()
    frames = feed(parser, data, at)
    assert frames[-1:] == list(then.valid)  # the next frame always survives
    assert frame.valid[0] not in frames[:-1] or frame.valid == then.valid
    s = parser.stats
    assert sum(map(frame_bytes, frames)) + s.discarded_bytes + parser.buffered == s.bytes_in
    if 0 < i < len(frame.data) - 1 and flipped not in b"#\r":
        assert (frames, s.crc_errors, s.discarded_bytes) == (list(then.valid), 1, len(frame.data))


@pytest.mark.parametrize("vector", SINGLE_FRAME_VECTORS, ids=lambda v: v.id)
def test_every_cut_of_every_vector_frame_is_abandoned_for_the_next(vector: FrameLike) -> None:
    confirm = VECTORS["MK-13"]
    for cut in range(1, len(vector.data)):
        parser = FrameParser()
        assert parser.feed(vector.data[:cut] + confirm.data) == list(confirm.valid)
        assert (parser.stats.discarded_bytes, parser.stats.crc_errors) == (cut, 0)


# --- the link on a real pty -------------------------------------------------------------------
async def test_the_link_on_a_pty_gets_every_debugout_and_writes_only_safe_commands() -> None:
    result = await run_mk_link(400, random.Random(10))
    assert result.problems == []
    assert (result.tried, result.missed, result.exceptions, result.mismatches) == (400, 0, 0, 0)
    assert result.out_of_limit == 0
    assert result.found == result.valid > 250
    assert result.notes["commands accepted"] > 20
    assert result.notes["commands refused"] > 20
    assert result.notes["crc_errors"] > 10
    assert result.notes["malformed"] > 10
