"""What ``mk info`` and ``laser scan`` share: one device, N printed lines, a clean stop.

Both talk to one device on ``--port`` or on a built-in emulator's pty (``--sim``), print
what answered, then one line per item (a DebugOut sample, a scan) until ``--count`` lines
or SIGINT/SIGTERM. A signal sets an event (:mod:`mkflight.commands.interrupt`) instead of
raising, so the command leaves through its normal path and closes the device.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import TYPE_CHECKING, Any

from mkflight.commands.interrupt import next_or_stop

if TYPE_CHECKING:
    from mkflight.sim.pty_server import PtyEmulator


@contextlib.asynccontextmanager
async def device_path(
    port: str | None, emulator: Callable[[], PtyEmulator[Any]] | None
) -> AsyncIterator[str]:
    """Yield the device's path: ``port`` itself, or the pty of ``emulator()`` while it runs.

    ``emulator`` comes with ``--sim``; without it argparse made ``--port`` required.
    """
    if emulator is None:
        assert port is not None
        yield port
        return
    async with emulator() as running:
        yield running.path


async def print_lines(
    next_line: Callable[[], Awaitable[str]], count: int, stop: asyncio.Event
) -> None:
    """Print ``next_line()`` results, flushed, until ``count`` lines (0: no limit) or ``stop``.

    A ``next_line()`` under way when ``stop`` is set is cancelled.
    """
    printed = 0
    while count == 0 or printed < count:
        line = await next_or_stop(next_line(), stop)
        if line is None:
            break
        print(line, flush=True)
        printed += 1
