"""The DebugOut wait's wake-up timer: never fires while samples flow, still on time."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

import pytest

from mkflight.config import MkConfig, SafetyConfig
from mkflight.errors import LinkError
from mkflight.io.stream import memory_pair
from mkflight.mk.link import MkLink
from mkflight.mk.messages import ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION

from .fakes import MK08, FakeFc, link_settings

SETTINGS = link_settings(
    MkConfig(release_interval_s=0.005, answer_timeout_s=0.5),
    SafetyConfig(mk_stale_s=0.2, mk_release_s=0.5),
)
PERIOD_S = 0.01  # the fake FC's DebugOut period: twenty samples in one stale_s
SAMPLES = 50


class _TimerCount:
    """Counts the timers of mkflight's code armed and fired on the running loop (not sleeps')."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.armed = 0
        self.fired = 0
        self._call_at = loop.call_at

    def __call__(self, when: float, callback: Any, *args: Any, **kwargs: Any) -> Any:
        if not getattr(callback, "__module__", "").startswith("mkflight."):
            return self._call_at(when, callback, *args, **kwargs)
        self.armed += 1

        def fire(*a: Any) -> Any:
            self.fired += 1
            return callback(*a)

        return self._call_at(when, fire, *args, **kwargs)


async def _stream(fc: FakeFc, n: int) -> None:
    """The FC's DebugOut stream: ``n`` samples, one a period."""
    for _ in range(n):
        fc.device.write(MK08.encode())
        await asyncio.sleep(PERIOD_S)


async def test_the_timer_never_fires_while_samples_flow_and_staleness_still_releases(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    fc_task = asyncio.create_task(fc.run())
    link = MkLink(host, SETTINGS, DEFAULT_CALIBRATION)
    try:
        await link.connect()
        link.subscribe()
        await link.next_sample(timeout_s=1.0)  # the subscription's answer
        link.send_extern_control(ExternControl(nick=30, gas=110, config=1))
        fc.answer = False  # from here on only the stream below: no answers to 'd'
        loop = asyncio.get_running_loop()
        count = _TimerCount(loop)
        monkeypatch.setattr(loop, "call_at", count)
        stream = asyncio.create_task(_stream(fc, SAMPLES))
        fired_streaming: list[int] = []
        armed_streaming: list[int] = []
        stream.add_done_callback(lambda _: fired_streaming.append(count.fired))
        stream.add_done_callback(lambda _: armed_streaming.append(count.armed))
        got = 0
        with contextlib.suppress(LinkError):
            while True:
                await link.next_sample(timeout_s=1.0)
                got += 1
        await stream
    finally:
        await link.close()
        fc_task.cancel()
    # Every sample of the stream was a wait of its own (none dropped on a quiet loop)...
    assert got + link.stats.samples_dropped == SAMPLES
    assert link.stats.stale_events >= 1
    # ...and while the samples flowed the wait's timer never fired (each fired timer is
    # a loop turn of its own): it was re-armed before it would, but not for every wait
    # (a wait it ends at most stale_s / 2 early keeps it).
    assert 2 * SETTINGS.stale_s <= SAMPLES * PERIOD_S  # long enough for a lazy one to fire
    assert fired_streaming[0] == 0
    assert armed_streaming[0] <= SAMPLES * PERIOD_S / (SETTINGS.stale_s / 2) + 2
    assert count.fired >= 1  # the stream's end: it does fire when no sample comes
    # The stream's end still became stale data, and with control taken, a release.
    assert link.stats.stale_releases == 1
    assert link.control_blocked is not None
