"""MkLink over the in-memory byte pair, against a small scripted FC responder."""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from mkflight.clock import ManualClock
from mkflight.config import MkConfig, SafetyConfig
from mkflight.errors import CommandRangeError, LinkError
from mkflight.io.pty import PtyDevice
from mkflight.io.serial import open_serial
from mkflight.io.stream import MemoryStream, memory_pair
from mkflight.mk.codec import Frame, FrameParser, encode_frame
from mkflight.mk.link import MkLink
from mkflight.mk.messages import (
    ExternControl,
    VersionInfo,
)
from mkflight.mk.units import DEFAULT_CALIBRATION
from mkflight.msgs import ImuSample

from .fakes import FAST, MK08, FakeFc, _until, link_settings


async def test_connect_reads_the_version(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    version = await link.connect()
    assert version.text == "0.84a"
    assert fc.frames[0] == Frame(1, "v", b"")


async def test_samples_are_converted_to_si_and_foreign_frames_dropped(
    pair: tuple[MkLink, FakeFc],
) -> None:
    link, fc = pair
    await link.connect()
    fc.device.write(b"#dk^\\yj======A=Nx\r")  # MK-19, the FC -> MK3MAG frame
    link.subscribe()
    sample = await link.next_sample(timeout_s=1.0)
    assert sample.pitch_rad == pytest.approx(0.020944, abs=1e-6)
    assert sample.roll_rad == pytest.approx(-0.054105, abs=1e-6)
    assert sample.acc_z_mps2 == pytest.approx(-9.670968, abs=1e-6)
    assert sample.yaw_rad == pytest.approx(-1.553343, abs=1e-6)
    assert sample.battery_v == pytest.approx(11.8)
    assert sample.gas_counts == 120
    assert link.last_debug == MK08  # decoded whole when asked for
    assert link.stats.foreign_frames == 1
    assert link.stats.parser.crc_errors == 0


async def test_garbage_and_crc_errors_are_counted_not_fatal(
    pair: tuple[MkLink, FakeFc],
) -> None:
    link, fc = pair
    link.start()
    fc.device.write(b"\x00\xffjunk" + b"#bV=BMH============PI\r")  # MK-20: bad CRC
    version = await link.connect()
    assert version.text == "0.84a"
    assert link.stats.parser.crc_errors == 1
    assert link.stats.parser.discarded_bytes >= 6 + 22


async def test_no_answer_is_a_clear_error_within_the_timeout() -> None:
    host, device = memory_pair("/dev/ttyFAKE", "fc")
    fc = FakeFc(device, answer=False)
    task = asyncio.create_task(fc.run())
    link = MkLink(host, FAST, DEFAULT_CALIBRATION)
    loop = asyncio.get_running_loop()
    start = loop.time()
    with pytest.raises(LinkError, match=r"no FlightCtrl answered on /dev/ttyFAKE"):
        await link.connect()
    assert loop.time() - start < FAST.answer_timeout_s + 0.2
    assert fc.count("v") >= 2  # retried
    await link.close(release=False)
    task.cancel()


async def test_extern_control_is_numbered_confirmed_and_range_checked(
    pair: tuple[MkLink, FakeFc],
) -> None:
    link, fc = pair
    await link.connect()
    first = link.send_extern_control(ExternControl(nick=-20, roll=15, gas=100, config=1))
    assert first == 1
    await asyncio.wait_for(_until(lambda: fc.count("b") == 1, fc), 1.0)
    cmd = fc.commands()[0]
    assert (cmd.nick, cmd.roll, cmd.gas, cmd.frame, cmd.config) == (-20, 15, 100, 1, 1)
    with pytest.raises(CommandRangeError, match="gas"):
        link.send_extern_control(ExternControl(gas=-1))
    assert link.stats.commands_sent == 1  # the bad one was never written
    assert await link.wait_confirm(first, timeout_s=1.0)
    assert link.stats.confirms == 1
    assert link.stats.rtt_ns[0] >= 0


@pytest.mark.parametrize("take_control", [True, False])
async def test_send_sticks_writes_the_frame_send_extern_control_writes(
    take_control: bool,
) -> None:
    frames: list[bytes] = []
    for fast in (True, False):
        host, _device = memory_pair("host", "fc")
        link = MkLink(host, FAST, DEFAULT_CALIBRATION)
        link.start()
        if fast:
            link.send_sticks(-20, 15, 3, 100, take_control=take_control)
        else:
            config = 1 if take_control else 0
            command = ExternControl(nick=-20, roll=15, yaw=3, gas=100, config=config)
            link.send_extern_control(command)
        await link.drain()
        frames.append(host.written[-1])
        await link.close(release=False)
    assert frames[0] == frames[1]
    assert ExternControl.decode(FrameParser().feed(frames[0])[0]).config == int(take_control)


@pytest.mark.parametrize(
    ("counts", "field"),
    [
        ((128, 0, 0, 100), "nick"),
        ((0, -128, 0, 100), "roll"),
        ((0, 0, 200, 100), "yaw"),
        ((0, 0, 0, -1), "gas"),
        ((0, 0, 0, FAST.gas_max + 1), "gas"),
        ((0, 0, 0, math.nan), "gas"),
        ((0.5, 0, 0, 100), "nick"),
    ],
)
async def test_send_sticks_refuses_what_send_extern_control_refuses(
    pair: tuple[MkLink, FakeFc], counts: tuple[float, float, float, float], field: str
) -> None:
    link, _ = pair
    nick, roll, yaw, gas = counts
    with pytest.raises(CommandRangeError, match=field):
        link.send_sticks(nick, roll, yaw, gas, take_control=True)  # type: ignore[arg-type]
    assert link.stats.commands_sent == 0


async def test_send_sticks_takes_whole_floats_like_the_command(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    link.send_sticks(5.0, 0, 0, 90.0, take_control=True)  # type: ignore[arg-type]
    await asyncio.wait_for(_until(lambda: fc.count("b") == 1, fc), 1.0)
    assert (fc.commands()[0].nick, fc.commands()[0].gas) == (5, 90)


async def test_send_sticks_is_refused_after_a_release(pair: tuple[MkLink, FakeFc]) -> None:
    link, _ = pair
    await link.release(quick=True)
    with pytest.raises(LinkError, match="not taking control"):
        link.send_sticks(0, 0, 0, 100, take_control=True)
    link.send_sticks(0, 0, 0, 0, take_control=False)  # Config 0 is always allowed


async def test_frame_numbers_roll_over_skipping_zero(pair: tuple[MkLink, FakeFc]) -> None:
    link, _ = pair
    numbers = [link.send_extern_control(ExternControl()) for _ in range(256)]
    assert numbers[254] == 255
    assert numbers[255] == 1
    assert 0 not in numbers


async def test_frames_are_spaced_by_the_minimum_gap(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    link.subscribe()
    link.send_extern_control(ExternControl())  # within 3 ms of the 'd': must wait
    assert link.stats.delayed_writes == 1
    assert fc.count("b") == 0
    link.send_extern_control(ExternControl(nick=5))  # supersedes the queued command
    await asyncio.wait_for(_until(lambda: fc.count("b") == 1, fc), 1.0)
    assert fc.commands()[0].nick == 5
    assert await link.wait_confirm(2, timeout_s=1.0)
    assert await link.wait_confirm(1, timeout_s=0.0)  # the superseded frame is not waited for
    assert link.stats.superseded_commands == 1


async def test_a_frame_due_before_a_chunk_arrived_leaves_before_the_chunk_is_handled() -> None:
    """Over a real pty: a starved loop runs the port's callback (and the step in it) before
    the outbox timer that fell due meanwhile. The queued command must still go out, ahead
    of the step's newer one: superseded, it would be missing here but sent by a replay,
    whose lock-step clock runs the timer on time (issue 21's flaky replays)."""
    device = PtyDevice("fc")
    link = MkLink(await open_serial(device.path, 57600), FAST, DEFAULT_CALIBRATION)
    try:

        def step(sample: ImuSample) -> bool:
            link.send_extern_control(ExternControl(nick=2))
            return True

        served = asyncio.create_task(link.serve(step, timeout_s=1.0))
        await asyncio.sleep(0)  # serving (it subscribed): each sample stepped in the callback
        link.send_extern_control(ExternControl(nick=1))  # within the gap after 'd': queued
        assert link.stats.delayed_writes == 1
        device.write(MK08.encode())  # the DebugOut the subscription asked for
        # The loop starved (the point of the test): no timer and no callback runs meanwhile.
        time.sleep(FAST.min_frame_gap_s + 0.01)  # noqa: ASYNC251
        await served
        parser = FrameParser()
        frames: list[Frame] = []
        while len(frames) < 3:
            frames += parser.feed(await asyncio.wait_for(device.read(), 1.0))
        assert [f.cmd for f in frames] == ["d", "b", "b"]
        assert [ExternControl.decode(f).nick for f in frames[1:]] == [1, 2]
        assert link.stats.superseded_commands == 0
    finally:
        await link.close(release=False)
        await device.close()


async def test_a_close_without_release_sends_no_queued_command(
    pair: tuple[MkLink, FakeFc],
) -> None:
    """A command still waiting for the line when the link closes stays unsent: it would
    renew the FC's ~5 s hold on a command after the flight let go of the link."""
    link, fc = pair
    link.subscribe()
    link.send_extern_control(ExternControl(nick=10, gas=120, config=1))  # queued behind 'd'
    assert link.stats.delayed_writes == 1
    await link.close(release=False)
    assert fc.count("b") == 0
    assert fc.frames[-1] == Frame(1, "d", b"\x00\x00\x00")  # the stream stopped, nothing else


async def test_close_releases_control_with_config_zero(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    await link.connect()
    link.send_extern_control(ExternControl(nick=10, gas=120, config=1))
    await asyncio.wait_for(_until(lambda: fc.count("b") == 1, fc), 1.0)
    await link.close()
    released = fc.commands()[1:]
    assert len(released) == FAST.release_frames
    for cmd in released:
        assert (cmd.nick, cmd.roll, cmd.yaw, cmd.gas, cmd.config) == (0, 0, 0, 0, 0)
    assert fc.frames[-1] == Frame(1, "d", b"\x00\x00\x00")  # stream stopped last


async def test_vanished_device_is_reported(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    await link.connect()
    link.subscribe()
    await link.next_sample(timeout_s=1.0)
    await fc.device.close()  # unplugged: the host end fails with EIO
    with pytest.raises(LinkError, match="vanished"):
        await link.next_sample(timeout_s=1.0)
    with pytest.raises(LinkError):
        link.send_extern_control(ExternControl())


async def test_stale_data_resubscribes_and_asks_the_version_again() -> None:
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device, answer=False)
    task = asyncio.create_task(fc.run())
    link = MkLink(host, FAST, DEFAULT_CALIBRATION)
    link.start()
    with pytest.raises(LinkError, match=r"no DebugOut from host for 0\.2 s"):
        await link.next_sample(timeout_s=0.2)
    await asyncio.wait_for(_until(lambda: fc.count("v") >= 1, fc), 1.0)
    assert fc.count("d") >= 3  # the first one, then at least every 50 ms of staleness
    assert link.stats.stale_events == 1
    await link.close(release=False)
    task.cancel()


async def test_renewal_comes_from_the_consumer_only() -> None:
    """A stalled consumer stops refreshing the FC's hold (SPEC §2)."""
    clock = ManualClock()
    host, device = memory_pair("host", "fc")
    no_staleness = SafetyConfig(mk_stale_s=100.0)
    settings = link_settings(MkConfig(resubscribe_s=2.0), no_staleness)
    link = MkLink(host, settings, DEFAULT_CALIBRATION, clock)
    link.start()
    link.subscribe()
    frame = MK08.encode()

    def d_count() -> int:
        return sum(1 for w in host.written if w[2:3] == b"d")

    for _ in range(3):
        clock.advance(1_000_000_000)
        device.write(frame)
        await link.next_sample(timeout_s=1.0)
        await link.drain()
    assert d_count() == 2  # the initial one and one renewal after 2 s
    device.write(frame)
    await link.next_sample(timeout_s=1.0)  # 1 s after the renewal: none due
    await link.drain()
    assert d_count() == 2
    clock.advance(10_000_000_000)  # the consumer stalled for 10 s: it renews when it asks
    device.write(frame)
    await link.next_sample(timeout_s=1.0)
    await link.drain()
    assert d_count() == 3
    await link.close(release=False)


async def test_reopen_with_backoff_after_the_port_vanished() -> None:
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    tasks = [asyncio.create_task(fc.run())]
    attempts = 0

    async def opener() -> MemoryStream:
        nonlocal attempts
        attempts += 1
        if attempts < 3:
            raise LinkError("host: not there yet")
        new_host, new_device = memory_pair("host", "fc")
        fc.device = new_device
        tasks.append(asyncio.create_task(fc.run()))
        return new_host

    settings = link_settings(MkConfig(reopen_backoff_s=0.01, reopen_backoff_max_s=0.02))
    link = MkLink(host, settings, DEFAULT_CALIBRATION, reopen=opener)
    await link.connect()
    await device.close()
    with pytest.raises(LinkError):
        await link.next_sample(timeout_s=1.0)
    version = await link.reopen(max_wait_s=2.0)
    assert version.text == "0.84a"
    assert attempts == 3
    assert link.stats.reopens == 1
    sample = await link.next_sample(timeout_s=1.0)  # reopen re-subscribed
    assert sample.battery_v == pytest.approx(11.8)
    await link.close()
    for t in tasks:
        t.cancel()


async def test_reopen_gives_up_with_a_clear_error() -> None:
    host, _ = memory_pair("/dev/ttyGONE", "fc")

    async def opener() -> MemoryStream:
        raise LinkError("/dev/ttyGONE: no such device")

    settings = link_settings(MkConfig(reopen_backoff_s=0.01, reopen_backoff_max_s=0.02))
    link = MkLink(host, settings, DEFAULT_CALIBRATION, reopen=opener)
    with pytest.raises(LinkError, match=r"/dev/ttyGONE: did not come back within 0.05 s"):
        await link.reopen(max_wait_s=0.05)


async def test_tap_sees_every_byte_both_ways(pair: tuple[MkLink, FakeFc]) -> None:
    link, _ = pair
    seen: list[tuple[str, bytes]] = []
    link._tap = lambda d, t, b: seen.append((d, b))
    await link.connect()
    assert ("w", encode_frame(1, "v")) in seen
    assert ("r", VersionInfo(0, 84, 11, 0, 0).encode()) in seen
