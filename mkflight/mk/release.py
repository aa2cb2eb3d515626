"""Hand the FlightCtrl back to the pilot without a link: ``mkflight mk release``.

The daemon releases on its way out (:meth:`mkflight.mk.link.MkLink.close`). When it died
without doing so (a kill, a watchdog abort, a power cut of the computer alone), the FC
keeps the last ExternControl until its hold counter runs out, ≈ 5.2 s after the last
frame (``mk-serial.md`` §7.4) — or indefinitely while anything else renews it. This sends
what the protocol prescribes instead of waiting: neutral ExternControl frames (sticks 0,
gas 0) with Config = 0, several of them ``interval_s`` apart because the FC drops a frame
whose '#' arrives while it still handles the previous one (§3), each with its own Frame
number (1, 2, ...) so that the FC's 'B' confirms say which arrived (§5.3). Nothing is
asked of the FC first (no version, no subscription): the release must work on an FC in
any state, and it is harmless to one that was not under extern control.
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass

from mkflight.io.stream import ByteStream
from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import CMD_CONFIRM, Confirm, ExternControl


@dataclass(frozen=True, slots=True)
class ReleaseResult:
    """How many Config = 0 frames went out, and which of them the FC confirmed."""

    sent: int
    confirmed: frozenset[int]


def release_frames(count: int) -> list[bytes]:
    """The ``count`` frames of a release, in order: neutral, gas 0, Config 0, Frame 1..count.

    Each is the protocol's vector MK-11 (the same frame with Frame 9) but for its number.
    """
    return [ExternControl.neutral(frame=i).encode() for i in range(1, count + 1)]


async def _collect_confirms(stream: ByteStream, confirmed: set[int], done: asyncio.Event) -> None:
    """Read until cancelled, noting every 'B' confirm's Frame number (other frames ignored)."""
    parser = FrameParser()
    try:
        while True:
            for frame in parser.feed(await stream.read()):
                if frame.cmd == CMD_CONFIRM and frame.payload:
                    confirmed.add(Confirm.decode(frame).frame)
                    done.set()
    finally:
        done.set()  # wakes the waiter when the port fails


async def release(
    stream: ByteStream, *, count: int, interval_s: float, confirm_timeout_s: float
) -> ReleaseResult:
    """Send the release frames on ``stream`` and wait up to ``confirm_timeout_s`` for confirms.

    Stops waiting as soon as every frame is confirmed. A read error (the port vanished)
    only ends the listening: what counts is what was confirmed.

    Raises:
        LinkError: a write failed.
    """
    confirmed: set[int] = set()
    got = asyncio.Event()
    reader = asyncio.create_task(_collect_confirms(stream, confirmed, got))
    try:
        for i, frame in enumerate(release_frames(count)):
            if i:
                await asyncio.sleep(interval_s)
            stream.write(frame)  # one frame per write (§3)
            await stream.drain()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + confirm_timeout_s
        while len(confirmed) < count and not reader.done() and loop.time() < deadline:
            got.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(got.wait(), deadline - loop.time())
    finally:
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await reader
    return ReleaseResult(sent=count, confirmed=frozenset(confirmed))
