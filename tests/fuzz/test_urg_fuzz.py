"""Fuzzing the SCIP 2.0 reply parser and the URG driver (``scip2.md`` §2, §6-7).

Streams of pieces (``tools/fuzz.py``) cut into arbitrary reads: every embedded valid reply of
every kind the parser returns is found, in order, and every counter, ``discarded_bytes``
included, is exactly the pieces' sum; arbitrary bytes never raise, parse the same whatever
the reads, and a reply after them (and an empty line) is still found. Then the real driver on
a real pty: every embedded scan of its stream arrives unchanged and the counters add up.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Callable
from typing import TypeVar

from fuzz import (
    Piece,
    Scip,
    Totals,
    check,
    join,
    run_urg_driver,
    scip1_switch,
    scip_after_garbage,
    scip_body,
    scip_corrupt,
    scip_garbage_block,
    scip_info,
    scip_malformed,
    scip_scan,
    scip_status,
    scip_time,
    scip_truncated,
    split,
)
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mkflight.urg.codec import value_count
from mkflight.urg.replies import Reply, ReplyParser
from tests.urg.vectors import CORRUPT, EXCHANGES

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
Test = TypeVar("Test", bound=Callable[..., None])

# --- strategies: every reply the parser returns, and the ways replies go wrong ---------------
u8 = st.integers(0, 255)
big = st.integers(0, 1 << 16)
tags = st.just("") | st.text("ABCxyz019 ._+@", max_size=16)
printable = st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters=";")
statuses = st.text("0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ", min_size=2, max_size=2)
# Echoes of commands the parser does not read data for (not GD/GS/MD/MS, VV/PP/II, TM).
plain_echoes = st.builds(
    lambda head, rest: head + rest,
    st.text("ABCDEFHJKLNOQRSUWXYZ", min_size=2, max_size=2),
    st.text(printable, max_size=20),
)


@st.composite
def scans(draw: st.DrawFn, most: int = 150) -> Scip:
    cmd = draw(st.sampled_from(["GD", "GS", "MD", "MS"]))
    start = draw(st.integers(0, 768))
    end = draw(st.integers(start, min(768, start + most)))
    cluster = draw(st.integers(0, 99) | st.just(1))
    top = (1 << (6 * (3 if cmd[1] == "D" else 2))) - 1
    n = value_count(start, end, cluster)
    values = draw(st.lists(st.integers(0, top), min_size=n, max_size=n))
    return scip_scan(
        cmd,
        (start, end, cluster),
        values,
        draw(st.integers(0, (1 << 24) - 1)),
        interval=draw(st.integers(0, 9)),
        remaining=draw(st.integers(0, 99)),
        tag=draw(tags),
    )


def _status_only(echo: str, status: str) -> Scip:
    """A scan command's reply without data must not carry the data status (00 GD, 99 MD)."""
    if status == ("00" if echo[0] == "G" else "99"):
        status = "0E"
    return scip_status(echo, status)


scan_echoes = st.builds(
    lambda cmd, steps: f"{cmd}{steps}",
    st.sampled_from(["GD", "GS", "MD", "MS"]),
    st.text("0123456789x", max_size=13),
)
info_texts = st.builds(
    lambda k, v: f"{k}:{v}",
    st.text("ABCDMNOPST", min_size=1, max_size=4),
    st.text(printable, max_size=40),
)
times = st.builds(scip_time, st.integers(0, (1 << 24) - 1), tags)
replies = st.one_of(
    scans(),
    st.builds(
        scip_status,
        plain_echoes | st.sampled_from(["BM", "QT", "RS", "TM2", "VV", "SCIP2.0"]),
        statuses,
    ),
    st.builds(_status_only, scan_echoes, statuses),
    st.just(scip1_switch()),
    st.builds(
        scip_info,
        st.sampled_from(["VV", "PP", "II"]),
        st.lists(
            st.tuples(info_texts | st.text(printable, max_size=30), st.integers(0, 2)), max_size=8
        ),
    ),
    times,
    st.builds(
        scip_body,
        plain_echoes,
        statuses,
        st.lists(
            st.binary(min_size=1, max_size=40).map(lambda b: b.replace(b"\n", b".")), max_size=4
        ),
    ),
)
lookalike_lines = st.sampled_from(
    [
        b"MD0044072501000;g1",
        b"GD0044072501",
        b"VV",
        b"SCIP2.0",
        b"0",
        b"00P",
        b"99b",
        b"0Ee",
        b"JUGnD",
        b"",
        b"DMIN:20;4",
        b"1Dh00C000@",
        b"\r",
    ]
)
garbage_lines = st.lists(
    lookalike_lines | st.binary(max_size=40) | st.binary(min_size=250, max_size=300), max_size=8
)


