"""Serial ports (real devices and pty slaves) as :class:`ByteStream`, on serialx.

serialx writes eagerly: ``write`` calls ``os.write`` at once and only buffers what the
kernel refuses, where pyserial-asyncio queues every write for the next event-loop turn
(``tools/bench.py`` measures the difference). A device that vanishes (USB unplugged:
EIO/ENODEV, or a hung-up pty) ends the stream with a :class:`LinkError` naming the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import termios
from typing import Any

from mkflight.errors import LinkError, PortNotFoundError
from mkflight.io.stream import ChunkQueue, OnData, OnEnd

READ_CHUNK_BYTES = 4096


class _SerialProtocol(asyncio.Protocol):
    """Feeds received chunks into a :class:`ChunkQueue`; turns a lost port into LinkError."""

    def __init__(self, name: str) -> None:
        self.rx = ChunkQueue(name)
        self._name = name

    def data_received(self, data: bytes) -> None:
        self.rx.put(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is None:
            self.rx.fail(LinkError(f"{self._name}: port closed"))
            return
        code = getattr(exc, "errno", None)
        what = errno.errorcode.get(code, "I/O error") if isinstance(code, int) else "I/O error"
        msg = f"{self._name}: device vanished or failed ({what}: {exc})"
        self.rx.fail(LinkError(msg))


class SerialStream:
    """An open serial port (see :func:`open_serial`)."""

    def __init__(self, name: str, transport: Any, protocol: _SerialProtocol) -> None:
        self._name = name
        self._transport = transport
        self._protocol = protocol

    @property
    def name(self) -> str:
        """The device path."""
        return self._name

    async def read(self) -> bytes:
        """Next received bytes (raises LinkError once the port is gone)."""
        return await self._protocol.rx.get()

    def deliver_to(self, on_data: OnData | None, on_end: OnEnd | None = None) -> None:
        """Hand each chunk over as serialx reads it, instead of :meth:`read` (None: stop).

        ``on_end`` is told once when the port is gone (see :meth:`ChunkQueue.deliver_to`).
        """
        self._protocol.rx.deliver_to(on_data, on_end)

    def write(self, data: bytes) -> None:
        """Hand ``data`` to the kernel now (serialx writes before it buffers)."""
        if self._transport.is_closing():
            # serialx closes the transport on a failed read at once but tells the protocol
            # (connection_lost, which names the error) a loop turn later: a write between
            # the two finds no error yet, and says what it knows.
            error = self._protocol.rx.error
            msg = f"{self._name}: write failed, port closed" if error is None else str(error)
            raise LinkError(msg)
        try:
            self._transport.write(data)
        except OSError as err:
            msg = f"{self._name}: write failed: {err}"
            raise LinkError(msg) from err
        if self._transport.is_closing():
            # serialx reports a failed os.write by closing the transport, not by raising.
            error = self._protocol.rx.error
            msg = f"{self._name}: write failed, port closed" if error is None else str(error)
            raise LinkError(msg)

    async def drain(self) -> None:
        """Wait until serialx has handed every buffered byte to the kernel."""
        if self._transport.is_closing():
            return
        with contextlib.suppress(OSError):
            await self._transport.flush()

    async def close(self) -> None:
        """Close the port and wait until it is closed."""
        if not self._transport.is_closing():
            self._transport.close()
        with contextlib.suppress(OSError):
            await self._transport.wait_closed()
        self._protocol.rx.fail(LinkError(f"{self._name}: port closed"))


async def open_serial(path: str, baudrate: int) -> SerialStream:
    """Open ``path`` at ``baudrate`` 8N1, exclusively, and discard stale input.

    Raises:
        PortNotFoundError: ``path`` does not exist.
        LinkError: it exists but cannot be opened (permissions, in use, not a tty).
    """
    import serialx  # imported here: keeps the serial stack off pure code's import path

    loop = asyncio.get_running_loop()
    protocol = _SerialProtocol(path)
    try:
        transport, _ = await serialx.create_serial_connection(
            loop, lambda: protocol, path, baudrate=baudrate
        )
    except PermissionError as err:
        msg = (
            f"cannot open {path!r}: permission denied "
            "(add the user to the 'dialout' group, then log in again)"
        )
        raise LinkError(msg) from err
    except FileNotFoundError as err:
        msg = f"serial port {path!r} does not exist"
        raise PortNotFoundError(msg) from err
    except (OSError, serialx.SerialException) as err:
        msg = f"cannot open {path!r}: {err}"
        raise LinkError(msg) from err
    # serialx reads up to 256 KiB per wake-up: a buffer that size is mmap'ed and freed on
    # every read (~0.1 ms). A 57600 Bd link delivers < 6 bytes per ms; 4 KiB is plenty.
    if hasattr(transport, "max_size"):
        transport.max_size = READ_CHUNK_BYTES
    serial = transport.get_extra_info("serial")
    if serial is not None:
        # Bytes the device sent before we opened it are stale: timestamps would lie.
        with contextlib.suppress(OSError, termios.error):
            termios.tcflush(serial.fileno(), termios.TCIFLUSH)
        protocol.rx.clear()
    return SerialStream(path, transport, protocol)
