"""The live view's side of the control path: :class:`LiveFeed`, a flight observer.

The MK step and the laser task call it (:class:`~mkflight.flight.observer.FlightObserver`);
it keeps references to the newest sample, step output, set-point and scan, queues the
steps that changed the phase or raised a failsafe (so that a publisher that skipped steps
still tells every event), and wakes the publisher. Each call is a few attribute stores:
no message is built, nothing is encoded or sent, nothing can raise. Once the publisher
has failed (:meth:`LiveFeed.stop`) the calls do nothing at all.

No Foxglove import here: the flight's modules may import this one.
"""

from __future__ import annotations

import asyncio
from collections import deque
from typing import TYPE_CHECKING, Final

from mkflight.flight.observer import FlightObserver

if TYPE_CHECKING:
    from mkflight.control.controller import Setpoint
    from mkflight.flight.step import ImuStepOutput
    from mkflight.msgs import ImuSample, Scan

MAX_PENDING_EVENTS: Final = 256
"""Steps with phase or failsafe events kept for a publisher that fell behind (a flight
has a handful; beyond this many unpublished, the oldest go)."""


class LiveFeed(FlightObserver):
    """The newest of everything the flight told, for the publisher (see the module).

    ``sample``, ``out``, ``setpoint``: the last step's (None before the first);
    ``scan``: the newest scan; ``steps``: how many steps were told; ``events``: the step
    outputs with phase or failsafe events not yet published; ``wake``: set on each step.
    """

    __slots__ = ("events", "on", "out", "sample", "scan", "setpoint", "steps", "wake")

    def __init__(self) -> None:
        self.sample: ImuSample | None = None
        self.out: ImuStepOutput | None = None
        self.setpoint: Setpoint | None = None
        self.scan: Scan | None = None
        self.steps = 0
        self.events: deque[ImuStepOutput] = deque(maxlen=MAX_PENDING_EVENTS)
        self.wake = asyncio.Event()
        self.on = True

    def on_step(self, sample: ImuSample, out: ImuStepOutput, setpoint: Setpoint | None) -> None:
        """Keep the step's values and wake the publisher (O(1), see the module)."""
        if not self.on:
            return
        self.sample, self.out, self.setpoint = sample, out, setpoint
        self.steps += 1
        if out.phase_events or out.failsafe_events:
            self.events.append(out)
        self.wake.set()

    def on_scan(self, scan: Scan) -> None:
        """Keep the newest scan (published after the next step)."""
        if self.on:
            self.scan = scan

    def stop(self) -> None:
        """Tell nothing more: drop the references, ignore every later call."""
        self.on = False
        self.sample = self.out = self.setpoint = self.scan = None
        self.events.clear()
