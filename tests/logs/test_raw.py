from __future__ import annotations

import errno
import io
import tempfile
from pathlib import Path
from typing import BinaryIO

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.clock import ManualClock
from mkflight.errors import ReplayError
from mkflight.io.stream import Tap
from mkflight.logs.raw import (
    FORMAT_VERSION,
    MAGIC,
    RawHeader,
    RawRecord,
    RawRecorder,
    read_raw,
)

WALL_NS = 1_700_000_000_123_456_789
HEADER_BYTES = 28  # fixed part of the header, before the port label


def _recorder(path: Path, port: str = "/dev/ttyUSB0", start_ns: int = 5_000) -> RawRecorder:
    return RawRecorder(path, port, clock=ManualClock(start_ns), wall_clock_ns=lambda: WALL_NS)


def _write(rec: RawRecorder, records: list[RawRecord]) -> None:
    for r in records:
        if r.kind in "rw":
            rec(r.kind, r.t_ns, r.data)
        else:
            rec.mark(r.kind, r.t_ns, r.text)


_int64 = st.integers(min_value=-(2**63), max_value=2**63 - 1)
_data_record = st.builds(RawRecord, _int64, st.sampled_from("rw"), st.binary(max_size=300))
_event_record = st.builds(
    lambda t, k, text: RawRecord(t, k, text.encode("utf-8")),
    _int64,
    st.sampled_from("oc"),
    st.text(max_size=40),
)


