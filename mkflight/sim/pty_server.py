"""Serving a pure, sans-I/O device model on a pseudo-terminal: the emulators' common part.

The emulated devices (:mod:`mkflight.sim.fc_server`, :mod:`mkflight.sim.urg_server`) are
pure models driven by explicit time (:class:`EmulatedDevice`); :class:`PtyEmulator` puts
one behind a :class:`PtyDevice` so clients open :attr:`PtyEmulator.path` like the real
serial port and the real drivers are exercised as in flight (SPEC §8).

Two tasks do the I/O: one feeds every chunk the client writes to the model's ``receive``,
stamped with ``time.monotonic_ns`` (the clock the host stamps with too); the other
sleeps until the model's ``next_event_ns`` (or new input), then writes what ``poll``
returns. No periodic tick, so the timing is the model's, not a loop's.

Faults: :meth:`PtyEmulator.vanish`/:meth:`PtyEmulator.replug` pull and reinsert the USB
plug (the device itself runs on); subclasses add the model's own faults, with times
relative to now, and call :meth:`PtyEmulator._poke` so the sender re-plans.

A crash of either task (the model or its data source raising, a failing pty read) is
not swallowed, so a broken simulation cannot pass for a silent device: it is kept in
:attr:`PtyEmulator.error`, makes :meth:`PtyEmulator.wait_for` raise at once, and is
re-raised by :meth:`PtyEmulator.stop`.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Generic, Protocol, Self, TypeVar

from mkflight.conversions import NS_PER_MS, NS_PER_S
from mkflight.errors import LinkError
from mkflight.io.pty import PtyDevice

LATE_NOTE_NS = 20_000_000
"""A wake-up this much after the model's event is noted in :attr:`PtyEmulator.late_wakes`."""
LATE_KEEP = 1000
"""At most this many late wake-ups are kept (the count goes on)."""


class EmulatedDevice(Protocol):
    """What :class:`PtyEmulator` needs of a model: bytes in, bytes out, next wake-up."""

    def receive(self, data: bytes, t_ns: int) -> object:
        """Take bytes the client wrote, all arriving at ``t_ns`` (the result is unused)."""
        ...

    def poll(self, t_ns: int) -> list[bytes]:
        """The chunks that have reached the client by ``t_ns``, in order."""
        ...

    def next_event_ns(self) -> int | None:
        """The earliest time :meth:`poll` may return something; None: wait for input."""
        ...


M = TypeVar("M", bound=EmulatedDevice)


class PtyEmulator(abc.ABC, Generic[M]):
    """A model of type ``M`` answering on a pty; subclasses say how to build the model."""

    def __init__(self, *, link: str | Path | None = None, name: str) -> None:
        """Prepare the emulator; nothing runs before :meth:`start`.

        Args:
            link: a stable symlink to the pty (survives :meth:`replug`), else none.
            name: a label for messages and task names.
        """
        self._link = link
        self._name = name
        self._device: PtyDevice | None = None
        self._model: M | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._wake = asyncio.Event()
        self._changed = asyncio.Event()
        self._plugged = asyncio.Event()
        self._plug_generation = 0
        self.lost_chunks = 0  # written while unplugged: the device sends into the void
        self.chunks_written = 0
        self.late_count = 0  # wake-ups >= LATE_NOTE_NS after the model's event was due
        self.late_wakes: list[tuple[int, float]] = []  # (monotonic ns, ms late), the first
        self.error: BaseException | None = None  # the first crash of a task

    @abc.abstractmethod
    def _new_model(self, t_ns: int) -> M:
        """The model, powered up at ``t_ns`` (called by :meth:`start`)."""

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Open the pty, power the model up now and start serving."""
        if self._tasks:
            return
        self._device = PtyDevice(self._name, self._link)
        self._model = self._new_model(time.monotonic_ns())
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

    async def __aenter__(self) -> Self:
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
    def model(self) -> M:
        """The model being served (its state, counters and faults)."""
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
                raise  # a real pty failure: a crash (see the module docstring)
            model.receive(data, time.monotonic_ns())
            self._poke()

    async def _send_loop(self) -> None:
        """Write what the model delivered, then sleep until its next event or new input."""
        device = self._require_device()
        model = self.model
        while True:
            for chunk in model.poll(time.monotonic_ns()):
                try:
                    device.write(chunk)
                    self.chunks_written += 1
                except LinkError:
                    self.lost_chunks += 1
            self._notify()
            next_ns = model.next_event_ns()
            self._wake.clear()
            if next_ns is None:
                await self._wake.wait()
                continue
            delay_s = (next_ns - time.monotonic_ns()) / NS_PER_S
            if delay_s > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay_s):
                        await self._wake.wait()
            if not self._wake.is_set():
                self._note_late(next_ns, time.monotonic_ns())

    def _note_late(self, due_ns: int, now_ns: int) -> None:
        """Note a wake-up late for its event: the device's bytes go out late (a busy host).

        What a client sees as a late frame is then the emulator's, not the client's: the
        soak (``tools/soak.py``) tells the two apart with these.
        """
        if now_ns - due_ns < LATE_NOTE_NS:
            return
        self.late_count += 1
        if len(self.late_wakes) < LATE_KEEP:
            self.late_wakes.append((now_ns, (now_ns - due_ns) / NS_PER_MS))

    def _poke(self) -> None:
        """Make the sender re-plan now (the model's next event may have moved)."""
        self._wake.set()
        self._notify()

    def _notify(self) -> None:
        """Wake everyone in :meth:`wait_for`: the model may have changed."""
        changed, self._changed = self._changed, asyncio.Event()
        changed.set()

    async def wait_for(self, predicate: Callable[[M], bool], timeout_s: float = 2.0) -> None:
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

    # ----------------------------------------------------------------- plug faults
    def vanish(self) -> None:
        """Pull the USB plug: the client's reads and writes fail; the device runs on."""
        self._plugged.clear()
        self._require_device().vanish()

    def replug(self) -> None:
        """Plug back in: a fresh pty behind the same link path; the device is untouched."""
        self._require_device().replug()
        self._plug_generation += 1
        self._plugged.set()
        self._poke()
