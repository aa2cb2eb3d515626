"""The URG emulator on a real pty, with the real serial client and the reply parser.

Nothing here sleeps: tests await the client's reads under a timeout, or the emulator's
``wait_for``. Draining "until 150 ms of silence" (``scip2.md`` §6 step 2) is a read that
times out.
"""

from __future__ import annotations

import asyncio
import itertools
import statistics
import time
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from mkflight.errors import LinkError
from mkflight.io.serial import SerialStream, open_serial
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg_scene import RoomScene, ScenePose
from mkflight.sim.urg_server import UrgEmulator
from mkflight.urg.codec import md_command, scip2_command, simple_command
from mkflight.urg.replies import InfoReply, Reply, ReplyParser, ScanReply
from mkflight.urg.units import URG_04LX, parse_params, ranges_m

BAUD = 115200  # ignored by a CDC-ACM port (§1)
FULL_MD = md_command(44, 725)


class Client:
    """A minimal SCIP client: the serial port, the parser, and what arrived when."""

    def __init__(self, stream: SerialStream) -> None:
        self.stream = stream
        self.parser = ReplyParser()
        self.pending: list[tuple[int, Reply]] = []

    async def _read(self) -> None:
        data = await self.stream.read()
        t_ns = time.monotonic_ns()
        self.pending += [(t_ns, r) for r in self.parser.feed(data)]

    async def request(self, command: bytes, timeout_s: float = 1.0) -> Reply:
        """Send ``command`` and return its answer, skipping anything else."""
        self.stream.write(command)
        async with asyncio.timeout(timeout_s):
            while True:
                while self.pending:
                    _, reply = self.pending.pop(0)
                    if reply.answers(command) and reply.status != "99":
                        return reply
                await self._read()

    async def drain(self, silence_s: float = 0.15) -> None:
        """Read until nothing arrives for ``silence_s`` (§6 step 2)."""
        while True:
            try:
                async with asyncio.timeout(silence_s):
                    await self._read()
            except TimeoutError:
                self.pending.clear()
                return

    async def scans(self, n: int, timeout_s: float = 2.0) -> list[tuple[int, ScanReply]]:
        """The next ``n`` scan messages with their arrival times."""
        found: list[tuple[int, ScanReply]] = []
        async with asyncio.timeout(timeout_s):
            while len(found) < n:
                while self.pending and len(found) < n:
                    t_ns, reply = self.pending.pop(0)
                    if isinstance(reply, ScanReply):
                        found.append((t_ns, reply))
                if len(found) < n:
                    await self._read()
        return found


async def read_until_closed(stream: SerialStream, timeout_s: float = 2.0) -> None:
    """Read whatever is still buffered until the stream ends (raises its LinkError)."""
    async with asyncio.timeout(timeout_s):
        while True:
            await stream.read()


def room_scene() -> RoomScene:
    return RoomScene(room_caster(box_room(6, 5)), pose=ScenePose(height_m=0.5), seed=2)


@pytest.fixture
async def emu(tmp_path: Path) -> AsyncIterator[UrgEmulator]:
    async with UrgEmulator(room_scene(), link=tmp_path / "urg") as urg:
        yield urg


@pytest.fixture
async def client(emu: UrgEmulator) -> AsyncIterator[Client]:
    stream = await open_serial(emu.path, BAUD)
    yield Client(stream)
    await stream.close()


async def handshake(client: Client) -> None:
    """``scip2.md`` §6 steps 2-6."""
    client.stream.write(simple_command("QT"))
    await client.drain()
    switch = await client.request(scip2_command())
    assert switch.ok
    assert (await client.request(simple_command("RS"))).status == "00"


