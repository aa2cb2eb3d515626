"""The lock-step loop: virtual time moves only when the loop is idle (replay, SPEC §6)."""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any, TypeVar

import pytest

from mkflight.conversions import NS_PER_S
from mkflight.io.serial import open_serial
from mkflight.replay.feeder import Feeder, replug_times
from mkflight.replay.inputs import Input
from mkflight.replay.vloop import Idle, LockstepLoop, VirtualClock

T = TypeVar("T")

T0 = 1_000 * NS_PER_S


class NoInput:
    """An idle hook with nothing to deliver: the clock jumps to each timer."""

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock
        self.idles = 0

    def on_idle(self, timer_in_s: float | None) -> float | None:
        self.idles += 1
        assert timer_in_s is not None, "a test loop must never wait with no timer"
        self.clock.advance_to(self.clock.now_ns() + int(timer_in_s * NS_PER_S) + 1)
        return None


def _run(coro_factory: Callable[[], Coroutine[Any, Any, T]], clock: VirtualClock, idle: Idle) -> T:
    loop = LockstepLoop(clock, idle)
    try:
        return loop.run_until_complete(coro_factory())
    finally:
        loop.close()


def test_a_long_sleep_takes_virtual_time_not_real_time() -> None:
    clock = VirtualClock(T0)
    idle = NoInput(clock)

    async def main() -> float:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await asyncio.sleep(3600.0)
        return loop.time() - t0

    wall0 = time.perf_counter()
    slept = _run(main, clock, idle)
    assert 3600.0 <= slept < 3600.001
    assert time.perf_counter() - wall0 < 5.0  # an hour of virtual time, not of ours
    assert clock.now_ns() >= T0 + 3600 * NS_PER_S


def test_timers_fire_in_order_at_their_virtual_times() -> None:
    clock = VirtualClock(T0)
    fired: list[tuple[str, int]] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        done = loop.create_future()

        def fire(name: str) -> None:
            fired.append((name, clock.now_ns()))

        for name, delay in (("c", 0.3), ("a", 0.1), ("b", 0.2)):
            loop.call_later(delay, fire, name)
        loop.call_later(0.4, done.set_result, None)
        await done

    _run(main, clock, NoInput(clock))
    assert [n for n, _ in fired] == ["a", "b", "c"]
    for (_, t), expected_s in zip(fired, (0.1, 0.2, 0.3), strict=True):
        assert abs((t - T0) / NS_PER_S - expected_s) < 1e-6


def test_the_clock_stands_still_while_a_thread_works() -> None:
    """serialx opens ports in a thread: its result must come before any timer moves time."""
    clock = VirtualClock(T0)
    idle = NoInput(clock)

    async def main() -> tuple[int, bool]:
        loop = asyncio.get_running_loop()
        timer_fired = False

        def fire() -> None:
            nonlocal timer_fired
            timer_fired = True

        loop.call_later(0.001, fire)
        await loop.run_in_executor(None, time.sleep, 0.2)  # 200 ms of real work
        return clock.now_ns(), timer_fired

    t, fired = _run(main, clock, idle)
    assert t == T0  # not a nanosecond passed while the thread ran
    assert not fired


def test_replug_is_played_before_the_reopen_but_not_before_the_loss() -> None:
    ins = [
        Input(T0, "laser", "o", b"/dev/x"),
        Input(T0 + 5 * NS_PER_S, "laser", "c", b"lost"),
        Input(T0 + 5 * NS_PER_S + 30_000_000, "mk", "r", b"#"),
        Input(T0 + 5 * NS_PER_S + 80_000_000, "laser", "o", b"/dev/x"),
        Input(T0 + 9 * NS_PER_S, "mk", "c", b"lost"),
        Input(T0 + 9 * NS_PER_S + 1_000_000, "mk", "o", b"/dev/y"),
    ]
    out = replug_times(ins)
    assert [i.t_ns for i in out] == sorted(i.t_ns for i in out)
    laser_o = [i for i in out if i.port == "laser" and i.kind == "o"]
    assert laser_o[0].t_ns == T0  # the first open is not a replug
    assert laser_o[1].t_ns == T0 + 5 * NS_PER_S + 30_000_000  # 50 ms before the re-open
    mk_o = next(i for i in out if i.port == "mk" and i.kind == "o")
    assert mk_o.t_ns == T0 + 9 * NS_PER_S  # not before the loss


def test_the_feeder_delivers_each_chunk_at_its_recorded_time(tmp_path: Path) -> None:
    """Over a real pty: the reader sees each chunk with the clock at its recorded time."""
    clock = VirtualClock(T0)
    times = [T0 + k * 50_000_000 for k in range(1, 6)]
    inputs = [Input(T0, "mk", "o", b"")] + [
        Input(t, "mk", "r", f"chunk{k}\n".encode()) for k, t in enumerate(times)
    ]
    feeder = Feeder(inputs, clock, tmp_path)
    seen: list[tuple[int, bytes]] = []

    async def main() -> None:
        feeder.open_devices()
        try:
            stream = await open_serial(feeder.path("mk"), 57600)
            feeder.on_open("mk")
            buf = b""
            while buf.count(b"\n") < len(times):
                data = await stream.read()
                feeder.on_read("mk", len(data))
                seen.append((clock.now_ns(), data))
                buf += data
            await stream.close()
        finally:
            feeder.close_devices()

    loop = LockstepLoop(clock, feeder)
    try:

        async def with_timer() -> None:  # a timer far away: the feeder must come first
            loop.call_later(3600, lambda: None)
            await main()

        loop.run_until_complete(with_timer())
    finally:
        loop.close()
    assert b"".join(d for _, d in seen) == b"".join(i.data for i in inputs[1:])
    assert [t for t, _ in seen] == times  # each chunk read at exactly its time
    assert feeder.stats.delivered_bytes["mk"] == feeder.consumed["mk"]
    assert not os.path.exists(feeder.path("mk"))  # the link is gone with the pty


def test_a_loop_with_nothing_to_wait_for_is_an_error_not_a_hang(tmp_path: Path) -> None:
    clock = VirtualClock(T0)
    feeder = Feeder([], clock, tmp_path)

    async def main() -> None:
        await asyncio.get_running_loop().create_future()  # waits for nothing that can come

    loop = LockstepLoop(clock, feeder)
    try:
        with pytest.raises(RuntimeError, match="no timer"):
            loop.run_until_complete(main())
    finally:
        loop.close()
