"""Chunks handed over in the callback that brought them (``ChunkQueue.deliver_to``), and
the MK link reading that way on a real serial port (a pty), crash and end included."""

from __future__ import annotations

import asyncio

import pytest

from mkflight.errors import LinkError
from mkflight.io.pty import PtyDevice
from mkflight.io.serial import SerialStream, open_serial
from mkflight.io.stream import ChunkQueue, MemoryStream, PushStream
from mkflight.mk.codec import FrameEncoder, encode_frame
from mkflight.mk.link import MkLink
from mkflight.mk.link_types import Tap
from mkflight.mk.messages import CMD_DEBUG_ANSWER
from mkflight.mk.units import DEFAULT_CALIBRATION
from tests.mk.fakes import FAST


async def test_chunks_go_to_the_receiver_as_they_come_and_the_end_once() -> None:
    q = ChunkQueue("q")
    got: list[bytes] = []
    ends: list[LinkError] = []
    q.deliver_to(got.append, ends.append)
    q.put(b"ab")
    assert got == [b"ab"]  # inside put: no loop turn
    q.fail(LinkError("gone"))
    q.fail(LinkError("again"))
    assert [str(e) for e in ends] == ["gone"]
    with pytest.raises(LinkError, match="gone"):
        await q.get()


async def test_what_was_queued_goes_over_on_the_next_turn_then_queueing_again() -> None:
    q = ChunkQueue("q")
    q.put(b"1")
    q.put(b"2")
    got: list[bytes] = []
    q.deliver_to(got.append)
    assert got == []  # never inside deliver_to
    await asyncio.sleep(0)
    assert got == [b"1", b"2"]
    q.deliver_to(None)
    q.put(b"3")
    assert got == [b"1", b"2"]
    assert await q.get() == b"3"


async def test_an_ended_stream_tells_a_late_receiver_its_end() -> None:
    q = ChunkQueue("q")
    q.put(b"x")
    q.fail(LinkError("closed"))
    got: list[bytes] = []
    ends: list[LinkError] = []
    q.deliver_to(got.append, ends.append)
    await asyncio.sleep(0)
    assert got == [b"x"]
    assert [str(e) for e in ends] == ["closed"]


async def test_only_ports_whose_chunks_come_in_a_loop_callback_push() -> None:
    dev = PtyDevice("fc")
    try:
        stream = await open_serial(dev.path, 57600)
        try:
            assert isinstance(stream, SerialStream)
            assert isinstance(stream, PushStream)
        finally:
            await stream.close()
    finally:
        dev.vanish()
    # a memory pair delivers inside the peer's write: it keeps the reader task
    assert not isinstance(MemoryStream("m"), PushStream)


def _debug_frame() -> bytes:
    return FrameEncoder(1, CMD_DEBUG_ANSWER)(bytes(66))


async def _link_on_pty(tap: Tap) -> tuple[PtyDevice, MkLink]:
    dev = PtyDevice("fc")
    stream = await open_serial(dev.path, 57600)
    return dev, MkLink(stream, FAST, DEFAULT_CALIBRATION, tap=tap)


async def test_the_link_reads_a_serial_port_in_its_callback_and_ends_with_it() -> None:
    tap: list[tuple[str, int, bytes]] = []
    dev, link = await _link_on_pty(lambda d, t, data: tap.append((d, t, data)))
    try:
        link.start()
        frame = _debug_frame()
        assert frame == encode_frame(1, CMD_DEBUG_ANSWER, bytes(66))
        dev.write(frame)
        sample = await link.next_sample(timeout_s=2.0)
        assert sample.t_ns > 0
        assert b"".join(d for k, _, d in tap if k == "r") == frame
        names = {t.get_name() for t in asyncio.all_tasks()}
        assert not any(n.startswith("mk-reader") for n in names)  # the callback parsed it
        dev.vanish()
        with pytest.raises(LinkError):
            await link.next_sample(timeout_s=2.0)
        assert link.error is not None
    finally:
        await link.close(release=False)
        dev.vanish()
    assert link.closed


async def test_a_crash_in_the_callback_fails_the_link_as_a_reader_crash() -> None:
    def broken(direction: str, t_ns: int, data: bytes) -> None:
        if direction == "r":  # the tap of a read runs in the port's callback
            raise RuntimeError("tap broke")

    dev, link = await _link_on_pty(broken)
    try:
        link.start()
        dev.write(_debug_frame())
        with pytest.raises(LinkError, match="reader crashed"):
            await link.next_sample(timeout_s=2.0)
        assert link.control_blocked == "the link's reader crashed"
    finally:
        await link.close(release=False)
        dev.vanish()
