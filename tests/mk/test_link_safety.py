"""MkLink's safety rules: handing control back is sticky, complete and survives failures."""

from __future__ import annotations

import asyncio
import contextlib
import time

import pytest

from mkflight.clock import ManualClock
from mkflight.config import MkConfig, SafetyConfig
from mkflight.errors import CommandRangeError, LinkError
from mkflight.io.stream import MemoryStream, memory_pair
from mkflight.mk.codec import Frame
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import DebugOut, ExternControl
from mkflight.mk.outbox import wire_s
from mkflight.mk.units import DEFAULT_CALIBRATION

from .fakes import FAST, MK08, FakeFc, _until, link_settings


def is_release(frame: Frame) -> bool:
    if frame.cmd != "b":
        return False
    c = ExternControl.decode(frame)
    return (c.config, c.nick, c.roll, c.yaw, c.gas) == (0, 0, 0, 0, 0)


STALE_SETTINGS = link_settings(
    MkConfig(release_interval_s=0.005, answer_timeout_s=0.5),
    SafetyConfig(mk_stale_s=0.05, mk_release_s=0.3),
)


async def _streaming_link(
    settings: LinkSettings,
) -> tuple[MkLink, FakeFc, asyncio.Task[None]]:
    """A link to a fake FC that has streamed its first DebugOut (stop it with the task)."""
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    task = asyncio.create_task(fc.run())
    link = MkLink(host, settings, DEFAULT_CALIBRATION)
    await link.connect()
    link.subscribe()
    await link.next_sample(timeout_s=1.0)
    return link, fc, task


async def test_commands_that_take_control_are_refused_after_release(
    pair: tuple[MkLink, FakeFc],
) -> None:
    link, _fc = pair
    await link.connect()
    link.send_extern_control(ExternControl(gas=100, config=1))
    await link.release()
    assert link.control_blocked == "control released"
    with pytest.raises(LinkError, match="not taking control: control released"):
        link.send_extern_control(ExternControl(gas=100, config=1))
    link.send_extern_control(ExternControl.neutral())  # Config 0 is always allowed
    link.allow_control()
    link.send_extern_control(ExternControl(gas=100, config=1))  # the flight logic re-engaged


async def test_close_wins_over_a_task_still_sending_commands(
    pair: tuple[MkLink, FakeFc],
) -> None:
    """The last ExternControl the FC sees after close() has Config = 0."""
    link, fc = pair
    await link.connect()

    async def control_task() -> None:
        with contextlib.suppress(LinkError):
            while True:
                fc.received.clear()
                link.send_extern_control(ExternControl(nick=20, gas=120, config=1))
                await fc.received.wait()  # paced by the FC receiving a frame, not a timer

    sender = asyncio.create_task(control_task())
    await asyncio.wait_for(_until(lambda: fc.count("b") >= 3, fc), 2.0)
    await link.close()
    sender.cancel()
    commands = [f for f in fc.frames if f.cmd == "b"]
    assert is_release(commands[-1])
    assert sum(is_release(f) for f in commands) == FAST.release_frames
    first_release = next(i for i, f in enumerate(commands) if is_release(f))
    assert all(is_release(f) for f in commands[first_release:])


async def test_stale_data_with_control_taken_releases_and_stops_renewing() -> None:
    """An FC whose TX died but RX works must not hold the last command."""
    settings = STALE_SETTINGS
    link, fc, task = await _streaming_link(settings)
    link.send_extern_control(ExternControl(nick=30, gas=110, config=1))
    fc.answer = False  # the FC's transmitter dies; it still receives
    with pytest.raises(LinkError, match="no DebugOut"):
        await link.next_sample(timeout_s=1.0)
    assert link.stats.stale_releases == 1
    frames = fc.frames
    releases = [i for i, f in enumerate(frames) if is_release(f)]
    assert len(releases) == settings.release_frames
    assert not any(f.cmd == "d" for f in frames[releases[0] :])  # no hold refresh after
    assert sum(f.cmd == "d" for f in frames[: releases[0]]) >= 3  # re-subscribed before
    assert link.control_blocked is not None
    with pytest.raises(LinkError, match="not taking control"):
        link.send_extern_control(ExternControl(gas=100, config=1))
    await link.close()
    task.cancel()


