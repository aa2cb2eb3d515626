"""The emulated URG-04LX on a pseudo-terminal: :class:`UrgModel` behind a :class:`PtyDevice`.

Clients open :attr:`UrgEmulator.path` like the sensor's ``/dev/ttyACM*`` (a CDC-ACM port,
where the baud rate does not matter: ``protocols/scip2.md`` §1), so the driver is
exercised exactly as in flight (SPEC §8). The serving itself (the read and send tasks,
stamped with ``time.monotonic_ns``, no periodic tick; ``wait_for``; crash surfacing) is
:class:`~mkflight.sim.pty_server.PtyEmulator`'s, shared with
:mod:`mkflight.sim.fc_server`; this module builds the :class:`UrgModel` and passes its
faults through.

Timing: a full scan leaves the sensor 70.8 ms after its timestamp (step 0, §3.3); the
USB transfer then takes ``usb_delay_s`` (default :data:`USB_DELAY_S`, 30 ms: the
simulator's own figure for this sensor, not the driver's configured
``transport_delay_s``) plus a per-reply jitter uniform in ``0..usb_jitter_s`` (seeded;
the model's ``delivery_delay_ns`` and ``delivery_jitter_ns``), so a scan reaches the
client about 100 ms after its step 0, as SPEC §2/§8 ask. The live simulator adds its
airframe's ``laser_extra_delay_s`` (a laser whose data is older than the driver assumes)
and ``laser_jitter_s``.

Faults: :meth:`UrgEmulator.vanish`/:meth:`UrgEmulator.replug` pull and reinsert the USB
cable (the UG01 is USB-powered, so by default it restarts on replug: SCIP 1.1, timer 0);
garbage, bad sums and stalls are passed to the model, with times relative to now.

A crash of either task (a :class:`~mkflight.sim.urg.RangeSource` raising, a failing pty
read) is not swallowed: it is kept in :attr:`UrgEmulator.error`, makes
:meth:`UrgEmulator.wait_for` raise at once, and is re-raised by :meth:`UrgEmulator.stop`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Final

from mkflight.conversions import NS_PER_S
from mkflight.sim.pty_server import PtyEmulator
from mkflight.sim.urg import RangeSource, UrgModel
from mkflight.sim.urg_answers import UrgIdentity

USB_DELAY_S: Final = 0.03  # the URG-04LX's USB transfer of a reply (the sensor's fact)


class UrgEmulator(PtyEmulator[UrgModel]):
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
        usb_jitter_s: float = 0.0,
        seed: int = 0,
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
            usb_jitter_s: plus a jitter per reply, uniform in 0..this (seeded).
            seed: seeds the jitter.
        """
        super().__init__(link=link, name=name)
        self._source = source
        self._scip1 = scip1
        self._timer_ms = timer_ms
        self._identity = identity
        self._usb_delay_s = usb_delay_s
        self._usb_jitter_s = usb_jitter_s
        self._seed = seed

    def _new_model(self, t_ns: int) -> UrgModel:
        """The sensor, powered up at ``t_ns``, its replies delayed by the USB transfer."""
        return UrgModel(
            self._source,
            t_ns=t_ns,
            timer_ms=self._timer_ms,
            scip1=self._scip1,
            identity=self._identity,
            delivery_delay_ns=round(self._usb_delay_s * NS_PER_S),
            delivery_jitter_ns=round(self._usb_jitter_s * NS_PER_S),
            seed=self._seed,
        )

    # ----------------------------------------------------------------- faults and knobs
    @property
    def usb_delay_s(self) -> float:
        """How long each reply takes from the sensor to the client."""
        return self._usb_delay_s

    @usb_delay_s.setter
    def usb_delay_s(self, value: float) -> None:
        self._usb_delay_s = value
        if self._model is not None:
            self._model.delivery_delay_ns = round(value * NS_PER_S)
            self._poke()

    def replug(self, *, power_cycle: bool = True) -> None:
        """Plug the cable back in: a fresh pty behind the same link path.

        A URG-04LX-UG01 is powered by its USB cable, so by default the sensor restarts
        (SCIP 1.1 if it started so, timer 0, laser off); ``power_cycle=False`` models a
        separately powered URG-04LX that kept running.
        """
        if power_cycle:
            self.model.power_cycle(time.monotonic_ns())
        super().replug()

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
        self.model.stall(time.monotonic_ns() + round(duration_s * NS_PER_S))
        self._poke()
