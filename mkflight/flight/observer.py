"""What a watcher of the flight is told: :class:`FlightObserver` (the live view's seam).

The MK step tells it each step's DebugOut sample, output and set-point once the step's
command is out and its rows are written; the laser task tells it each scan as it
arrives. Both calls run on the control path, so an observer only keeps references to
values the flight has already made (O(1)): it builds, encodes and sends nothing there,
and it never raises. Whatever it does with them runs elsewhere (the live view's publisher,
:mod:`mkflight.ground.live`, is a task of its own in the idle gap after a step). The
default observer does nothing: a flight without ``--live`` is told to nobody.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mkflight.control.controller import Setpoint
    from mkflight.flight.step import ImuStepOutput
    from mkflight.msgs import ImuSample, Scan


class FlightObserver:
    """Told of every step and every scan; the default forgets them (see the module)."""

    __slots__ = ()

    def on_step(self, sample: ImuSample, out: ImuStepOutput, setpoint: Setpoint | None) -> None:
        """A step ran on ``sample``; ``setpoint`` is the one its controller was given."""

    def on_scan(self, scan: Scan) -> None:
        """A scan came from the URG (before the matcher has it)."""
