"""Stopping a streaming command cleanly on SIGINT/SIGTERM (shared by ``mk info``, ``laser scan``).

The signals set an event instead of raising KeyboardInterrupt inside whatever is running,
so the command leaves through its normal path: the link hands control back, the laser gets
its QT, the port is closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


def stop_on_signals() -> asyncio.Event:
    """An event set by SIGINT or SIGTERM on the running loop."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    return stop


async def next_or_stop(item: Awaitable[T], stop: asyncio.Event) -> T | None:
    """Await ``item`` unless ``stop`` is set first; then cancel it and return None."""
    if stop.is_set():
        if isinstance(item, asyncio.Future):
            item.cancel()
        elif asyncio.iscoroutine(item):
            item.close()
        return None
    task = asyncio.ensure_future(item)
    stopped = asyncio.ensure_future(stop.wait())
    done, _ = await asyncio.wait({task, stopped}, return_when=asyncio.FIRST_COMPLETED)
    if task in done:
        stopped.cancel()
        return task.result()
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError, Exception):
        await task
    return None