async def test_startup_sequence_of_section_6(emu: UrgEmulator, client: Client) -> None:
    client.stream.write(simple_command("QT"))
    await client.drain()  # a SCIP 1.1 sensor's refusal is garbage to the parser
    assert await client.request(scip2_command()) == Reply("SCIP2.0", "0")
    assert await client.request(scip2_command()) == Reply("SCIP2.0", "0E")
    assert (await client.request(simple_command("RS"))).status == "00"
    vv = await client.request(simple_command("VV"))
    assert isinstance(vv, InfoReply)
    assert vv.info["PROT"] == "SCIP 2.0"
    pp = await client.request(simple_command("PP"))
    assert isinstance(pp, InfoReply)
    assert parse_params(pp.info) == URG_04LX
    ii = await client.request(simple_command("II"))
    assert isinstance(ii, InfoReply)
    assert 0 <= int(ii.info["TIME"], 16) < 1000  # the timer restarted at RS
    assert ii.info["LASR"] == "OFF"
    assert await client.request(FULL_MD) == Reply("MD0044072501000", "00")
    (_, scan), *_ = await client.scans(1)
    assert scan.answers(FULL_MD)
    assert len(scan.values) == 682
    assert (await client.request(simple_command("QT"))).status == "00"
    assert emu.model.rx_by_command["SCIP2.0"] == 2


async def test_full_scans_at_10_hz_about_100_ms_after_their_timestamp(
    emu: UrgEmulator, client: Client
) -> None:
    await handshake(client)
    assert (await client.request(FULL_MD)).ok
    found = await client.scans(12, timeout_s=3.0)
    arrivals = [t for t, _ in found]
    stamps = [s.timestamp_ms for _, s in found]
    assert [b - a for a, b in itertools.pairwise(stamps)] == [100] * 11
    gaps_ms = [(b - a) / 1e6 for a, b in itertools.pairwise(arrivals)]
    assert 90 <= statistics.median(gaps_ms) <= 110
    # Sensor time -> host time: the age at arrival is ~71 ms (end step) + 30 ms (USB).
    offsets_ms = [t / 1e6 - s for t, s in zip(arrivals, stamps, strict=True)]
    ages_ms = [o - min(offsets_ms) for o in offsets_ms]
    assert max(ages_ms) < 30  # a steady delay, not a growing one
    scan = found[-1][1]
    hat = [r for r in ranges_m(scan.values[: 127 - 44 + 1]) if r == r]
    assert statistics.median(hat) == pytest.approx(0.55, abs=0.01)
    walls = np.array(ranges_m(scan.values[150 - 44 :]), dtype=np.float64)
    assert np.nanmin(walls) == pytest.approx(2.5, abs=0.05)  # the side walls


async def test_garbage_and_bad_sums_are_counted_and_the_stream_goes_on(
    emu: UrgEmulator, client: Client
) -> None:
    await handshake(client)
    assert (await client.request(FULL_MD)).ok
    await client.scans(1)
    emu.inject_garbage(b"\x00\xfe line noise\n")
    emu.corrupt_next(2)
    await emu.wait_for(lambda m: m.tx_corrupted >= 2)
    (_, good), *_ = await client.scans(1)
    stats = client.parser.stats
    assert stats.sum_errors == 2
    assert stats.garbage_lines >= 1
    assert good.answers(FULL_MD)


async def test_stall_then_recovery_by_reissuing_md(emu: UrgEmulator, client: Client) -> None:
    await handshake(client)
    assert (await client.request(FULL_MD)).ok
    await client.scans(2)
    emu.stall_for(0.5)
    with pytest.raises(TimeoutError):
        await client.scans(1, timeout_s=0.3)  # §6 item 4: 3 periods without a scan
    assert (await client.request(simple_command("QT"))).status == "00"
    await client.drain()
    assert (await client.request(FULL_MD)).ok
    found = await client.scans(3, timeout_s=2.0)
    assert all(s.answers(FULL_MD) for _, s in found)
    assert emu.model.scans_stalled >= 2


async def test_vanish_fails_the_client_and_replug_restarts_the_sensor(
    emu: UrgEmulator, client: Client, tmp_path: Path
) -> None:
    await handshake(client)
    assert (await client.request(FULL_MD)).ok
    await client.scans(1)
    emu.vanish()
    with pytest.raises(LinkError):
        await read_until_closed(client.stream)
    assert not (tmp_path / "urg").exists()
    emu.replug()
    assert emu.path == str(tmp_path / "urg")
    stream = await open_serial(emu.path, BAUD)
    try:
        again = Client(stream)
        assert emu.model.power_ups == 1
        assert not emu.model.streaming
        assert await again.request(scip2_command()) == Reply("SCIP2.0", "0")  # SCIP 1.1
        assert (await again.request(FULL_MD)).ok
        await again.scans(1)
    finally:
        await stream.close()