@given(
    records=st.lists(st.one_of(_data_record, _event_record), max_size=40),
    port=st.text(max_size=60),
    start_ns=_int64,
)
def test_round_trip(records: list[RawRecord], port: str, start_ns: int) -> None:
    # a port's records are in time order (the tap is called in order, on one clock)
    times = sorted(r.t_ns for r in records)
    records = [RawRecord(t, r.kind, r.data) for t, r in zip(times, records, strict=True)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mk.raw"
        with _recorder(path, port, start_ns) as rec:
            _write(rec, records)
        got = read_raw(path)
    assert got.header == RawHeader(FORMAT_VERSION, port, WALL_NS, start_ns)
    assert got.records == records  # order, times, kinds and bytes all kept
    assert got.truncated_at is None
    assert got.warning is None
    assert rec.records == len(records)
    assert rec.bytes_read == sum(len(r.data) for r in records if r.kind == "r")
    assert rec.bytes_written == sum(len(r.data) for r in records if r.kind == "w")
    assert got.payload("r") == b"".join(r.data for r in records if r.kind == "r")
    assert (rec.dropped, rec.errors, rec.error) == (0, 0, None)


def test_records_out_of_time_order_are_damage_named_by_byte_offset(tmp_path: Path) -> None:
    path = tmp_path / "mk.raw"
    with _recorder(path, "/dev/ttyUSB0") as rec:
        rec("r", 5_000, b"#a")
        rec("w", 6_000, b"#b")
        rec("r", 4_000, b"#c")  # back in time: a damaged file, not a recording
    with pytest.raises(ReplayError, match=r"mk\.raw: byte \d+: record time 4000 ns is before"):
        read_raw(path)


def test_recorder_is_a_tap_and_each_record_is_on_disk_at_once(tmp_path: Path) -> None:
    path = tmp_path / "laser.raw"
    rec = _recorder(path, "/dev/ttyACM0")
    tap: Tap = rec
    tap("w", 6_000, b"MD0044072501000\n")
    assert read_raw(path).records == [RawRecord(6_000, "w", b"MD0044072501000\n")]
    rec.mark("c", 7_000, "device vanished")
    rec.mark("o", 9_000, "/dev/ttyACM0")
    tap("r", 9_500, b"MD")
    got = read_raw(path)  # not closed yet: nothing waits in a buffer
    assert [(r.t_ns, r.kind) for r in got] == [
        (6_000, "w"),
        (7_000, "c"),
        (9_000, "o"),
        (9_500, "r"),
    ]
    assert got.records[1].text == "device vanished"
    assert got.header.port_name == "/dev/ttyACM0"
    assert got.header.wall_ns(9_500) == WALL_NS + 4_500  # start_t_ns = 5_000
    rec.close()
    rec.close()  # idempotent
    tap("r", 10_000, b"late")  # after close: dropped, not raised
    assert rec.dropped == 1
    assert rec.error is None
    assert len(read_raw(path).records) == 4


def test_bad_kinds_are_caller_bugs(tmp_path: Path) -> None:
    with _recorder(tmp_path / "mk.raw") as rec:
        with pytest.raises(ValueError, match="direction must be 'r' or 'w', got 'x'"):
            rec("x", 1, b"a")
        with pytest.raises(ValueError, match="event kind must be 'o' or 'c', got 'r'"):
            rec.mark("r", 1, "a")
    assert read_raw(tmp_path / "mk.raw").records == []


def test_existing_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "mk.raw"
    path.write_bytes(b"an earlier flight")
    with pytest.raises(FileExistsError, match=r"not overwriting.*mk\.raw"):
        _recorder(path)
    assert path.read_bytes() == b"an earlier flight"


def _small_file(tmp_path: Path) -> tuple[bytes, list[RawRecord], list[int]]:
    """A recording's bytes, its records and the byte offset where each record starts."""
    records = [
        RawRecord(10, "o", b"/dev/x"),
        RawRecord(20, "w", b"#bv====\r"),
        RawRecord(30, "r", b""),
        RawRecord(40, "r", b"#bV\r"),
        RawRecord(50, "c", b"lost"),
    ]
    path = tmp_path / "small.raw"
    with _recorder(path, "/dev/x") as rec:
        _write(rec, records)
    starts = [HEADER_BYTES + len("/dev/x")]
    for r in records[:-1]:
        starts.append(starts[-1] + 13 + len(r.data))
    blob = path.read_bytes()
    assert len(blob) == starts[-1] + 13 + len(records[-1].data)
    return blob, records, starts


def test_truncation_at_every_byte(tmp_path: Path) -> None:
    blob, records, starts = _small_file(tmp_path)
    cut_path = tmp_path / "cut.raw"
    for size in range(len(blob) + 1):
        cut_path.write_bytes(blob[:size])
        if size < starts[0]:
            with pytest.raises(ReplayError, match=r"cut\.raw: byte \d+: "):
                read_raw(cut_path)
            continue
        got = read_raw(cut_path)
        complete = [i for i, s in enumerate(starts) if s + 13 + len(records[i].data) <= size]
        assert got.records == records[: len(complete)], size
        if size in [*starts, len(blob)]:
            assert got.truncated_at is None, size
        else:
            assert got.truncated_at == starts[len(complete)], size
            assert got.warning is not None
            assert f"byte {got.truncated_at}" in got.warning
            assert f"({size - got.truncated_at} bytes)" in got.warning


def test_broken_headers_name_file_and_offset(tmp_path: Path) -> None:
    blob, _, starts = _small_file(tmp_path)
    path = tmp_path / "bad.raw"
    path.write_bytes(b"")
    with pytest.raises(ReplayError, match=r"bad\.raw: byte 0: header cut short"):
        read_raw(path)
    path.write_bytes(b"MKR")
    with pytest.raises(ReplayError, match=r"bad\.raw: byte 3: header cut short"):
        read_raw(path)
    path.write_bytes(b"t_ns dir data\n1 r abc\n" + blob)
    with pytest.raises(ReplayError, match=r"bad\.raw: byte 0: not a raw recording"):
        read_raw(path)
    path.write_bytes(MAGIC.replace(b"\r\n", b"\n") + blob[8:])  # a text-mode copy
    with pytest.raises(ReplayError, match="not a raw recording"):
        read_raw(path)
    path.write_bytes(blob[:8] + (2).to_bytes(2, "little") + blob[10:])
    with pytest.raises(ReplayError, match=r"bad\.raw: byte 8: unknown format version 2"):
        read_raw(path)
    path.write_bytes(blob[:HEADER_BYTES] + b"/dev/\xff" + blob[starts[0] :])
    with pytest.raises(ReplayError, match=rf"bad\.raw: byte {HEADER_BYTES + 5}: port label"):
        read_raw(path)
    kind_at = starts[1] + 8
    path.write_bytes(blob[:kind_at] + b"x" + blob[kind_at + 1 :])
    with pytest.raises(ReplayError, match=rf"bad\.raw: byte {kind_at}: unknown record kind"):
        read_raw(path)
    with pytest.raises(ReplayError, match=r"missing\.raw: cannot read"):
        read_raw(tmp_path / "missing.raw")


class _FillingDisk(io.FileIO):
    """A real file whose writes fail with ENOSPC after ``room`` bytes (part-writes first)."""

    def __init__(self, path: Path, room: int) -> None:
        super().__init__(path, "xb")
        self.room = room
        self.attempts = 0

    def write(self, data: object, /) -> int:
        assert isinstance(data, bytes | memoryview)
        self.attempts += 1
        if self.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = super().write(bytes(data)[: self.room])
        assert n is not None
        self.room -= n
        return n


def test_disk_full_mid_flight_stops_recording_without_raising(tmp_path: Path) -> None:
    path = tmp_path / "mk.raw"
    disks: list[_FillingDisk] = []

    def opener(p: Path) -> BinaryIO:
        disks.append(_FillingDisk(p, room=HEADER_BYTES + 2 + 2 * (13 + 4) + 5))
        return disks[0]

    rec = RawRecorder(path, "mk", clock=ManualClock(0), opener=opener)
    rec("r", 1, b"abcd")
    rec("w", 2, b"efgh")
    assert rec.recording
    rec("r", 3, b"ijklmnop")  # 5 bytes fit, then ENOSPC
    rec("r", 4, b"q")
    rec.mark("c", 5, "lost")
    assert not rec.recording
    assert rec.error is not None
    assert rec.error.errno == errno.ENOSPC
    assert (rec.errors, rec.dropped, rec.records) == (1, 3, 2)
    assert (rec.bytes_read, rec.bytes_written) == (4, 4)
    # header, two records, the third's part-write and its ENOSPC retry: none after that
    assert disks[0].attempts == 5
    rec.close()
    got = read_raw(path)
    assert got.records == [RawRecord(1, "r", b"abcd"), RawRecord(2, "w", b"efgh")]
    assert got.truncated_at == HEADER_BYTES + 2 + 2 * (13 + 4)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_disk_full_before_take_off_raises(tmp_path: Path) -> None:
    def opener(_: Path) -> BinaryIO:
        return open("/dev/full", "wb", buffering=0)  # the recorder closes it

    with pytest.raises(OSError, match="No space left") as info:
        RawRecorder(tmp_path / "mk.raw", "mk", opener=opener)
    assert info.value.errno == errno.ENOSPC


def test_port_label_too_long(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="port label too long"):
        _recorder(tmp_path / "mk.raw", "x" * 70_000)
    assert not (tmp_path / "mk.raw").exists()


def test_damage_is_not_taken_for_a_killed_process(tmp_path: Path) -> None:
    """A header overwritten mid-file (its length now past the end, its time absurd) is an
    error naming the byte, not a 'truncated tail' that silently drops the rest."""
    path = tmp_path / "mk.raw"
    with _recorder(path) as rec:
        for t in (6_000, 7_000, 8_000):
            rec("r", t, b"#bD" + b"=" * 60 + b"\r")
    blob = bytearray(path.read_bytes())
    third = len(blob) - (13 + 64)
    blob[third : third + 8] = b"\xff" * 8  # t_ns
    blob[third + 9 : third + 13] = b"\xff" * 4  # length
    path.write_bytes(bytes(blob))
    with pytest.raises(ReplayError, match=rf"byte {third}: .* corrupt"):
        read_raw(path)
