"""A lock-step clock: an asyncio event loop whose time moves only when the daemon waits.

Replay (SPEC §6) runs the unchanged daemon on recorded input. Its timing decisions -
timeouts, staleness, the DebugOut and scan stamps, the link's frame spacing - all read
either the injected :class:`~mkflight.clock.Clock` or the event loop's ``time()``. Both
are one :class:`VirtualClock` here, and it moves only when the loop has nothing left to
do: :class:`LockstepSelector` asks the :class:`Idle` hook (the replay feeder) what happens
next - the next recorded input (delivered on a real pty at its recorded time) or the next
timer - and jumps the clock there. The daemon therefore sees the recorded timestamps
exactly, however fast the machine is (``--fast``), or paced to real time (``--speed X``).

Real I/O stays real: the ptys, the kernel in between, the daemon's serial stack. Bytes
written into a pty can take a few microseconds to surface at the other end, so while the
feeder knows of undelivered bytes the selector waits for them in real time before it lets
the clock move; so it does while a thread works for the loop (serialx opens a port in
one): the virtual clock stands still until the thread's result is in.
"""

from __future__ import annotations

import asyncio
import math
import selectors
from collections.abc import Callable, Mapping
from typing import Any, Protocol, TypeVar

from mkflight.conversions import NS_PER_S

T = TypeVar("T")

#: Real seconds per poll while a thread works (its result wakes the loop sooner).
THREAD_POLL_S = 0.05
#: The latest time the loop runs at (2**26 s, about 777 days of the recording host's
#: uptime). Its time is float seconds: up to 2**27 s they still resolve the 10 ns a timer
#: is due within; beyond, a due timer can stay pending forever while the loop spins. The
#: margin leaves room for the daemon's timers after the last recorded time.
MAX_T_NS = 2**26 * NS_PER_S


class VirtualClock:
    """Integer nanoseconds that move only forward and only when told to (the lock-step)."""

    def __init__(self, start_ns: int) -> None:
        self._t_ns = start_ns

    def now_ns(self) -> int:
        """The virtual time."""
        return self._t_ns

    def advance_to(self, t_ns: int) -> None:
        """Move to ``t_ns`` if it is later than now (time never goes back)."""
        if t_ns > self._t_ns:
            self._t_ns = t_ns


class Idle(Protocol):
    """What the selector asks when the loop has nothing ready (the replay feeder)."""

    def on_idle(self, timer_in_s: float | None) -> float | None:
        """The loop would block: deliver input or move the clock.

        Args:
            timer_in_s: virtual seconds to the next timer, None if there is none.

        Returns:
            None when something happened (input delivered, clock moved): the loop goes
            round again at once; else the real seconds to wait for I/O (bytes in flight).
        """
        ...


class LockstepSelector(selectors.BaseSelector):
    """The default selector, but an idle loop asks :class:`Idle` instead of sleeping."""

    def __init__(self, idle: Idle) -> None:
        self._sel = selectors.DefaultSelector()
        self._idle = idle
        #: work handed to threads (serialx opens ports in one): time waits for it
        self.threads_busy = 0

    def register(
        self, fileobj: Any, events: int, data: Any = None
    ) -> selectors.SelectorKey:  # pragma: no cover - delegation
        """Delegate to the real selector."""
        return self._sel.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        """Delegate to the real selector."""
        return self._sel.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        """Delegate to the real selector."""
        return self._sel.modify(fileobj, events, data)

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        """Delegate to the real selector."""
        return self._sel.get_map()

    def close(self) -> None:
        """Close the real selector."""
        self._sel.close()

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        """Ready I/O now; if none and the loop would block, let the feeder act instead."""
        events = self._sel.select(0)
        if events or timeout == 0:
            return events
        if self.threads_busy:  # a thread's result comes through the loop's self-pipe
            return self._sel.select(
                THREAD_POLL_S if timeout is None else min(timeout, THREAD_POLL_S)
            )
        wait_s = self._idle.on_idle(timeout)
        if wait_s is None:
            return []
        return self._sel.select(wait_s)


class LockstepLoop(asyncio.SelectorEventLoop):
    """An event loop on a :class:`VirtualClock` whose idle turns go to an :class:`Idle`."""

    def __init__(self, clock: VirtualClock, idle: Idle) -> None:
        self._lockstep = LockstepSelector(idle)
        super().__init__(self._lockstep)
        self._vclock = clock
        # A timer is due when its time is reached; the clock lands on whole ns, and the
        # float seconds of a ~1e13 ns monotonic time have ~4e-12 s of rounding.
        self._clock_resolution = 1e-8

    def time(self) -> float:
        """The virtual time in seconds (asyncio's timers run on it)."""
        return self._vclock.now_ns() / NS_PER_S

    def run_in_executor(  # type: ignore[override]
        self, executor: Any, func: Callable[..., T], *args: Any
    ) -> asyncio.Future[T]:
        """As asyncio's, but the clock stands still until the thread is done."""
        future: asyncio.Future[T] = super().run_in_executor(executor, func, *args)
        self._lockstep.threads_busy += 1

        def done(_: asyncio.Future[Any]) -> None:
            self._lockstep.threads_busy -= 1

        future.add_done_callback(done)
        return future


def seconds_to_ns_ceil(t_s: float) -> int:
    """A loop time in seconds as the first whole ns not before it (timers fire on it)."""
    return math.ceil(t_s * NS_PER_S)
