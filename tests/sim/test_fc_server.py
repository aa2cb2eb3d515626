"""The FlightCtrl emulator on a real pty, with the real serial client (mk-serial.md §3-9).

Nothing here sleeps: tests await the client's reads (under a timeout) or the emulator's
``wait_for``, which wakes whenever the model changed.
"""

from __future__ import annotations

import asyncio
import itertools
import statistics
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mkflight.config import SimFcConfig
from mkflight.errors import LinkError
from mkflight.io.serial import SerialStream, open_serial
from mkflight.mk.codec import Frame, FrameParser
from mkflight.mk.messages import (
    Confirm,
    DebugOut,
    ExternControl,
    debug_request,
    version_request,
)
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_server import FcEmulator
from mkflight.sim.sources import FixedSource

MK_03 = b"#bV=BMH============PH\r"
MK08_VALUES = {0: -12, 1: 31, 2: -13, 3: 33, 4: -3, 5: 14, 6: -2, 7: 480, 8: 0, 9: 118}
MK08_VALUES |= {10: 200, 11: 271, 12: 118, 13: 122, 14: 120, 15: 125, 21: 120}
SETTINGS = SimFcConfig(mk3mag_frames=False, external_control=200)
BAUD = 57600


@pytest.fixture
async def emu(tmp_path: Path) -> AsyncIterator[FcEmulator]:
    async with FcEmulator(SETTINGS, FixedSource(MK08_VALUES), link=tmp_path / "fc") as fc:
        yield fc


@pytest.fixture
async def client(emu: FcEmulator) -> AsyncIterator[SerialStream]:
    stream = await open_serial(emu.path, BAUD)
    yield stream
    await stream.close()


async def read_frames(
    stream: SerialStream, parser: FrameParser, count: int, cmd: str, timeout_s: float = 2.0
) -> list[tuple[int, Frame]]:
    """Read until ``count`` frames with command ``cmd`` arrived; each with its read time."""
    found: list[tuple[int, Frame]] = []
    async with asyncio.timeout(timeout_s):
        while len(found) < count:
            data = await stream.read()
            t_ns = time.monotonic_ns()
            found += [(t_ns, f) for f in parser.feed(data) if f.cmd == cmd]
    return found


async def read_until_closed(stream: SerialStream, timeout_s: float = 2.0) -> None:
    """Read whatever is still buffered until the stream ends (raises its LinkError)."""
    async with asyncio.timeout(timeout_s):
        while True:
            await stream.read()


async def test_version_answer_is_mk03(emu: FcEmulator, client: SerialStream) -> None:
    client.write(version_request())
    raw = b""
    async with asyncio.timeout(2.0):
        while len(raw) < len(MK_03):
            raw += await client.read()
    assert raw == MK_03
    assert emu.model.rx_by_cmd["v"] == 1


async def test_debug_stream_every_53_ms(emu: FcEmulator, client: SerialStream) -> None:
    client.write(debug_request(5))
    found = await read_frames(client, FrameParser(), 12, "D")
    stamps = [t for t, _ in found]
    gaps_ms = [(b - a) / 1e6 for a, b in itertools.pairwise(stamps)]
    assert 40 <= statistics.median(gaps_ms) <= 70
    assert DebugOut.decode(found[0][1]).analog[:16] == tuple(MK08_VALUES[i] for i in range(16))


async def test_extern_control_confirmed_and_awaited(emu: FcEmulator, client: SerialStream) -> None:
    client.write(ExternControl(gas=90, frame=7, config=1).encode())
    await emu.wait_for(lambda m: m.rx_by_cmd["b"] >= 1)
    assert emu.model.extern_active
    assert emu.model.effective_command().gas == 90
    (_, confirm), *_ = await read_frames(client, FrameParser(), 1, "B")
    assert Confirm.decode(confirm).frame == 7


async def test_vanish_fails_the_client_and_replug_serves_again(
    emu: FcEmulator, client: SerialStream, tmp_path: Path
) -> None:
    client.write(ExternControl(gas=90, frame=3, config=1).encode())
    await emu.wait_for(lambda m: m.rx_by_cmd["b"] >= 1)
    emu.vanish()
    with pytest.raises(LinkError):
        await read_until_closed(client)
    assert not (tmp_path / "fc").exists()
    emu.replug()
    assert emu.path == str(tmp_path / "fc")
    again = await open_serial(emu.path, BAUD)
    try:
        again.write(version_request())
        (_, version), *_ = await read_frames(again, FrameParser(), 1, "V")
        assert version.payload[:2] == bytes((0, 84))
        # Unplugging the adapter does not reset the FC: the extern command is still held.
        assert emu.model.reboots == 0
        assert emu.model.extern_active
    finally:
        await again.close()