async def test_stale_data_sends_the_blind_command_once_then_releases() -> None:
    """The FC holds the last command it got: at stale, the flight's level hover goes out.

    Once per stale period (not per re-subscription), only while we have control, and
    before the release, which still comes.
    """
    settings = STALE_SETTINGS
    link, fc, task = await _streaming_link(settings)
    link.send_extern_control(ExternControl(nick=30, gas=77, config=1))  # a noisy last gas
    link.set_blind_command(lambda: ExternControl(gas=97, config=1))
    fc.answer = False
    with pytest.raises(LinkError, match="no DebugOut"):
        await link.next_sample(timeout_s=1.0)
    commands = [ExternControl.decode(f) for f in fc.frames if f.cmd == "b"]
    blind = [c for c in commands if (c.config, c.nick, c.roll, c.yaw, c.gas) == (1, 0, 0, 0, 97)]
    assert len(blind) == 1
    assert blind[0].frame != 0  # numbered out of turn (mk.confirm_every): did the FC hear it?
    assert link.stats.blind_commands == 1
    first_release = next(i for i, c in enumerate(commands) if c.config == 0)
    assert commands.index(blind[0]) < first_release
    assert link.stats.stale_releases == 1
    await link.close()
    task.cancel()


async def test_no_blind_command_without_control() -> None:
    link, fc, task = await _streaming_link(STALE_SETTINGS)
    link.set_blind_command(lambda: ExternControl(gas=97, config=1))  # no control taken
    fc.answer = False
    with pytest.raises(LinkError, match="no DebugOut"):
        await link.next_sample(timeout_s=0.3)
    assert not any(f.cmd == "b" for f in fc.frames)
    assert link.stats.blind_commands == 0
    await link.close()
    task.cancel()


async def test_reader_crash_still_releases_and_closes(pair: tuple[MkLink, FakeFc]) -> None:
    """A bug in the reader must not leave the FC under extern control."""
    link, fc = pair
    await link.connect()
    link.send_extern_control(ExternControl(gas=100, config=1))

    def crashing_tap(direction: str, t_ns: int, data: bytes) -> None:
        if direction == "r":
            raise RuntimeError("bug in a tap")

    link._tap = crashing_tap
    link.subscribe()  # the FC answers with a DebugOut: the reader crashes on it
    with pytest.raises(LinkError, match="reader crashed"):
        await link.next_sample(timeout_s=1.0)
    with pytest.raises(LinkError):
        link.send_extern_control(ExternControl(gas=100, config=1))
    await link.close()
    assert sum(is_release(f) for f in fc.frames) == FAST.release_frames
    with pytest.raises(LinkError):
        await fc.device.read()  # the host end was closed: the device sees the end


async def test_cancelling_close_does_not_cut_the_release_short(
    pair: tuple[MkLink, FakeFc],
) -> None:
    """Review S4: a cancelled close() still sends every release frame and closes."""
    link, fc = pair
    await link.connect()
    link.send_extern_control(ExternControl(gas=100, config=1))
    closing = asyncio.create_task(link.close())
    await asyncio.wait_for(_until(lambda: any(is_release(f) for f in fc.frames), fc), 2.0)
    closing.cancel()
    with pytest.raises(asyncio.CancelledError):
        await closing
    await asyncio.wait_for(_until(lambda: fc.frames[-1] == Frame(1, "d", bytes(3)), fc), 2.0)
    assert sum(is_release(f) for f in fc.frames) == FAST.release_frames
    await link.close()  # idempotent: waits for the same shutdown


async def test_reopen_releases_before_renewing_and_blocks_control() -> None:
    """Review S5: an FC that still holds the old command is handed back first."""
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    tasks = [asyncio.create_task(fc.run())]

    async def opener() -> MemoryStream:
        new_host, new_device = memory_pair("host", "fc")
        fc.device = new_device
        fc.frames.clear()
        tasks.append(asyncio.create_task(fc.run()))
        return new_host

    link = MkLink(host, FAST, DEFAULT_CALIBRATION, reopen=opener)
    await link.connect()
    link.send_extern_control(ExternControl(gas=100, config=1))
    await device.close()
    await link.reopen(max_wait_s=1.0)
    await link.drain()
    cmds = [f.cmd for f in fc.frames]
    assert cmds[0] == "v"
    first_d = cmds.index("d")
    assert sum(is_release(f) for f in fc.frames[:first_d]) == FAST.release_frames
    assert link.control_blocked == "port re-opened"
    with pytest.raises(LinkError, match="port re-opened"):
        link.send_extern_control(ExternControl(gas=100, config=1))
    await link.close()
    for t in tasks:
        t.cancel()


