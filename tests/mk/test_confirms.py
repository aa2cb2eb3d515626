"""Which ExternControl frames are numbered for a 'B' confirm (``mk.confirm_every``).

A command that takes control is numbered once in ``confirm_every`` (the first after a
Config = 0 frame, then every ``confirm_every``-th); Config = 0 frames (the handshake, the
release) and the blind command always are. The numbered ones are confirmed, give the
round-trip time and are counted lost when no confirm comes.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import pytest

from mkflight.clock import ManualClock
from mkflight.config import MkConfig, SafetyConfig
from mkflight.io.stream import memory_pair
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import Confirm, ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION

from .fakes import FakeFc, _until, link_settings

EVERY_4 = link_settings(
    MkConfig(answer_timeout_s=0.3, version_retry_s=0.1, release_interval_s=0.005, confirm_every=4),
    SafetyConfig(mk_stale_s=0.05),
)
CONTROL = ExternControl(nick=12, roll=-3, gas=110, config=1)


@pytest.fixture
async def every4() -> AsyncIterator[tuple[MkLink, FakeFc]]:
    """A connected link numbering one command in 4, and its fake FC."""
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    task = asyncio.create_task(fc.run())
    link = MkLink(host, EVERY_4, DEFAULT_CALIBRATION)
    await link.connect()
    yield link, fc
    await link.close(release=False)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


async def _send(link: MkLink, command: ExternControl, *, confirm: bool = False) -> int:
    """Send ``command`` and wait until it has left the wire (no newer one supersedes it)."""
    frame_no = link.send_extern_control(command, confirm=confirm)
    await link.drain()
    return frame_no


async def test_one_command_that_takes_control_in_n_is_numbered_and_confirmed(
    every4: tuple[MkLink, FakeFc],
) -> None:
    link, fc = every4
    numbers = [await _send(link, CONTROL) for _ in range(9)]
    assert numbers == [1, 0, 0, 0, 2, 0, 0, 0, 3]
    await asyncio.wait_for(_until(lambda: fc.count("b") == 9, fc), 1.0)
    assert [c.frame for c in fc.commands()] == numbers  # Frame 0 on the wire: no confirm asked
    assert [c.config for c in fc.commands()] == [1] * 9
    assert await link.wait_confirm(3, timeout_s=1.0)
    assert link.stats.confirms == 3  # every numbered one, and only those
    assert len(link.stats.rtt_ns) == 3  # the round trip of each numbered one
    assert all(rtt >= 0 for rtt in link.stats.rtt_ns)
    assert link.stats.commands_sent == 9
    assert link.stats.confirms_lost == 0


async def test_config_zero_frames_are_always_numbered_and_the_next_command_too(
    every4: tuple[MkLink, FakeFc],
) -> None:
    """The handshake's neutral stream is all numbered (its confirms end HANDSHAKE); the
    first command that takes control after it is numbered, then one in 4."""
    link, _ = every4
    handshake = [await _send(link, ExternControl.neutral()) for _ in range(5)]
    assert handshake == [1, 2, 3, 4, 5]
    assert await link.wait_confirm(5, timeout_s=1.0)
    assert link.stats.confirms == 5
    flying = [await _send(link, CONTROL) for _ in range(5)]
    assert flying == [6, 0, 0, 0, 7]
    assert await _send(link, ExternControl.neutral()) == 8
    assert await _send(link, CONTROL) == 9  # control taken again: numbered first


async def test_release_frames_are_numbered_and_confirmed(every4: tuple[MkLink, FakeFc]) -> None:
    link, fc = every4
    for _ in range(2):
        await _send(link, CONTROL)  # one numbered, one not
    confirmed = await link.release()
    assert confirmed == EVERY_4.release_frames
    released = fc.commands()[2:]
    assert [c.config for c in released] == [0] * EVERY_4.release_frames
    assert [c.frame for c in released] == list(range(2, 2 + EVERY_4.release_frames))


async def test_confirm_numbers_a_command_out_of_turn(every4: tuple[MkLink, FakeFc]) -> None:
    """The blind command asks for its confirm whatever the count."""
    link, _ = every4
    assert await _send(link, CONTROL) == 1
    assert await _send(link, CONTROL) == 0
    assert await _send(link, CONTROL, confirm=True) == 2
    assert await link.wait_confirm(2, timeout_s=1.0)
    assert [await _send(link, CONTROL) for _ in range(4)] == [0, 0, 0, 3]  # counted from it


async def test_confirm_every_1_numbers_every_command() -> None:
    host, _device = memory_pair("host", "fc")
    link = MkLink(host, link_settings(MkConfig(confirm_every=1)), DEFAULT_CALIBRATION)
    link.start()
    assert [await _send(link, CONTROL) for _ in range(4)] == [1, 2, 3, 4]
    await link.close(release=False)


def _silent_link(settings: LinkSettings, clock: ManualClock) -> tuple[MkLink, FakeFc]:
    host, device = memory_pair("host", "fc")
    return MkLink(host, settings, DEFAULT_CALIBRATION, clock), FakeFc(device, answer=False)


async def test_a_lost_confirm_of_a_numbered_command_is_counted_and_frame_0_never() -> None:
    clock = ManualClock()
    link, fc = _silent_link(EVERY_4, clock)  # the FC never confirms
    task = asyncio.create_task(fc.run())
    link.start()
    assert await _send(link, CONTROL) == 1
    for _ in range(3):
        clock.advance(2_000_000_000)  # each unnumbered one is long past the confirm timeout
        assert await _send(link, CONTROL) == 0
    # the numbered one is counted lost once, when the next command goes out
    assert link.stats.confirms_lost == 1
    clock.advance(2_000_000_000)
    assert await _send(link, CONTROL) == 2
    clock.advance(2_000_000_000)
    assert await _send(link, CONTROL) == 0
    assert link.stats.confirms_lost == 2
    assert link.stats.confirms == 0
    assert not link.stats.rtt_ns
    await link.close(release=False)
    task.cancel()


async def test_a_command_while_a_confirm_is_awaited_is_numbered_too() -> None:
    """The FC keeps one confirm flag: a Frame 0 command before the confirm went out would
    cancel it, and the confirm would be counted lost although nothing was lost. So while a
    confirm is awaited (younger than the confirm timeout) the next command is numbered."""
    clock = ManualClock()
    link, fc = _silent_link(EVERY_4, clock)  # the confirms are late: not back yet
    task = asyncio.create_task(fc.run())
    link.start()
    assert await _send(link, CONTROL) == 1
    clock.advance(20_000_000)  # 20 ms later, the confirm still awaited
    assert await _send(link, CONTROL) == 2
    assert link.stats.confirms_lost == 0
    fc.device.write(Confirm(1).encode() + Confirm(2).encode())  # both come back
    await asyncio.wait_for(_until(lambda: link.stats.confirms == 2, fc), 1.0)
    assert [await _send(link, CONTROL) for _ in range(4)] == [0, 0, 0, 3]
    assert link.stats.confirms_lost == 0
    await link.close(release=False)
    task.cancel()
