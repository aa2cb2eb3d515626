"""Clocks: the one place time is read, injected everywhere else.

Records carry ``t_ns`` from a :class:`Clock`; pure code never reads time itself, so the
simulator and replay can swap the monotonic clock for a manual one. Every ``t_ns`` is integer
nanoseconds (:data:`mkflight.conversions.NS_PER_S`).
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """A source of monotonic time in integer nanoseconds."""

    def now_ns(self) -> int:
        """Return the current time in nanoseconds (arbitrary epoch, monotonic)."""
        ...


class MonotonicClock:
    """The host's monotonic clock (``time.monotonic_ns``)."""

    def now_ns(self) -> int:
        """Return ``time.monotonic_ns()``."""
        return time.monotonic_ns()


class ManualClock:
    """A clock that moves only when told to: for tests and lock-step simulation."""

    def __init__(self, start_ns: int = 0) -> None:
        self._t_ns = start_ns

    def now_ns(self) -> int:
        """Return the time last set."""
        return self._t_ns

    def advance(self, dt_ns: int) -> None:
        """Move the clock forward by ``dt_ns`` (never backward)."""
        if dt_ns < 0:
            msg = f"a ManualClock cannot go back ({dt_ns} ns)"
            raise ValueError(msg)
        self._t_ns += dt_ns

    def set(self, t_ns: int) -> None:
        """Set the clock to ``t_ns``, which must not be earlier than now."""
        self.advance(t_ns - self._t_ns)
