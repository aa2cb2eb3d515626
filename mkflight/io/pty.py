"""The device end of a pseudo-terminal: how emulators and replay pose as serial devices.

:class:`PtyDevice` opens a pty, puts it in raw mode (no echo, no CR/LF translation,
before any client configures it) and keeps its own slave descriptor open so the pty
lives while clients come and go. Clients open :attr:`PtyDevice.path` like any serial
port; the optional ``link`` is a stable symlink to it (like ``/dev/serial/by-id/...``)
that :meth:`PtyDevice.replug` points at a fresh pty after :meth:`PtyDevice.vanish`.

Like a UART, the device never blocks on writing: when the client is not reading and the
kernel buffer is full, the bytes are dropped and counted.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import pty
import tty
from pathlib import Path

from mkflight.errors import LinkError
from mkflight.io.stream import ChunkQueue


class PtyDevice:
    """A pseudo-terminal whose master end is read and written as a :class:`ByteStream`."""

    def __init__(self, name: str = "pty", link: str | Path | None = None) -> None:
        self._name = name
        self._link = Path(link) if link is not None else None
        self._master = -1
        self._slave = -1
        self._path = ""
        self._rx = ChunkQueue(name)
        self.dropped_bytes = 0
        self._open()

    def _open(self) -> None:
        master, slave = pty.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._path = os.ttyname(slave)
        self._rx = ChunkQueue(self._name)
        if self._link is not None:
            tmp = self._link.with_name(self._link.name + ".tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self._path)
            tmp.replace(self._link)
        with contextlib.suppress(RuntimeError):
            asyncio.get_running_loop().add_reader(master, self._on_readable)

    @property
    def name(self) -> str:
        """The label given at creation."""
        return self._name

    @property
    def path(self) -> str:
        """What clients open: the stable link if there is one, else the slave path."""
        return str(self._link) if self._link is not None else self._path

    @property
    def slave_path(self) -> str:
        """The current ``/dev/pts/N``."""
        return self._path

    @property
    def is_open(self) -> bool:
        """False after :meth:`vanish` or :meth:`close`."""
        return self._master >= 0

    def attach(self) -> None:
        """Start reading on the running loop (needed only if created outside a loop)."""
        asyncio.get_running_loop().add_reader(self._master, self._on_readable)

    def _on_readable(self) -> None:
        try:
            data = os.read(self._master, 65536)
        except BlockingIOError:
            return
        except OSError as err:
            # EIO on the master means no client has the slave open: not an error for a
            # device (we hold a slave fd, so this is rare); wait for the next client.
            if err.errno == errno.EIO:
                return
            self._rx.fail(LinkError(f"{self._name}: pty read failed: {err}"))
            return
        self._rx.put(data)

    async def read(self) -> bytes:
        """Bytes the client wrote to the pty."""
        return await self._rx.get()

    def write(self, data: bytes) -> None:
        """Send ``data`` to the client; what the kernel will not take is dropped."""
        if self._master < 0:
            msg = f"{self._name}: pty is closed"
            raise LinkError(msg)
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        except OSError as err:
            msg = f"{self._name}: pty write failed: {err}"
            raise LinkError(msg) from err
        self.dropped_bytes += len(data) - n

    def discard_input(self) -> None:
        """Forget what the client sent that has not been read yet."""
        self._rx.clear()

    def detach(self) -> None:
        """Stop reading on the loop: the owner drains with :meth:`drop_client_bytes`."""
        if self._master >= 0:
            with contextlib.suppress(RuntimeError, ValueError):
                asyncio.get_running_loop().remove_reader(self._master)

    def drop_client_bytes(self) -> int:
        """Read and drop what the client wrote (never blocks); return how many bytes."""
        n = 0
        while self._master >= 0:
            try:
                data = os.read(self._master, 65536)
            except OSError:  # EAGAIN: nothing (more); EIO: no client
                break
            if not data:
                break
            n += len(data)
        return n

    async def drain(self) -> None:
        """Writes are immediate: nothing to wait for."""

    def vanish(self) -> None:
        """Pull the plug: close the pty so the client's reads and writes fail with EIO."""
        if self._master < 0:
            return
        with contextlib.suppress(RuntimeError, ValueError):
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1
        self._rx.fail(LinkError(f"{self._name}: unplugged"))
        if self._link is not None:
            with contextlib.suppress(FileNotFoundError):
                self._link.unlink()

    def replug(self) -> None:
        """Plug back in: a fresh pty behind the same :attr:`path` (needs ``link``)."""
        self.vanish()
        self._open()

    async def close(self) -> None:
        """Close the pty and remove the link."""
        self.vanish()
