"""A replayed port without a pseudo-terminal: recorded bytes straight into the daemon.

``mkflight replay --fast`` plays the recording through :class:`MemoryDevice` instead of a
:class:`~mkflight.io.pty.PtyDevice`: the daemon opens its port through
:meth:`mkflight.flight.policy.FlightPolicy.open_port`, which a replay points here, and gets a
:class:`MemoryPortStream` - a :class:`~mkflight.io.stream.ByteStream` like a serial port,
read by the same link, driver and parsers. A pty costs two kernel round trips per
recorded chunk and a real-time wait for each to surface (the kernel moves pty bytes
asynchronously); here a chunk is in the daemon's queue when :meth:`MemoryDevice.write`
returns, so the lock-step clock never waits in real time. ``--speed`` keeps the ptys: a
paced replay is for watching the real serial stack work.

The device behaves as a pty does, so the replay is the same byte for byte (the
determinism check holds on both paths): an unplugged device fails the open stream's
reads and writes and refuses a new open (``PortNotFoundError``, as a vanished
``/dev/ttyUSB0`` does); a replug lets the next open succeed with an empty queue (the
serial stack flushes stale input on open); what the daemon writes goes to ``sink`` (an
emulated device's input) or is counted and dropped.
"""

from __future__ import annotations

from collections.abc import Callable

from mkflight.errors import LinkError, PortNotFoundError
from mkflight.io.stream import ChunkQueue


class MemoryPortStream:
    """The daemon's end of a :class:`MemoryDevice` (a :class:`ByteStream`)."""

    def __init__(self, device: MemoryDevice) -> None:
        self._device = device
        self.rx = ChunkQueue(device.path)
        self.closed = False

    @property
    def name(self) -> str:
        """The port path the daemon opened."""
        return self._device.path

    async def read(self) -> bytes:
        """Next bytes the device sent (LinkError once it vanished or the port closed)."""
        return await self.rx.get()

    def write(self, data: bytes) -> None:
        """To the device at once; LinkError if the port is closed or the device gone."""
        if self.closed or self._device.stream is not self:
            error = self.rx.error
            msg = f"{self.name}: port is closed" if error is None else str(error)
            raise LinkError(msg)
        self._device.from_daemon(data)

    async def drain(self) -> None:
        """Writes are immediate: nothing to wait for."""

    async def close(self) -> None:
        """Close the port: pending and later reads raise LinkError."""
        self.closed = True
        self.rx.fail(LinkError(f"{self.name}: port closed"))
        if self._device.stream is self:
            self._device.stream = None


class MemoryDevice:
    """The device side of a replayed port: the feeder writes, the daemon opens and reads.

    The same surface the feeder uses on a :class:`~mkflight.io.pty.PtyDevice` (``write``,
    ``vanish``, ``replug``, ``detach``, ``drop_client_bytes``, ``is_open``,
    ``dropped_bytes``), plus :meth:`open` for the daemon.
    """

    def __init__(self, path: str, sink: Callable[[bytes], None] | None = None) -> None:
        self.path = path
        self._sink = sink
        self._plugged = True
        self.stream: MemoryPortStream | None = None
        self.dropped_bytes = 0  # a pty drops what its buffer will not take; never here

    @property
    def is_open(self) -> bool:
        """The device is plugged in."""
        return self._plugged

    def open(self) -> MemoryPortStream:
        """The daemon opens the port (the serial stack's open, exclusive as it is).

        Raises:
            PortNotFoundError: the device is unplugged.
            LinkError: the port is open already.
        """
        if not self._plugged:
            msg = f"serial port {self.path!r} does not exist"
            raise PortNotFoundError(msg)
        if self.stream is not None and not self.stream.closed:
            msg = f"cannot open {self.path!r}: in use"
            raise LinkError(msg)
        self.stream = MemoryPortStream(self)
        return self.stream

    def write(self, data: bytes) -> None:
        """Bytes from the device to the daemon (lost, as on a wire, if it has no port open).

        Raises:
            LinkError: the device is unplugged.
        """
        if not self._plugged:
            msg = f"{self.path}: unplugged"
            raise LinkError(msg)
        if self.stream is not None:
            self.stream.rx.put(data)

    def from_daemon(self, data: bytes) -> None:
        """What the daemon wrote: to the sink (an emulated device), else dropped."""
        if self._sink is not None:
            self._sink(data)

    def detach(self) -> None:
        """What the daemon writes is dropped already (pty parity: nothing to do)."""

    def drop_client_bytes(self) -> int:
        """Nothing is kept of what the daemon wrote (pty parity)."""
        return 0

    def vanish(self) -> None:
        """Pull the plug: the open stream's reads and writes fail, opens fail."""
        self._plugged = False
        stream, self.stream = self.stream, None
        if stream is not None:
            stream.rx.fail(LinkError(f"{self.path}: device vanished (unplugged)"))

    def replug(self) -> None:
        """Plug back in: the next open succeeds, with nothing stale queued."""
        self.vanish()
        self._plugged = True
