"""The flight's one way out, latched: :class:`StopLatch` (SPEC §5).

SIGINT, SIGTERM, SIGHUP (:func:`stop_signals`), ``--duration``, a failed log write and
a crashed task all become a :class:`~mkflight.safety.failsafe.StopRequest`; the first
one wins (the step turns it into a soft landing), later ones are only logged. A landing
that has not released within the deadline is cut short: :class:`StopDeadlineError`, and
the shutdown hands control back.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Callable, Iterator

from mkflight.conversions import NS_PER_S
from mkflight.errors import FlightError
from mkflight.safety.failsafe import StopRequest

#: The signals that land the vehicle, and the stop request each one makes.
STOP_SIGNALS = (
    (signal.SIGINT, StopRequest.SIGINT),
    (signal.SIGTERM, StopRequest.SIGTERM),
    (signal.SIGHUP, StopRequest.SIGTERM),  # the terminal or ssh went away: land
)


class StopDeadlineError(FlightError):
    """A stop request did not end in RELEASED in time: hand control back regardless."""


class StopLatch:
    """The first stop request, why, and when; the deadline its landing has."""

    __slots__ = ("at_ns", "deadline_s", "reason", "request")

    def __init__(self, deadline_s: float) -> None:
        self.deadline_s = deadline_s
        self.request: StopRequest | None = None
        self.reason = ""
        self.at_ns: int | None = None

    def latch(self, request: StopRequest, reason: str, now_ns: int) -> bool:
        """Keep ``request`` if it is the first; True if it was."""
        if self.request is not None:
            return False
        self.request, self.reason, self.at_ns = request, reason, now_ns
        return True

    def check_deadline(self, now_ns: int) -> None:
        """Raise when the landing has outlasted the deadline.

        Raises:
            StopDeadlineError: more than ``deadline_s`` since the first request.
        """
        if self.at_ns is not None and (now_ns - self.at_ns) / NS_PER_S > self.deadline_s:
            msg = f"the landing did not end within {self.deadline_s:g} s of the stop request"
            raise StopDeadlineError(msg)


@contextlib.contextmanager
def stop_signals(
    loop: asyncio.AbstractEventLoop, handler: Callable[[StopRequest, str], None]
) -> Iterator[None]:
    """Inside, each of :data:`STOP_SIGNALS` calls ``handler(request, signal name)``.

    Where the loop cannot watch signals (not its main thread, another platform), none do.
    """
    for sig, request in STOP_SIGNALS:
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, handler, request, sig.name)
    try:
        yield
    finally:
        for sig, _ in STOP_SIGNALS:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(sig)