@pytest.mark.parametrize(
    ("command", "field"),
    [
        (ExternControl(gas=131, config=1), "gas"),
        (ExternControl(nick=-128), "nick"),
        (ExternControl(roll=-128), "roll"),
        (ExternControl(yaw=-128), "yaw"),
        (ExternControl(gas=float("nan")), "gas"),
        (ExternControl(nick=float("inf")), "nick"),
    ],
)
async def test_the_link_is_the_last_gate_on_limits(
    pair: tuple[MkLink, FakeFc], command: ExternControl, field: str
) -> None:
    link, fc = pair
    with pytest.raises(CommandRangeError, match=field):
        link.send_extern_control(command)
    assert link.stats.commands_sent == 0
    assert fc.count("b") == 0


async def test_commands_always_go_to_the_fc_address(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    link.send_extern_control(ExternControl(addr=0, gas=10))
    await asyncio.wait_for(_until(lambda: fc.count("b") == 1, fc), 1.0)
    assert fc.frames[0].addr == 1


async def test_frames_start_a_gap_after_the_previous_left_the_wire(
    pair: tuple[MkLink, FakeFc],
) -> None:
    """Review P1: a 'd' right after a 22-byte 'b' waits for its 3.8 ms on the wire + 3 ms."""
    link, _fc = pair
    loop = asyncio.get_running_loop()
    tap_times: list[float] = []
    link._tap = lambda d, t, b: tap_times.append(loop.time()) if d == "w" else None
    link.send_extern_control(ExternControl(gas=10))
    link.subscribe()
    await link.drain()
    arrivals = tap_times
    assert len(arrivals) == 2
    needed_s = wire_s(22, 57600) + FAST.min_frame_gap_s
    assert arrivals[1] - arrivals[0] >= needed_s - 1e-4


async def test_a_slow_consumer_gets_the_newest_sample(pair: tuple[MkLink, FakeFc]) -> None:
    link, fc = pair
    link.start()
    frames = b"".join(DebugOut.from_values({9: volts}).encode() for volts in (110, 111, 112))
    fc.device.write(frames)
    sample = await link.next_sample(timeout_s=1.0)
    assert sample.battery_v == pytest.approx(11.2)
    assert link.stats.samples == 3
    assert link.stats.samples_dropped == 2


async def test_lost_confirms_are_counted_without_later_confirms() -> None:
    clock = ManualClock()
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device, answer=False)  # no confirms ever
    task = asyncio.create_task(fc.run())
    link = MkLink(host, FAST, DEFAULT_CALIBRATION, clock)
    link.start()
    link.send_extern_control(ExternControl())
    clock.advance(2_000_000_000)
    link.send_extern_control(ExternControl())
    assert link.stats.confirms_lost == 1
    await link.close(release=False)
    task.cancel()


def test_mk08_fixture_is_the_worked_example() -> None:
    assert MK08.analog[11] == 271


async def test_a_debugout_read_after_a_freeze_longer_than_the_release_time_releases() -> None:
    """SIGSTOP past the release time: on waking, the DebugOut queued meanwhile is read
    before the release timer can fire. It must not count as fresh data: the link releases
    as the timer would have (the fault campaign's process-pause row)."""
    link, fc, task = await _streaming_link(STALE_SETTINGS)
    link.send_extern_control(ExternControl(nick=30, gas=110, config=1))
    await _until(lambda: fc.count("b") >= 1, fc)
    fc.answer = False
    fc.device.write(MK08.encode())  # queued for the link's reader, which cannot run:
    time.sleep(STALE_SETTINGS.release_after_stale_s * 2)  # noqa: ASYNC251 - the fault: a frozen loop
    with pytest.raises(LinkError, match="no DebugOut"):
        await link.next_sample(timeout_s=1.0)
    assert link.stats.stale_releases == 1
    assert sum(is_release(f) for f in fc.frames) == STALE_SETTINGS.release_frames
    assert link.control_blocked is not None
    await link.close()
    task.cancel()
