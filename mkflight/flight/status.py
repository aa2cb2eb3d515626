"""The daemon's status line (SPEC §7): :func:`status_line`, shown by :class:`StatusDisplay`."""

from __future__ import annotations

import contextlib
import math
import sys

from mkflight.control.controller import Setpoint
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.step import ImuStepOutput


def status_line(
    out: ImuStepOutput | None, sp: Setpoint | None, battery_v: float, latency_ms: float
) -> str:
    """Phase, height, position error, battery, step latency of the last step ``out``."""
    if out is None:
        return "waiting for the FlightCtrl"
    est = out.estimate
    err = math.hypot(est.x_m - sp.x_m, est.y_m - sp.y_m) if sp is not None else math.nan
    return (
        f"{out.phase.name:<9} h {est.height_m:5.2f} m  err {err:5.3f} m  "
        f"bat {battery_v:5.2f} V  "
        f"step {latency_ms:5.2f} ms  {out.action.name}"
    )


class StatusDisplay:
    """The status line: to systemd's STATUS, and redrawn on the terminal while there is one."""

    __slots__ = ("_notifier", "_tty")

    def __init__(self, notifier: Notifier, *, tty: bool) -> None:
        self._notifier = notifier
        self._tty = tty

    def show(self, line: str) -> None:
        """Send ``line`` as STATUS; redraw it on the terminal."""
        self._notifier.status(line)
        if self._tty:
            try:
                sys.stderr.write("\r" + line + "\x1b[K")
                sys.stderr.flush()
            except (OSError, ValueError):  # the terminal went away (ssh dropped)
                self._tty = False

    def terminal_gone(self) -> None:
        """The terminal is gone (SIGHUP): no more redraws."""
        self._tty = False

    def end(self) -> None:
        """Leave the terminal's cursor below the last line drawn."""
        if self._tty:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write("\n")
