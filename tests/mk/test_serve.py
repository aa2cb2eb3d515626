"""MkLink.serve: each DebugOut stepped in the turn that read it, with every safety rule kept."""

from __future__ import annotations

import asyncio
import contextlib

import pytest

from mkflight.config import MkConfig, SafetyConfig
from mkflight.errors import LinkError
from mkflight.io.stream import memory_pair
from mkflight.mk.link import MkLink
from mkflight.mk.messages import ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION
from mkflight.msgs import ImuSample

from .fakes import MK08, FakeFc, link_settings

SETTINGS = link_settings(
    MkConfig(release_interval_s=0.005, answer_timeout_s=0.5),
    SafetyConfig(mk_stale_s=0.2, mk_release_s=0.5),
)
PERIOD_S = 0.01


async def _stream(fc: FakeFc, n: int) -> None:
    for _ in range(n):
        fc.device.write(MK08.encode())
        await asyncio.sleep(PERIOD_S)


async def _linked() -> tuple[MkLink, FakeFc, asyncio.Task[None]]:
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    fc_task = asyncio.create_task(fc.run())
    link = MkLink(host, SETTINGS, DEFAULT_CALIBRATION)
    await link.connect()
    link.subscribe()
    await link.next_sample(timeout_s=1.0)  # the subscription's answer
    fc.answer = False  # from here on only the streams the tests send
    return link, fc, fc_task


async def _done(link: MkLink, fc_task: asyncio.Task[None]) -> None:
    await link.close()
    fc_task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await fc_task


async def test_each_sample_is_handled_in_the_readers_turn_and_true_ends_the_serve() -> None:
    link, fc, fc_task = await _linked()
    try:
        tasks: list[asyncio.Task[object] | None] = []

        def on_sample(sample: ImuSample) -> bool:
            tasks.append(asyncio.current_task())
            link.send_extern_control(ExternControl(gas=100, config=1))  # a step's command
            return len(tasks) == 10

        stream = asyncio.create_task(_stream(fc, 15))
        server = asyncio.create_task(link.serve(on_sample, timeout_s=1.0))
        await server
        stream.cancel()
    finally:
        await _done(link, fc_task)
    assert len(tasks) == 10
    # The serving task was not woken per sample: the step ran in the reader's turn.
    assert all(t is not server for t in tasks)
    assert link.stats.samples_dropped == 0
    assert len(fc.commands()) >= 10


async def test_an_error_of_the_step_is_raised_by_serve() -> None:
    link, fc, fc_task = await _linked()
    try:

        def on_sample(sample: ImuSample) -> bool:
            msg = "injected"
            raise ZeroDivisionError(msg)

        stream = asyncio.create_task(_stream(fc, 3))
        with pytest.raises(ZeroDivisionError, match="injected"):
            await link.serve(on_sample, timeout_s=1.0)
        stream.cancel()
        # the link itself is unharmed: its reader was not the one that failed
        assert link.error is None
    finally:
        await _done(link, fc_task)


async def test_stale_data_still_releases_and_the_timeout_still_ends_the_serve() -> None:
    link, fc, fc_task = await _linked()
    loop = asyncio.get_running_loop()
    try:
        link.send_extern_control(ExternControl(nick=30, gas=110, config=1))  # control taken
        steps: list[float] = []

        def on_sample(sample: ImuSample) -> bool:
            steps.append(loop.time())
            return False

        stream = asyncio.create_task(_stream(fc, 20))
        with pytest.raises(LinkError, match="no DebugOut"):
            await link.serve(on_sample, timeout_s=0.8)
        await stream
        ended = loop.time()
    finally:
        await _done(link, fc_task)
    assert len(steps) == 20
    assert link.stats.stale_events >= 1
    assert link.stats.stale_releases == 1  # release_after_stale_s without data, in control
    # the timeout counts from the last sample, not from the call
    assert ended - steps[-1] >= 0.8
