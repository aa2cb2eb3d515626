"""The watchdog's work in its own timer callback: --duration, the stop deadline, errors."""

from __future__ import annotations

import asyncio

import pytest

from mkflight.clock import MonotonicClock
from mkflight.flight.stop import StopDeadlineError, StopLatch
from mkflight.flight.tasks import WATCH_PERIOD_S, watchdog_task
from mkflight.safety.failsafe import StopRequest


async def test_duration_then_deadline_end_the_watchdog_with_its_error() -> None:
    clock = MonotonicClock()
    stop = StopLatch(deadline_s=0.2)
    requests: list[tuple[StopRequest, str]] = []
    shown: list[float] = []
    loop = asyncio.get_running_loop()

    def request_stop(request: StopRequest, reason: str) -> None:
        requests.append((request, reason))
        stop.latch(request, reason, clock.now_ns())

    started = loop.time()
    with pytest.raises(StopDeadlineError):
        await watchdog_task(
            clock,
            stop,
            start_ns=clock.now_ns(),
            duration_s=0.1,
            request_stop=request_stop,
            show_status=lambda: shown.append(loop.time()),
        )
    took_s = loop.time() - started
    assert requests == [(StopRequest.DURATION, "--duration 0.1 s")]
    assert shown  # the status line at its first wake-up
    # --duration after 0.1 s, the deadline 0.2 s later, each noticed within a watch period
    assert 0.3 <= took_s <= 0.3 + 3 * WATCH_PERIOD_S


async def test_an_error_in_the_timer_is_raised_by_the_task_and_no_timer_is_left() -> None:
    clock = MonotonicClock()
    calls = 0

    def show_status() -> None:
        nonlocal calls
        calls += 1
        msg = "status broken"
        raise RuntimeError(msg)

    task = asyncio.create_task(
        watchdog_task(
            clock,
            StopLatch(deadline_s=9.0),
            start_ns=clock.now_ns(),
            duration_s=None,
            request_stop=lambda request, reason: None,
            show_status=show_status,
        )
    )
    with pytest.raises(RuntimeError, match="status broken"):
        await task
    await asyncio.sleep(2 * WATCH_PERIOD_S)
    assert calls == 1  # the failed timer did not arm another
