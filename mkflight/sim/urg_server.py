"""The emulated URG-04LX on a pseudo-terminal: :class:`UrgModel` behind a :class:`PtyDevice`.

Clients open :attr:`UrgEmulator.path` like the sensor's ``/dev/ttyACM*`` (a CDC-ACM port,
where the baud rate does not matter: ``protocols/scip2.md`` §1), so the driver is
exercised exactly as in flight (SPEC §8). Like :mod:`mkflight.sim.fc_server`, two tasks do
the I/O: one feeds what the client writes to :meth:`UrgModel.receive`, stamped with
``time.monotonic_ns``; the other sleeps until :meth:`UrgModel.next_event_ns` (or new
input) and writes what :meth:`UrgModel.poll` has delivered. No periodic tick.

Timing: a full scan leaves the sensor 70.8 ms after its timestamp (step 0, §3.3); the
USB transfer then takes ``usb_delay_s`` (default 30 ms), so a scan reaches the client
about 100 ms after its step 0, as SPEC §2/§8 ask.

Faults: :meth:`UrgEmulator.vanish`/:meth:`UrgEmulator.replug` pull and reinsert the USB
cable (the UG01 is USB-powered, so by default it restarts on replug: SCIP 1.1, timer 0);
garbage, bad sums and stalls are passed to the model, with times relative to now.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Final

from mkflight.errors import LinkError
from mkflight.io.pty import PtyDevice
from mkflight.sim.urg import RangeSource, UrgModel
from mkflight.sim.urg_answers import UrgIdentity

USB_DELAY_S: Final = 0.03


class UrgEmulator:
    """A URG-04LX answering SCIP on a pty (``scip2.md``), for tests and ``--sim``."""

    def __init__(
        self,
        source: RangeSource,
        *,
        link: str | Path | None = None,
        name: str = "urg",
        scip1: bool = True,
        timer_ms: int = 0,
        identity: UrgIdentity | None = None,
        usb_delay_s: float = USB_DELAY_S,
    ) -> None:
        """Prepare the emulator; nothing runs before :meth:`start`.

        Args:
            source: the ranges the sensor measures (a room scene, a fixed table).
            link: a stable symlink to the pty (survives :meth:`replug`), else none.
            name: a label for messages.
            scip1: power up in SCIP 1.1 like a URG-04LX (False: a UG01).
            timer_ms: the sensor's millisecond timer at start.
            identity: the VV/PP/II texts and parameters (default: a URG-04LX).
            usb_delay_s: how long each reply takes from the sensor to the client.
        """
        self._source = source
        self._link = link
        self._name = name
        self._scip1 = scip1
        self._timer_ms = timer_ms
        self._identity = identity
        self._usb_delay_s = usb_delay_s
        self._device: PtyDevice | None = None
        self._model: UrgModel | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._wake = asyncio.Event()
        self._changed = asyncio.Event()
        self._plugged = asyncio.Event()
        self._plug_generation = 0
        self.lost_chunks = 0
        self.chunks_written = 0
        self.error: LinkError | None = None

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Open the pty, power the sensor model up now and start serving."""
        if self._tasks:
            return
        self._device = PtyDevice(self._name, self._link)
        self._model = UrgModel(
            self._source,
            t_ns=time.monotonic_ns(),
            timer_ms=self._timer_ms,
            scip1=self._scip1,
            identity=self._identity,
            delivery_delay_ns=round(self._usb_delay_s * 1e9),
        )
        self._plugged.set()
        self._tasks = [
            asyncio.create_task(self._read_loop(), name=f"{self._name}-rx"),
            asyncio.create_task(self._send_loop(), name=f"{self._name}-tx"),
        ]

    async def stop(self) -> None:
        """Stop serving and close the pty (its link is removed)."""
        tasks, self._tasks = self._tasks, []
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self._device is not None:
            await self._device.close()

    async def __aenter__(self) -> UrgEmulator:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.stop()

    @property
    def path(self) -> str:
        """What a client opens: the link if one was given, else ``/dev/pts/N``."""
        return self._require_device().path

    @property
    def device(self) -> PtyDevice:
        """The pty device end."""
        return self._require_device()

    @property
    def model(self) -> UrgModel:
        """The sensor model being served (its state, counters and faults)."""
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
            except LinkError as err:
                if generation != self._plug_generation:
                    continue  # replugged while we waited on the old pty
                if not device.is_open:
                    await self._plugged.wait()
                    continue
                self.error = err
                return
            model.receive(data, time.monotonic_ns())
            self._poke()

    async def _send_loop(self) -> None:
        """Write delivered replies, then sleep until the model's next event or new input."""
        device = self._require_device()
        model = self.model
        while True:
            for chunk in model.poll(time.monotonic_ns()):
                try:
                    device.write(chunk)
                    self.chunks_written += 1
                except LinkError:
                    self.lost_chunks += 1  # unplugged: the sensor sends into the void
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

    async def wait_for(self, predicate: Callable[[UrgModel], bool], timeout_s: float = 2.0) -> None:
        """Wait until ``predicate(model)`` holds, checking whenever the model changed.

        Raises:
            TimeoutError: it did not hold within ``timeout_s``.
        """
        model = self.model
        try:
            async with asyncio.timeout(timeout_s):
                while not predicate(model):
                    await self._changed.wait()
        except TimeoutError as err:
            msg = f"{self._name}: condition not met within {timeout_s} s"
            raise TimeoutError(msg) from err

    # ----------------------------------------------------------------- faults and knobs
    @property
    def usb_delay_s(self) -> float:
        """How long each reply takes from the sensor to the client."""
        return self._usb_delay_s

    @usb_delay_s.setter
    def usb_delay_s(self, value: float) -> None:
        self._usb_delay_s = value
        if self._model is not None:
            self._model.delivery_delay_ns = round(value * 1e9)
            self._poke()

    def vanish(self) -> None:
        """Unplug the USB cable: the client's reads and writes fail; the sensor runs on."""
        self._plugged.clear()
        self._require_device().vanish()

    def replug(self, *, power_cycle: bool = True) -> None:
        """Plug the cable back in: a fresh pty behind the same link path.

        A URG-04LX-UG01 is powered by its USB cable, so by default the sensor restarts
        (SCIP 1.1 if it started so, timer 0, laser off); ``power_cycle=False`` models a
        separately powered URG-04LX that kept running.
        """
        if power_cycle:
            self.model.power_cycle(time.monotonic_ns())
        self._require_device().replug()
        self._plug_generation += 1
        self._plugged.set()
        self._poke()

    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next reply."""
        self.model.inject_garbage(data)
        self._poke()

    def corrupt_next(self, n: int) -> None:
        """Give the next ``n`` replies a bad sum (the client drops them, SC-21)."""
        self.model.corrupt_next(n)
        self._poke()

    def stall_for(self, duration_s: float) -> None:
        """Send no scan for ``duration_s`` while still answering commands."""
        self.model.stall(time.monotonic_ns() + round(duration_s * 1e9))
        self._poke()