def _or_nothing(piece: Piece[Reply] | None) -> Piece[Reply]:
    """A piece the builder could not make becomes an LF (it also ends a block)."""
    return piece if piece is not None else Piece(b"\n")


broken = st.one_of(
    st.builds(scip_corrupt, replies, big, big, u8).map(_or_nothing),
    st.builds(lambda r, line, chars: scip_truncated(r, line, chars), scans(), big, big).map(
        _or_nothing
    ),
    st.builds(scip_malformed, scans() | times, big, big, u8).map(_or_nothing),
    st.builds(scip_garbage_block, garbage_lines),
)
pieces = replies.map(Scip.piece) | broken
pieces = pieces | st.builds(scip_after_garbage, garbage_lines, pieces)
streams = st.lists(pieces, max_size=8).map(join)
cuts = st.lists(st.integers(0, 1 << 16), max_size=30) | st.integers(1, 24).map(
    lambda k: list(range(0, 1 << 14, k))
)


def feed(parser: ReplyParser, data: bytes, at: list[int]) -> list[Reply]:
    return [r for chunk in split(data, at) for r in parser.feed(chunk)]


@FUZZ
@given(stream=streams, at=cuts)
def test_every_embedded_reply_is_found_and_the_counters_add_up(
    stream: Piece[Reply], at: list[int]
) -> None:
    parser = ReplyParser()
    assert feed(parser, stream.data, at) == list(stream.valid)
    totals = Totals()
    totals.add(stream)
    assert check(parser.stats, totals, sum(stream.sizes), parser.buffered) == []
    assert parser.buffered == 0


def _exchange_examples(test: Test) -> Test:
    sc = [v.reply for v in EXCHANGES] + [v.reply for v in CORRUPT]  # SC-01..SC-21
    for reply in sc:  # whole and byte by byte
        for at in ([], list(range(len(reply)))):
            test = example(data=reply, at=at, then=scip_status("QT", "00"))(test)
    return test


@FUZZ
@given(
    data=st.lists(lookalike_lines | st.binary(max_size=80) | st.just(b"\n"), max_size=20).map(
        b"\n".join
    )
    | st.binary(max_size=600),
    at=cuts,
    then=replies,
)
@_exchange_examples
def test_any_bytes_in_any_reads_parse_alike_and_a_reply_after_them_is_found(
    data: bytes, at: list[int], then: Scip
) -> None:
    whole, chunked = ReplyParser(), ReplyParser()
    stream = data + b"\n\n" + then.piece().data
    replies = whole.feed(stream)
    assert feed(chunked, stream, at) == replies
    assert dataclasses.asdict(chunked.stats) == dataclasses.asdict(whole.stats)
    assert replies[-1:] == [then.expected]
    s = whole.stats
    assert s.bytes_in == len(stream)
    assert 0 <= s.discarded_bytes <= s.bytes_in - len(then.piece().data)
    assert whole.buffered == 0


@FUZZ
@given(reply=replies, index=big, bit=st.integers(0, 7), then=replies, at=cuts)
def test_a_flipped_bit_costs_at_most_its_own_reply(
    reply: Scip, index: int, bit: int, then: Scip, at: list[int]
) -> None:
    data = reply.piece().data
    i = index % len(data)
    tail = then.piece().data
    stream = data[:i] + bytes((data[i] ^ (1 << bit),)) + data[i + 1 :] + b"\n\n" + tail
    parser = ReplyParser()
    assert feed(parser, stream, at)[-1:] == [then.expected]
    s = parser.stats
    assert s.bytes_in - s.discarded_bytes - parser.buffered >= len(tail)


# --- the driver on a real pty -----------------------------------------------------------------
async def test_the_driver_on_a_pty_gets_every_scan_of_its_stream() -> None:
    result = await run_urg_driver(80, random.Random(11))
    assert result.problems == []
    assert (result.tried, result.missed, result.exceptions, result.mismatches) == (80, 0, 0, 0)
    assert result.found == result.valid > 30
    assert result.notes["scans"] > 25
    assert result.notes["sum_errors"] > 5
