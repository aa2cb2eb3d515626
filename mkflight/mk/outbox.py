"""Spacing of the frames we send to the FC (``mk-serial.md`` §3 "Consequences for sending").

The FC has one receive buffer and handles a frame within about 2 ms of its last byte; a
``'#'`` arriving before that is lost together with its frame. So frames go out one per
write, and each starts at least ``gap`` after the previous one has *left the wire*
(``10 bits x len / baud`` after it was written), not merely after the write call. A frame
that may go now is written in the call (no queueing delay); one that may not waits for a
loop timer. A newer ExternControl replaces a queued one (it is stale anyway) and goes
ahead of queued requests.

The spacing is physical, so it runs on the event loop's monotonic time, not on the
injected clock that stamps data (a manual clock in a test must not hold frames back).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop

#: Writes one frame now: (kind, data, Frame number or 0); raises LinkError if it cannot.
Writer = Callable[[str, bytes, int], None]


def wire_s(n_bytes: int, baudrate: int) -> float:
    """Seconds ``n_bytes`` take on the wire at ``baudrate`` 8N1."""
    return n_bytes * BITS_PER_BYTE / baudrate


class Outbox:
    """Writes frames spaced by their wire time plus a gap; ExternControl has priority."""

    def __init__(self, writer: Writer, *, baudrate: int, gap_s: float) -> None:
        self._writer = writer
        self._baudrate = baudrate
        self._gap_s = gap_s
        self._free_s = float("-inf")  # loop time at which the next frame may start
        self._queue: deque[tuple[str, bytes, int]] = deque()  # (kind, data, Frame no.)
        self._timer: asyncio.TimerHandle | None = None
        self._idle = asyncio.Event()
        self._idle.set()
        self.delayed = 0
        #: Called with the Frame number of a queued command that a newer one replaced.
        self.on_superseded: Callable[[int], None] | None = None

    @staticmethod
    def _now() -> float:
        return asyncio.get_running_loop().time()

    def send(self, kind: str, data: bytes, frame_no: int = 0) -> bool:
        """Write ``data`` now if the line allows it, else queue it; True if written now.

        ``kind`` is the command character; a ``'b'`` supersedes a queued ``'b'``.
        Raises :class:`~mkflight.errors.LinkError` (from the writer) if the port is gone.
        """
        now = self._now()
        if not self._queue and now >= self._free_s:
            self._write(kind, data, frame_no, now)
            return True
        if kind == "b":
            for old_kind, _, old_no in self._queue:
                if old_kind == "b" and self.on_superseded is not None:
                    self.on_superseded(old_no)
            self._queue = deque(item for item in self._queue if item[0] != "b")
            self._queue.appendleft((kind, data, frame_no))
        else:
            self._queue.append((kind, data, frame_no))
        self.delayed += 1
        self._idle.clear()
        self._arm()
        return False

    def flush_due(self) -> None:
        """Write the first queued frame now if its time has come and its timer has not run.

        A loop that could not keep time (a starved CPU) runs a port's callback before the
        timers that fell due meanwhile. Called before a received chunk is handled, this sends
        a frame that was due before the bytes arrived first, as a loop that kept time would
        have: a newer command then cannot supersede it, and the replay, whose lock-step
        clock fires the timer on time, makes the same frames.
        """
        if self._timer is not None and self._now() >= self._free_s:
            self._timer.cancel()
            self._flush()

    def _write(self, kind: str, data: bytes, frame_no: int, now: float) -> None:
        self._writer(kind, data, frame_no)
        self._free_s = now + wire_s(len(data), self._baudrate) + self._gap_s

    def _arm(self) -> None:
        if self._timer is not None or not self._queue:
            return
        delay_s = max(0.0, self._free_s - self._now())
        self._timer = asyncio.get_running_loop().call_later(delay_s, self._flush)

    def _flush(self) -> None:
        self._timer = None
        if self._queue:
            kind, data, frame_no = self._queue.popleft()
            try:
                self._write(kind, data, frame_no, self._now())
            except Exception:
                self.cancel()  # the port is gone: nothing queued can go out
                return
        if self._queue:
            self._arm()
        else:
            self._idle.set()

    @property
    def pending(self) -> int:
        """Frames waiting for the line."""
        return len(self._queue)

    def cancel(self) -> list[int]:
        """Drop everything queued; return the Frame numbers of dropped commands."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        dropped = [no for kind, _, no in self._queue if kind == "b"]
        self._queue.clear()
        self._idle.set()
        return dropped

    async def drained(self) -> None:
        """Wait until the queue is empty and the last frame has left the wire."""
        await self._idle.wait()
        left_s = self._free_s - self._now()
        if left_s > 0:
            await asyncio.sleep(left_s)
