"""The byte seam every link is built on, and an in-memory pair that fakes it in tests.

A :class:`ByteStream` is what the MK link and the URG driver take in their constructor:
a real serial port (:mod:`mkflight.io.serial`), the device end of a pseudo-terminal
(:mod:`mkflight.io.pty`) or the in-memory fake below. Writes are eager (no queueing
delay: a command goes to the kernel in the ``write`` call); reads wake on a future, so
tests await data instead of sleeping for it.
"""

from __future__ import annotations

import asyncio
import errno
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Protocol, runtime_checkable

from mkflight.errors import LinkError


class ByteStream(Protocol):
    """A bidirectional byte stream: a serial port, a pty end, or a fake."""

    @property
    def name(self) -> str:
        """The port path or a label, for messages."""
        ...

    async def read(self) -> bytes:
        """Return the next bytes received (at least one), waiting if there are none.

        Raises:
            LinkError: the device vanished, the stream was closed, or an I/O error.
        """
        ...

    def write(self, data: bytes) -> None:
        """Write ``data`` now, as one write; raise :class:`LinkError` if it cannot be sent."""
        ...

    async def drain(self) -> None:
        """Wait until everything written has left the process."""
        ...

    async def close(self) -> None:
        """Close the stream; pending and later reads raise :class:`LinkError`."""
        ...


@runtime_checkable
class PushStream(ByteStream, Protocol):
    """A stream that can also hand each chunk over as it arrives (a serial port).

    ``deliver_to(on_data, on_end)``: see :meth:`ChunkQueue.deliver_to`. Only streams
    whose chunks arrive in an event-loop callback offer it (never inside a write).
    """

    def deliver_to(
        self, on_data: Callable[[bytes], None] | None, on_end: Callable[[LinkError], None] | None
    ) -> None:
        """Hand each chunk to ``on_data`` as it arrives (None: queue for :meth:`read`)."""
        ...


#: A tap on the raw bytes: (direction 'r' or 'w', host t_ns, data). Used for recordings.
Tap = Callable[[str, int, bytes], None]
#: Opens a port again after it vanished (the links' ``reopen``).
Opener = Callable[[], Awaitable["ByteStream"]]


def resolve_waiter(waiter: asyncio.Future[None]) -> None:
    """Wake a reader's bare future (a timer's callback: the wait is over)."""
    if not waiter.done():
        waiter.set_result(None)


#: Takes each chunk as it arrives (:meth:`ChunkQueue.deliver_to`).
OnData = Callable[[bytes], None]
#: Told once that the stream ended, with the error reads would raise.
OnEnd = Callable[[LinkError], None]


class ChunkQueue:
    """Received chunks and the one reader waiting for them; ends with an error.

    A reader may instead have each chunk handed over in the callback that brought it
    (:meth:`deliver_to`): a task woken per chunk costs an event-loop turn per chunk.
    """

    def __init__(self, name: str) -> None:
        self._name = name
        self._chunks: deque[bytes] = deque()
        self._waiter: asyncio.Future[None] | None = None
        self._error: LinkError | None = None
        self._on_data: OnData | None = None
        self._on_end: OnEnd | None = None

    def deliver_to(self, on_data: OnData | None, on_end: OnEnd | None = None) -> None:
        """Hand each chunk to ``on_data`` as it arrives, and the end to ``on_end``.

        Instead of queueing them for :meth:`get`; None queues them again. Whatever was
        queued before goes to ``on_data`` on the loop's next turn (never inside this
        call), then the end if the stream has ended.
        """
        self._on_data, self._on_end = on_data, on_end
        if on_data is not None and (self._chunks or self._error is not None):
            asyncio.get_running_loop().call_soon(self._hand_over, on_data)

    def _hand_over(self, on_data: OnData) -> None:
        """Queued chunks (and the end) to the receiver set with them (if still set)."""
        while self._chunks and self._on_data is on_data:
            on_data(self._chunks.popleft())
        if self._on_data is on_data and self._error is not None:
            self._end()

    def _end(self) -> None:
        on_end = self._on_end
        self._on_data = self._on_end = None
        if on_end is not None and self._error is not None:
            on_end(self._error)

    @property
    def error(self) -> LinkError | None:
        """The error that ended the stream, if it has ended."""
        return self._error

    def put(self, data: bytes) -> None:
        """Append received bytes and wake the reader."""
        if data and self._error is None:
            on_data = self._on_data
            if on_data is not None:
                on_data(data)
                return
            self._chunks.append(data)
            self._wake()

    def clear(self) -> None:
        """Discard everything queued (stale input)."""
        self._chunks.clear()

    def fail(self, error: LinkError) -> None:
        """End the stream: the reader gets what is queued, then ``error``."""
        if self._error is None:
            self._error = error
        if self._on_data is not None and not self._chunks:
            self._end()
        self._wake()

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def get(self) -> bytes:
        """Return everything queued (joined), waiting for at least one byte."""
        while not self._chunks:
            if self._error is not None:
                raise self._error
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        if len(self._chunks) == 1:
            return self._chunks.popleft()
        data = b"".join(self._chunks)
        self._chunks.clear()
        return data


class MemoryStream:
    """One end of an in-memory stream pair, with fault injection for tests.

    ``write`` delivers to the peer at once unless the peer is stalled (then it is held
    until :meth:`resume`) or ``drop_writes`` is set (then it is counted and lost).
    """

    def __init__(self, name: str) -> None:
        self._name = name
        self._rx = ChunkQueue(name)
        self.peer: MemoryStream | None = None
        self.written: list[bytes] = []
        self.drop_writes = 0
        self.dropped = 0
        self._stalled = False
        self._held: list[bytes] = []
        self._closed = False

    @property
    def name(self) -> str:
        """The label given at creation."""
        return self._name

    async def read(self) -> bytes:
        """Next received bytes."""
        return await self._rx.get()

    def write(self, data: bytes) -> None:
        """Deliver ``data`` to the peer (or hold/drop it as the faults say)."""
        if self._closed:
            msg = f"{self._name}: write on a closed stream"
            raise LinkError(msg)
        self.written.append(bytes(data))
        if self.drop_writes > 0:
            self.drop_writes -= 1
            self.dropped += 1
            return
        if self.peer is not None:
            self.peer.inject(data)

    async def drain(self) -> None:
        """Nothing to wait for: writes are delivered synchronously."""

    async def close(self) -> None:
        """Close this end; its reader and the peer's reader see the end."""
        if self._closed:
            return
        self._closed = True
        self._rx.fail(LinkError(f"{self._name}: stream closed"))
        if self.peer is not None:
            self.peer.vanish(errno.EIO)

    def inject(self, data: bytes) -> None:
        """Make ``data`` arrive on this end as if the peer had sent it."""
        if self._stalled:
            self._held.append(bytes(data))
        else:
            self._rx.put(bytes(data))

    def stall(self) -> None:
        """Hold everything arriving at this end until :meth:`resume`."""
        self._stalled = True

    def resume(self) -> None:
        """Deliver what was held and stop holding."""
        self._stalled = False
        for chunk in self._held:
            self._rx.put(chunk)
        self._held.clear()

    def vanish(self, err: int = errno.EIO) -> None:
        """Make this end's reader fail as a vanished device does."""
        self._rx.fail(LinkError(f"{self._name}: device vanished ({errno.errorcode[err]})"))


def memory_pair(name_a: str = "host", name_b: str = "device") -> tuple[MemoryStream, MemoryStream]:
    """Two connected in-memory ends: what one writes, the other reads."""
    a, b = MemoryStream(name_a), MemoryStream(name_b)
    a.peer, b.peer = b, a
    return a, b
