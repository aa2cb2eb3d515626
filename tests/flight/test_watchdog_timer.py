"""The watchdog's work in its own timer callback: --duration, the stop deadline, errors.

Both run on the replay's lock-step loop: its time jumps to each timer, so the timings
checked are exact and the tests wait for nothing in real time.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from mkflight.conversions import NS_PER_S
from mkflight.flight.stop import StopDeadlineError, StopLatch
from mkflight.flight.tasks import WATCH_PERIOD_S, watchdog_task
from mkflight.replay.vloop import LockstepLoop, VirtualClock
from mkflight.safety.failsafe import StopRequest

T0_NS = 1_000 * NS_PER_S


class JumpToTimers:
    """The lock-step loop's idle hook: no input, the clock jumps to the next timer."""

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock

    def on_idle(self, timer_in_s: float | None) -> float | None:
        assert timer_in_s is not None, "the loop would wait with no timer"
        self.clock.advance_to(self.clock.now_ns() + int(timer_in_s * NS_PER_S) + 1)
        return None


def _run_virtual(test: Callable[[VirtualClock], Coroutine[Any, Any, None]]) -> None:
    clock = VirtualClock(T0_NS)
    loop = LockstepLoop(clock, JumpToTimers(clock))
    try:
        loop.run_until_complete(test(clock))
    finally:
        loop.close()


def test_duration_then_deadline_end_the_watchdog_with_its_error() -> None:
    _run_virtual(_duration_then_deadline)


async def _duration_then_deadline(clock: VirtualClock) -> None:
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


def test_an_error_in_the_timer_is_raised_by_the_task_and_no_timer_is_left() -> None:
    _run_virtual(_an_error_in_the_timer)


async def _an_error_in_the_timer(clock: VirtualClock) -> None:
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
    await asyncio.sleep(2 * WATCH_PERIOD_S)  # virtual time: the clock jumps there
    assert calls == 1  # the failed timer did not arm another
