"""What a replay or a test harness changes in the flight shell: :class:`FlightPolicy`.

The flight daemon (:class:`~mkflight.flight.app.FlightApp`) runs the same pre-flight,
links, tasks and step live and in a replay (STYLE: "``--sim`` and replay swap streams
and clock, never code"). What a replay must add - wait for a recorded moment, pin where
a recorded result enters, tell its feeder what was read, end on a signal instead of
landing - comes in through this object. The live daemon passes the default, whose
hooks do nothing (and whose ports are the serial ports); a replay passes its own
(:class:`~mkflight.replay.daemon.ReplayPolicy`).
"""

from __future__ import annotations

from collections.abc import Sequence

from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.safety.failsafe import StopRequest

NO_STOPS: tuple[tuple[StopRequest, str], ...] = ()


class FlightPolicy:
    """The flight shell's seams; each default is what a live flight does (nothing extra)."""

    async def open_port(self, path: str, baudrate: int) -> ByteStream:
        """Open one of the daemon's ports: here the serial port ``path``.

        Raises:
            PortNotFoundError: ``path`` does not exist.
            LinkError: it cannot be opened.
        """
        return await open_serial(path, baudrate)

    def on_bytes(self, port: str, direction: str, n_bytes: int) -> None:
        """``n_bytes`` were read ('r') from or written ('w') to ``port`` ('mk', 'laser')."""

    def on_mark(self, port: str, kind: str) -> None:
        """``port`` was (re)opened ('o') or given up ('c')."""

    async def before_ready(self) -> None:
        """Return at once: READY follows the pre-flight."""

    async def before_subscribe(self) -> None:
        """Return at once: the MK task subscribes to DebugOut as it starts."""

    def stops_due(self, steps: int) -> Sequence[tuple[StopRequest, str]]:
        """Stop requests to make before the step that follows ``steps`` steps: none."""
        return NO_STOPS

    def after_step(self, logs: FlightLogs) -> None:
        """A step's rows and events were written to ``logs``."""

    def scan_wanted(self, seq: int) -> bool:
        """Whether the laser task matches scan ``seq``: always."""
        return True

    def laser_result_due(self, result: LaserResult, step: int) -> bool:
        """Whether ``result`` enters the core at step number ``step``: at once."""
        return True

    def on_signal(self, name: str) -> None:
        """SIGINT, SIGTERM or SIGHUP arrived; the shell lands after this returns."""
