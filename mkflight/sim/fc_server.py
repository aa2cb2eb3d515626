"""The emulated FlightCtrl on a pseudo-terminal: :class:`FcModel` behind a :class:`PtyDevice`.

Clients open :attr:`FcEmulator.path` like the FC's USB-serial adapter, so the MK link is
exercised exactly as in flight (SPEC §8). Two tasks do the I/O: one feeds every chunk the
client writes to :meth:`FcModel.receive`, stamped with ``time.monotonic_ns`` (the clock
the host link stamps with too); the other sleeps until :meth:`FcModel.next_event_ns` (or
new input), then writes the frames :meth:`FcModel.poll` has finished. No periodic tick.

Faults: :meth:`FcEmulator.vanish`/:meth:`FcEmulator.replug` pull and reinsert the USB
adapter (the FC itself keeps running, as it does when only the adapter is unplugged);
the model's own faults are passed through with times relative to now.

A crash of either task (an :class:`~mkflight.sim.fc.AnalogSource` raising, a failing pty
read) is not swallowed: it is kept in :attr:`FcEmulator.error`, makes
:meth:`FcEmulator.wait_for` raise at once, and is re-raised by :meth:`FcEmulator.stop`.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from mkflight.config import SimFcConfig
from mkflight.errors import LinkError
from mkflight.io.pty import PtyDevice
from mkflight.sim.fc import DEFAULT_BOOT_NS, AnalogSource, FcModel


class FcEmulator:
    """A FlightCtrl 0.84a answering on a pty (``mk-serial.md``), for tests and ``--sim``."""

    def __init__(
        self,
        settings: SimFcConfig,
        source: AnalogSource,
        *,
        link: str | Path | None = None,
        name: str = "fc",
    ) -> None:
        """Prepare the emulator; nothing runs before :meth:`start`.

        Args:
            settings: the emulated FC's settings (``sim.fc``).
            source: where the DebugOut values come from.
            link: a stable symlink to the pty (survives :meth:`replug`), else none.
            name: a label for messages.
        """
        self._settings = settings
        self._source = source
        self._link = link
        self._name = name
        self._device: PtyDevice | None = None
        self._model: FcModel | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._wake = asyncio.Event()
        self._changed = asyncio.Event()
        self._plugged = asyncio.Event()
        self._plug_generation = 0
        self.lost_chunks = 0
        self.error: BaseException | None = None  # the first crash of a task

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Open the pty, boot the FC model now and start serving."""
        if self._tasks:
            return
        self._device = PtyDevice(self._name, self._link)
        self._model = FcModel(self._settings, self._source, t_ns=time.monotonic_ns())
        self._plugged.set()
        self._tasks = [
            asyncio.create_task(self._read_loop(), name=f"{self._name}-rx"),
            asyncio.create_task(self._send_loop(), name=f"{self._name}-tx"),
        ]
        for task in self._tasks:
            task.add_done_callback(self._on_task_done)

    async def stop(self) -> None:
        """Stop serving and close the pty (its link is removed).

        Raises:
            BaseException: the first crash of a task (:attr:`error`), once, after the
                cleanup.
        """
        tasks, self._tasks = self._tasks, []
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self._device is not None:
            await self._device.close()
        if tasks and self.error is not None:
            raise self.error

    def _on_task_done(self, task: asyncio.Task[None]) -> None:
        """Keep the first crash and wake :meth:`wait_for`; a cancelled task is no crash."""
        if task.cancelled():
            return
        err = task.exception()
        if err is not None and self.error is None:
            self.error = err
        self._notify()

    async def __aenter__(self) -> FcEmulator:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop; a task crash is raised unless the body already raised (then it is noted)."""
        if exc is None:
            await self.stop()
            return
        try:
            await self.stop()
        except Exception as crash:
            exc.add_note(f"{self._name}: emulator task crashed: {crash!r}")

    @property
    def path(self) -> str:
        """What a client opens: the link if one was given, else ``/dev/pts/N``."""
        return self._require_device().path

    @property
    def device(self) -> PtyDevice:
        """The pty device end."""
        return self._require_device()

    @property
    def model(self) -> FcModel:
        """The FC model being served (its counters, extern state, faults)."""
        if self._model is None:
            msg = f"{self._name}: emulator not started"
            raise RuntimeError(msg)
        return self._model

    def _require_device(self) -> PtyDevice:
        if self._device is None:
            msg = f"{self._name}: emulator not started"
            raise RuntimeError(msg)
        return self._device

    # ----------------------------------------------------------------- the two tasks
    async def _read_loop(self) -> None:
        """Feed what the client writes to the model; park while unplugged."""
        device = self._require_device()
        model = self.model
        while True:
            generation = self._plug_generation
            try:
                data = await device.read()
            except LinkError:
                if generation != self._plug_generation:
                    continue  # replugged while we waited on the old pty
                if not device.is_open:
                    await self._plugged.wait()
                    continue
                raise
            model.receive(data, time.monotonic_ns())
            self._poke()

    async def _send_loop(self) -> None:
        """Write finished frames, then sleep until the model's next event or new input."""
        device = self._require_device()
        model = self.model
        while True:
            for chunk in model.poll(time.monotonic_ns()):
                try:
                    device.write(chunk)
                except LinkError:
                    self.lost_chunks += 1  # unplugged: the FC sends into the void
            self._notify()
            next_ns = model.next_event_ns()
            self._wake.clear()
            if next_ns is None:
                await self._wake.wait()
                continue
            delay_s = (next_ns - time.monotonic_ns()) / 1e9
            if delay_s > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay_s):
                        await self._wake.wait()

    def _poke(self) -> None:
        """Make the sender re-plan now (the model's next event may have moved)."""
        self._wake.set()
        self._notify()

    def _notify(self) -> None:
        """Wake everyone in :meth:`wait_for`: the model may have changed."""
        changed, self._changed = self._changed, asyncio.Event()
        changed.set()

    async def wait_for(self, predicate: Callable[[FcModel], bool], timeout_s: float = 2.0) -> None:
        """Wait until ``predicate(model)`` holds, checking whenever the model changed.

        Raises:
            RuntimeError: a task of the emulator crashed (before or while waiting); the
                crash is its ``__cause__``.
            TimeoutError: it did not hold within ``timeout_s``.
        """
        model = self.model
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    if self.error is not None:
                        msg = f"{self._name}: emulator task crashed: {self.error!r}"
                        raise RuntimeError(msg) from self.error
                    if predicate(model):
                        return
                    await self._changed.wait()
        except TimeoutError as err:
            msg = f"{self._name}: condition not met within {timeout_s} s"
            raise TimeoutError(msg) from err

    # ----------------------------------------------------------------- faults
    def vanish(self) -> None:
        """Unplug the adapter: the client's reads and writes fail; the FC runs on."""
        self._plugged.clear()
        self._require_device().vanish()

    def replug(self) -> None:
        """Plug the adapter back in: a fresh pty behind the same link path."""
        self._require_device().replug()
        self._plug_generation += 1
        self._plugged.set()
        self._poke()

    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next frame."""
        self.model.inject_garbage(data)
        self._poke()

    def corrupt_next(self, n: int) -> None:
        """Give the next ``n`` frames a bad checksum."""
        self.model.corrupt_next(n)
        self._poke()

    def silence_for(self, duration_s: float) -> None:
        """Lose every frame the FC starts in the next ``duration_s`` (a dead TX line)."""
        self.model.silence(time.monotonic_ns() + round(duration_s * 1e9))
        self._poke()

    def reboot(self, boot_s: float = DEFAULT_BOOT_NS / 1e9) -> None:
        """Reboot the FC now; it is deaf and mute for ``boot_s``."""
        self.model.reboot(time.monotonic_ns(), boot_ns=round(boot_s * 1e9))
        self._poke()
