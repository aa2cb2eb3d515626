"""The SCIP 2.0 codec and reply parser against every vector of ``protocols/scip2.md`` §7.

The vectors are the in-project literals of ``tests/urg/vectors.py``; the tests marked
``shared`` also check those literals against the document itself when ``../shared`` is there
(``tests/conftest.py``), and are deselected on a clone without it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.errors import CommandRangeError
from mkflight.urg.codec import (
    data_blocks,
    decode_value,
    decode_values,
    encode_value,
    encode_values,
    gd_command,
    info_line,
    is_success,
    md_command,
    scip2_command,
    simple_command,
    status_line,
    status_message,
    sum_char,
    timestamp_line,
    tm_command,
)
from mkflight.urg.replies import InfoReply, Reply, ReplyParser, ScanReply, TimeReply
from tests.urg.vectors import (
    ALL_VECTORS,
    CODEC_VECTORS,
    CORRUPT,
    EXCHANGES,
    KIND_OF,
    EncodeVector,
    ExchangeVector,
    SumVector,
    TimestampVector,
)

#: The document the vectors are transcribed from, relative to the shared folder.
SCIP2_MD = "protocols/scip2.md"


def parse_one(data: bytes) -> tuple[list[Reply], ReplyParser]:
    parser = ReplyParser()
    return parser.feed(data), parser


# --- the document's §7 tables ---------------------------------------------------------------

_ROW = re.compile(r"^\|\s*(SC-C?\d+)\s*\|")


def _doc_rows(text: str) -> dict[str, tuple[str, dict[str, Any], list[bytes]]]:
    """id -> (kind, keyword fields, bytes columns) for every row of §7.1 and §7.2."""
    rows: dict[str, tuple[str, dict[str, Any], list[bytes]]] = {}
    for line in text.splitlines():
        m = _ROW.match(line)
        if not m:
            continue
        cells = re.findall(r"`([^`]*)`", line)
        n_bytes = 2 if cells[-2].startswith("b'") else 1
        call = ast.parse(cells[-1 - n_bytes], mode="eval").body
        assert isinstance(call, ast.Call), m[1]
        assert isinstance(call.func, ast.Name), m[1]
        fields = {kw.arg: ast.literal_eval(kw.value) for kw in call.keywords if kw.arg}
        data = [ast.literal_eval(c) for c in cells[-n_bytes:]]
        assert all(isinstance(d, bytes) for d in data), m[1]
        assert m[1] not in rows, f"{m[1]} appears twice"
        rows[m[1]] = (call.func.id, fields, data)
    return rows


@pytest.fixture(scope="module")
def doc_rows(shared_dir: Path) -> dict[str, tuple[str, dict[str, Any], list[bytes]]]:
    """The §7 rows of the shared document (only tests marked ``shared(SCIP2_MD)`` use it)."""
    return _doc_rows((shared_dir / SCIP2_MD).read_text(encoding="utf-8"))


def test_vector_ids() -> None:
    codec = [f"SC-C{i}" for i in range(1, 11)]
    exchanges = [f"SC-{i:02d}" for i in range(1, 22)]
    assert list(ALL_VECTORS) == codec + exchanges


@pytest.mark.shared(SCIP2_MD)
def test_document_lists_exactly_our_vectors(
    doc_rows: dict[str, tuple[str, dict[str, Any], list[bytes]]],
) -> None:
    assert list(doc_rows) == list(ALL_VECTORS)


@pytest.mark.shared(SCIP2_MD)
@pytest.mark.parametrize("vid", list(ALL_VECTORS))
def test_vector_equals_document(
    vid: str, doc_rows: dict[str, tuple[str, dict[str, Any], list[bytes]]]
) -> None:
    kind, fields, data = doc_rows[vid]
    columns = {"data": data[0]} if len(data) == 1 else {"command": data[0], "reply": data[1]}
    assert KIND_OF[kind](id=vid, **columns, **fields) == ALL_VECTORS[vid]  # type: ignore[arg-type]


# --- §7.1 codec vectors ----------------------------------------------------------------------


@pytest.mark.parametrize("vector", CODEC_VECTORS, ids=lambda v: v.id)
def test_codec_vector(vector: EncodeVector | SumVector | TimestampVector) -> None:
    if isinstance(vector, EncodeVector):
        assert encode_value(vector.value, vector.chars) == vector.data
        assert decode_value(vector.data) == vector.value
    elif isinstance(vector, SumVector):
        assert bytes((sum_char(vector.text),)) == vector.data
    else:
        assert timestamp_line(vector.ms) == vector.data
        assert decode_value(vector.data[:4]) == vector.ms


def test_status_and_info_lines() -> None:
    assert status_line("00") == b"00P"
    assert status_line("99") == b"99b"
    assert info_line("DMIN", "20") == b"DMIN:20;4"


def test_encode_rejects_out_of_range() -> None:
    with pytest.raises(ValueError, match="does not fit 2"):
        encode_value(4096, 2)
    with pytest.raises(ValueError, match="does not fit 3"):
        encode_value(-1, 3)
    with pytest.raises(ValueError, match="not a SCIP character"):
        decode_value(b"0p")


def test_decode_values_rejects_bad_length_and_characters() -> None:
    assert decode_values(b"1Dh00C", 3) == [5432, 19]
    assert decode_values(b"1Dh00", 3) is None
    assert decode_values(b"1D\x7f", 3) is None
    assert decode_values(b"CBCB", 4) == [decode_value(b"CBCB")]


# --- §7.2 exchanges: each reply parsed -------------------------------------------------------


@pytest.mark.parametrize("vector", EXCHANGES, ids=lambda v: v.id)
def test_exchange_reply_parses_as_fields_say(vector: ExchangeVector) -> None:
    replies, parser = parse_one(vector.reply)
    expected_status = vector.status or ("0" if vector.scip1 else "")
    stream = vector.scans
    assert len(replies) == 1 + len(stream)
    first = replies[0]
    assert first.echo == vector.command.rstrip(b"\n").decode()
    assert first.status == expected_status
    assert first.answers(vector.command)
    for key, value in vector.info.items():
        assert isinstance(first, InfoReply)
        assert first.info[key] == value
    if vector.values is not None:
        assert isinstance(first, ScanReply)
        assert first.timestamp_ms == vector.timestamp
        assert list(first.values) == vector.values
    else:
        assert not isinstance(first, ScanReply)
    for reply, (remaining, stamp, values) in zip(replies[1:], stream, strict=True):
        assert isinstance(reply, ScanReply)
        assert reply.status == "99"
        assert reply.answers(vector.command)
        assert reply.echo[-2:] == remaining
        assert reply.remaining == int(remaining)
        assert reply.timestamp_ms == stamp
        assert list(reply.values) == values
    assert parser.stats.replies == len(replies)
    assert parser.stats.dropped == parser.stats.garbage_lines == 0
    assert parser.buffered == 0


@pytest.mark.parametrize("vector", CORRUPT, ids=lambda v: v.id)
def test_corrupt_reply_is_dropped_and_counted(vector: ExchangeVector) -> None:
    replies, parser = parse_one(vector.reply)
    assert replies == []
    assert parser.stats.sum_errors == 1
    assert parser.stats.garbage_lines == 0
    # The parser resynchronises: the intact reply that follows is found.
    original = ALL_VECTORS["SC-11"]
    assert isinstance(original, ExchangeVector)
    assert len(parser.feed(original.reply)) == 1


@pytest.mark.parametrize("vector", EXCHANGES, ids=lambda v: v.id)
def test_split_at_every_byte_parses_the_same(vector: ExchangeVector) -> None:
    whole, _ = parse_one(vector.reply)
    data = vector.reply
    for cut in range(1, len(data)):
        parser = ReplyParser()
        assert parser.feed(data[:cut]) + parser.feed(data[cut:]) == whole, cut
    parser = ReplyParser()
    assert [r for i in range(len(data)) for r in parser.feed(data[i : i + 1])] == whole


def test_info_sum_with_or_without_the_semicolon() -> None:
    with_semicolon = b"DMIN:20;" + bytes((sum_char(b"DMIN:20;"),))
    (reply,), parser = parse_one(b"PP\n00P\n" + with_semicolon + b"\nDMAX:5600;_\n\n")
    assert isinstance(reply, InfoReply)
    assert reply.info == {"DMIN": "20", "DMAX": "5600"}
    assert parser.stats.sum_errors == 0
    _, parser = parse_one(b"PP\n00P\nDMIN:20;5\n\n")
    assert parser.stats.sum_errors == 1


def test_unknown_extra_info_line_is_kept_or_ignored() -> None:
    extra = b"just text"
    line = extra + bytes((sum_char(extra),))
    (reply,), _ = parse_one(
        b"VV\n00P\nXTRA:1;" + bytes((sum_char(b"XTRA:1"),)) + b"\n" + line + b"\n\n"
    )
    assert isinstance(reply, InfoReply)
    assert reply.info == {"XTRA": "1"}


def test_time_reply() -> None:
    (reply,), _ = parse_one(b"TM1\n00P\n" + timestamp_line(123456) + b"\n\n")
    assert isinstance(reply, TimeReply)
    assert reply.timestamp_ms == 123456


def test_lost_block_is_malformed_not_a_short_scan() -> None:
    values = encode_values([1000] * 100, 3)
    blocks = data_blocks(values).split(b"\n")
    reply = b"GD0100019901\n00P\n" + timestamp_line(5) + b"\n" + b"\n".join(blocks[1:])
    replies, parser = parse_one(reply + b"\n")
    assert replies == []
    assert parser.stats.malformed == 1


def test_scan_reply_without_data_is_malformed() -> None:
    _, parser = parse_one(b"GD0044072501\n00P\n\nMD0044072501000\n99b\n\n")
    assert parser.stats.malformed == 2


def test_garbage_lines_are_counted_and_reply_after_them_found() -> None:
    data = b"\x00\xffjunk\nAB\nxyz\nBM\n00P\n\n\n\nnoise only\n\n"
    replies, parser = parse_one(data)
    assert replies == [Reply("BM", "00")]
    assert parser.stats.garbage_lines == 4
    assert parser.stats.dropped == 0


def test_overlong_line_is_an_overflow() -> None:
    parser = ReplyParser()
    assert parser.feed(b"x" * 300) == []
    assert parser.feed(b"y" * 300 + b"\nQT\n00P\n\n") == [Reply("QT", "00")]
    assert parser.stats.overflows == 1


def test_tag_and_stream_matching() -> None:
    request = md_command(44, 725, 1, 0, 3, tag="g7")
    assert request == b"MD0044072501003;g7\n"
    message = Reply("MD0044072501002;g7", "99")
    assert message.tag == "g7"
    assert message.answers(request)
    assert not message.answers(md_command(44, 725, 1, 0, 3, tag="g8"))
    assert not Reply("MD0044072501002;g7", "00").answers(request)
    assert not Reply("GD0044072502", "00").answers(gd_command(44, 725, 1))


# --- command builders ------------------------------------------------------------------------


def test_commands_of_the_vectors() -> None:
    assert scip2_command() == b"SCIP2.0\n"
    assert [simple_command(c) for c in ("VV", "PP", "II", "BM", "QT", "RS")] == [
        b"VV\n",
        b"PP\n",
        b"II\n",
        b"BM\n",
        b"QT\n",
        b"RS\n",
    ]
    assert tm_command(2) == b"TM2\n"
    assert gd_command(44, 725) == b"GD0044072501\n"
    assert gd_command(380, 403, 1, chars=2) == b"GS0380040301\n"
    assert gd_command(380, 403, 3) == b"GD0380040303\n"
    assert md_command(384, 386, 1, 0, 2) == b"MD0384038601002\n"
    assert md_command(384, 386, 1, 1, 0, chars=2) == b"MS0384038601100\n"
    assert md_command(44, 725) == b"MD0044072501000\n"


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: gd_command(725, 44), "end_step 44 < start_step 725"),
        (lambda: gd_command(44, 800), "end_step = 800 outside 0..768"),
        (lambda: gd_command(-1, 10), "start_step = -1"),
        (lambda: gd_command(0, 10, 100), "cluster = 100"),
        (lambda: gd_command(0, 10, chars=4), "2 or 3 characters"),
        (lambda: md_command(0, 10, 1, 10), "interval = 10"),
        (lambda: md_command(0, 10, 1, 0, 100), "count = 100"),
        (lambda: md_command(0, 10, tag="x" * 17), "longer than 16"),
        (lambda: md_command(0, 10, tag="a;b"), "character outside"),
        (lambda: simple_command("vv"), "two capital letters"),
        (lambda: tm_command(3), "mode = 3"),
        (lambda: gd_command(True, 10), "start_step = True"),
    ],
)
def test_command_validation(call: Any, match: str) -> None:
    with pytest.raises(CommandRangeError, match=match):
        call()


def test_status_messages() -> None:
    assert status_message("GD0044072501", "10") == "laser is off (send BM first)"
    assert status_message("BM", "02") == "laser was already on (not an error)"
    assert status_message("SCIP2.0", "0") == "switched from SCIP 1.1 to SCIP 2.0"
    assert status_message("ZZ", "0E") == "undefined command or not allowed now"
    assert status_message("MD", "33") == "MD/MS stopped because of an error"
    assert status_message("MD", "60") == "hardware error"
    assert status_message("MD", "0Z") == "command rejected"
    assert is_success("SCIP2.0", "0")
    assert is_success("SCIP2.0", "0E")
    assert is_success("BM", "02")
    assert not is_success("GD", "02")
    assert not is_success("ZZ", "0E")
    assert Reply("GD0044072501", "10").message == "laser is off (send BM first)"


# --- properties ------------------------------------------------------------------------------


@given(st.data(), st.sampled_from([2, 3, 4]))
def test_encode_decode_identity(data: st.DataObject, chars: int) -> None:
    value = data.draw(st.integers(0, (1 << (6 * chars)) - 1))
    encoded = encode_value(value, chars)
    assert len(encoded) == chars
    assert all(0x30 <= c <= 0x6F for c in encoded)
    assert decode_value(encoded) == value


@given(st.lists(st.integers(0, 4095), max_size=700), st.sampled_from([2, 3]))
def test_values_round_trip_through_blocks(values: list[int], chars: int) -> None:
    encoded = encode_values(values, chars)
    joined = b"".join(line[:-1] for line in data_blocks(encoded).split(b"\n") if line)
    assert decode_values(joined, chars) == values


@given(st.lists(st.binary(max_size=80), max_size=20))
def test_parser_never_raises(chunks: list[bytes]) -> None:
    parser = ReplyParser()
    for chunk in chunks:
        parser.feed(chunk)
    assert parser.stats.bytes_in == sum(map(len, chunks))


@given(
    st.lists(st.binary(max_size=40).map(lambda b: b.replace(b"\n", b"")), max_size=8),
    st.sampled_from([v for v in EXCHANGES if v.values is not None]),
)
def test_reply_after_garbage_lines_is_found(garbage: list[bytes], vector: ExchangeVector) -> None:
    (expected,), _ = parse_one(vector.reply)
    replies, _ = parse_one(b"".join(g + b"\n" for g in garbage) + vector.reply)
    assert replies[-1:] == [expected]
