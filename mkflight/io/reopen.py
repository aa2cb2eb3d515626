"""Re-open a vanished port with exponential back-off (the links' ``reopen``).

The MK link and the URG driver both wait for a device that was unplugged (or whose USB
adapter re-enumerated) in the same way: call the opener, and while it fails with a
:class:`~mkflight.errors.LinkError` sleep ``backoff_s``, doubling up to ``backoff_max_s``,
until the next attempt would start after ``max_wait_s``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import structlog

from mkflight.conversions import NS_PER_S
from mkflight.errors import LinkError
from mkflight.io.stream import ByteStream, Opener

__all__ = ["open_with_backoff"]

log = structlog.get_logger("mkflight.io")


def _loop_now_ns() -> int:
    return int(asyncio.get_running_loop().time() * NS_PER_S)


async def open_with_backoff(
    opener: Opener,
    *,
    port: str,
    max_wait_s: float,
    backoff_s: float,
    backoff_max_s: float,
    log_event: str,
    now_ns: Callable[[], int] | None = None,
) -> ByteStream:
    """Call ``opener`` until it returns a stream, sleeping with exponential back-off.

    Each failed attempt is logged as ``log_event`` (with the port, the error and the wait).

    Args:
        opener: opens the port again; raises :class:`LinkError` while it is not there.
        port: the port's name, for messages.
        max_wait_s: give up when the next attempt would start later than this, s.
        backoff_s: the first wait between attempts, s (doubled after each failure).
        backoff_max_s: the longest wait between attempts, s.
        log_event: the event name of the retry warning (``mk_reopen_retry``).
        now_ns: the time the deadline runs on, ns (default: the event loop's time).

    Raises:
        LinkError: the port did not come back within ``max_wait_s`` (chaining the last
            attempt's error).
    """
    now = now_ns or _loop_now_ns
    delay_s = backoff_s
    deadline_ns = now() + int(max_wait_s * NS_PER_S)
    while True:
        try:
            return await opener()
        except LinkError as err:
            if now() + int(delay_s * NS_PER_S) > deadline_ns:
                msg = f"{port}: did not come back within {max_wait_s:g} s ({err})"
                raise LinkError(msg) from err
            log.warning(log_event, port=port, error=str(err), wait_s=delay_s)
            await asyncio.sleep(delay_s)
            delay_s = min(delay_s * 2, backoff_max_s)