async def test_replug_without_power_cycle_keeps_the_sensor_running(
    emu: UrgEmulator, client: Client
) -> None:
    await handshake(client)
    assert (await client.request(FULL_MD)).ok
    await client.scans(1)
    emu.vanish()
    emu.replug(power_cycle=False)  # a separately powered URG-04LX
    stream = await open_serial(emu.path, BAUD)
    try:
        assert emu.model.power_ups == 0
        assert emu.model.streaming
        await Client(stream).scans(1)  # still SCIP 2.0 and streaming: no command needed
    finally:
        await stream.close()


async def test_usb_delay_can_be_changed_while_serving(emu: UrgEmulator, client: Client) -> None:
    await handshake(client)
    emu.usb_delay_s = 0.25
    assert emu.usb_delay_s == 0.25
    assert emu.model.delivery_delay_ns == 250_000_000
    t0 = time.monotonic_ns()
    assert (await client.request(simple_command("VV"))).ok  # answered at once, then USB
    assert (time.monotonic_ns() - t0) / 1e9 >= 0.25


class FailingScene:
    """The room's ranges until told to fail; then every scan raises (a broken simulation)."""

    def __init__(self) -> None:
        self.scene = room_scene()
        self.fail = False

    def ranges_mm(self, t_ns: int, steps: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        if self.fail:
            msg = "the simulation broke"
            raise ValueError(msg)
        return self.scene.ranges_mm(t_ns, steps)


async def test_a_task_crash_is_raised_by_wait_for_and_stop(tmp_path: Path) -> None:
    source = FailingScene()
    emu = UrgEmulator(source, link=tmp_path / "urg")
    await emu.start()
    stream = await open_serial(emu.path, BAUD)
    try:
        client = Client(stream)
        await handshake(client)
        assert (await client.request(FULL_MD)).ok
        await client.scans(1)
        source.fail = True  # the next scan is measured in a task: it crashes
        with pytest.raises(RuntimeError, match="urg: emulator task crashed") as info:
            await emu.wait_for(lambda m: False, timeout_s=30.0)  # raised at once, no timeout
        assert isinstance(info.value.__cause__, ValueError)
        assert emu.error is info.value.__cause__
        with pytest.raises(RuntimeError, match="crashed"):  # and on every later call
            await emu.wait_for(lambda m: True)
    finally:
        await stream.close()
        with pytest.raises(ValueError, match="the simulation broke"):
            await emu.stop()
    assert not (tmp_path / "urg").exists()  # cleaned up before raising
    await emu.stop()  # raised once


async def test_a_task_crash_is_raised_when_the_context_exits(tmp_path: Path) -> None:
    source = FailingScene()

    async def serve(*, catch: bool) -> None:
        source.fail = False
        async with UrgEmulator(source, link=tmp_path / "urg") as emu:
            stream = await open_serial(emu.path, BAUD)
            try:
                client = Client(stream)
                await handshake(client)
                source.fail = True
                client.stream.write(FULL_MD)  # its first scan crashes a task
                if catch:
                    with pytest.raises(RuntimeError, match="crashed"):
                        await emu.wait_for(lambda m: m.scans_sent > 0)
                else:
                    await emu.wait_for(lambda m: m.scans_sent > 0)
            finally:
                await stream.close()

    with pytest.raises(ValueError, match="the simulation broke"):
        await serve(catch=True)  # the body ended normally: the exit raises the crash
    with pytest.raises(RuntimeError, match="crashed") as info:
        await serve(catch=False)  # the body raised: its exception wins, with a note
    assert info.value.__notes__ == [
        "urg: emulator task crashed: ValueError('the simulation broke')"
    ]