async def test_faults_over_the_pty(emu: FcEmulator, client: SerialStream) -> None:
    parser = FrameParser()
    emu.inject_garbage(b"\x00\xffAT\r")
    emu.corrupt_next(1)
    client.write(version_request())
    await emu.wait_for(lambda m: m.tx_corrupted == 1)
    await emu.wait_for(lambda m: m.rx_by_cmd["v"] == 1)
    client.write(version_request())
    await read_frames(client, parser, 1, "V")
    assert parser.stats.crc_errors == 1
    assert parser.stats.discarded_bytes >= 5 + len(MK_03)


async def test_reboot_forgets_the_subscription(emu: FcEmulator, client: SerialStream) -> None:
    client.write(debug_request(5))
    await read_frames(client, FrameParser(), 2, "D")
    emu.reboot(boot_s=0.05)
    assert emu.model.booting
    await emu.wait_for(lambda m: not m.booting)
    assert emu.model.rx_frames == 0
    client.write(version_request())  # the FC hears again, and answers 'v' first
    found = await read_frames(client, FrameParser(), 1, "V")
    assert found[0][1].payload[:2] == bytes((0, 84))
    assert emu.model.tx_by_cmd["D"] == 0  # no DebugOut since the reboot


async def test_wait_for_times_out_with_a_clear_message(emu: FcEmulator) -> None:
    with pytest.raises(TimeoutError, match="fc: condition not met"):
        await emu.wait_for(lambda m: m.rx_frames > 0, timeout_s=0.05)


class FailingSource:
    """DebugOut values until told to fail; then every call raises (a broken simulation)."""

    def __init__(self) -> None:
        self.fail = False

    def analog(self, t_ns: int, fc: FcModel) -> dict[int, int]:
        if self.fail:
            msg = "the simulation broke"
            raise ValueError(msg)
        return {9: 118}


async def test_a_task_crash_is_raised_by_wait_for_and_stop(tmp_path: Path) -> None:
    source = FailingSource()
    emu = FcEmulator(SETTINGS, source, link=tmp_path / "fc")
    await emu.start()
    client = await open_serial(emu.path, BAUD)
    try:
        client.write(debug_request(5))
        await read_frames(client, FrameParser(), 1, "D")
        source.fail = True  # the next DebugOut is built in the send task: it crashes
        with pytest.raises(RuntimeError, match="fc: emulator task crashed") as info:
            await emu.wait_for(lambda m: False, timeout_s=30.0)  # raised at once, no timeout
        assert isinstance(info.value.__cause__, ValueError)
        assert emu.error is info.value.__cause__
        with pytest.raises(RuntimeError, match="crashed"):  # and on every later call
            await emu.wait_for(lambda m: True)
    finally:
        await client.close()
        with pytest.raises(ValueError, match="the simulation broke"):
            await emu.stop()
    assert not (tmp_path / "fc").exists()  # cleaned up before raising
    await emu.stop()  # raised once


async def test_a_task_crash_is_raised_when_the_context_exits(tmp_path: Path) -> None:
    source = FailingSource()
    source.fail = True

    async def serve(*, catch: bool) -> None:
        async with FcEmulator(SETTINGS, source, link=tmp_path / "fc") as emu:
            client = await open_serial(emu.path, BAUD)
            try:
                client.write(debug_request(5))  # its DebugOut crashes the send task
                if catch:
                    with pytest.raises(RuntimeError, match="crashed"):
                        await emu.wait_for(lambda m: m.tx_by_cmd["D"] > 0)
                else:
                    await emu.wait_for(lambda m: m.tx_by_cmd["D"] > 0)
            finally:
                await client.close()

    with pytest.raises(ValueError, match="the simulation broke"):
        await serve(catch=True)  # the body ended normally: the exit raises the crash
    with pytest.raises(RuntimeError, match="crashed") as info:
        await serve(catch=False)  # the body raised: its exception wins, with a note
    assert info.value.__notes__ == ["fc: emulator task crashed: ValueError('the simulation broke')"]


async def test_late_wakeups_are_noted_so_a_late_frame_is_known_as_the_emulators(
    emu: FcEmulator, client: SerialStream
) -> None:
    """A busy host wakes the sender late: noted (time, ms late), so the soak can attribute it."""
    from mkflight.sim.pty_server import LATE_KEEP, LATE_NOTE_NS

    assert emu.late_count == 0
    emu._note_late(1_000_000_000, 1_000_000_000 + LATE_NOTE_NS - 1)  # on time enough
    assert emu.late_count == 0
    client.write(debug_request(5))  # a DebugOut at once, then every 50 ms
    parser = FrameParser()
    await read_frames(client, parser, 1, "D")
    time.sleep(0.12)  # noqa: ASYNC251 -- block the loop on purpose: the next send is late
    await read_frames(client, parser, 1, "D")
    assert emu.late_count >= 1
    at_ns, late_ms = emu.late_wakes[0]
    assert late_ms >= LATE_NOTE_NS / 1e6
    assert at_ns <= time.monotonic_ns()
    for _ in range(LATE_KEEP + 5):
        emu._note_late(0, LATE_NOTE_NS)
    assert len(emu.late_wakes) == LATE_KEEP
    assert emu.late_count >= LATE_KEEP + 6
