"""The flight's folder and its two ports: :class:`FlightPorts` (SPEC §6, §7).

The pre-flight opens them in this order - the folder first
(:mod:`~mkflight.flight.flight_logs`), so that every byte the ports carry is recorded
(:mod:`~mkflight.flight.taps`), then the FC's port and the laser's
(:mod:`~mkflight.flight.links`: a port that cannot be opened is a failed check, named) -
and keeps each one as soon as it is open, so that a later failure still closes it. The
shutdown closes them the other way round: the MK link first, handing control back to
the pilot, then the laser, and the folder last, with the summary.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from mkflight.clock import Clock
from mkflight.config import Config
from mkflight.config_search import ConfigSource
from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.links import open_laser, open_mk
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.stats import StepStats
from mkflight.flight.taps import PortTaps
from mkflight.logs.schema import FlightSummary
from mkflight.mk.link import MkLink
from mkflight.urg.driver import UrgDriver


class OpenPorts(NamedTuple):
    """The folder and both links, all open."""

    logs: FlightLogs
    taps: PortTaps
    link: MkLink
    driver: UrgDriver


class FlightPorts:
    """The flight folder, the byte taps, the MK link and the URG driver (None until open)."""

    __slots__ = ("_clock", "_policy", "_stats", "driver", "link", "logs", "taps")

    def __init__(self, *, clock: Clock, policy: FlightPolicy, stats: StepStats) -> None:
        self._clock = clock
        self._policy = policy
        self._stats = stats
        self.logs: FlightLogs | None = None
        self.taps: PortTaps | None = None
        self.link: MkLink | None = None
        self.driver: UrgDriver | None = None

    async def open(
        self,
        cfg: Config,
        folder: Path,
        *,
        mk_port: str,
        laser_port: str,
        durable: bool,
        on_log_error: Callable[[OSError], None],
        config_source: ConfigSource | None = None,
    ) -> OpenPorts:
        """Create the folder's files, then open both ports as links (see the module docstring).

        Raises:
            PreflightError: 'log dir', 'FC port' or 'laser port' failed.
        """
        clock = self._clock
        self.logs = logs = FlightLogs(
            folder,
            cfg,
            mk_port=mk_port,
            laser_port=laser_port,
            clock=clock,
            on_error=on_log_error,
            durable=durable,
            config_source=config_source,
        )
        self.taps = taps = PortTaps(
            logs.mk_raw, logs.laser_raw, clock=clock, policy=self._policy, stats=self._stats
        )
        open_port = self._policy.open_port
        self.link = link = await open_mk(
            mk_port, cfg, clock, taps.mk, lambda p: taps.mark("mk", "o", p), open_port
        )
        self.driver = driver = await open_laser(
            laser_port, cfg, clock, taps.laser, lambda p: taps.mark("laser", "o", p), open_port
        )
        return OpenPorts(logs, taps, link, driver)

    def opened(self) -> OpenPorts:
        """The folder and both links, after :meth:`open` succeeded.

        Raises:
            RuntimeError: something is not open (a bug in the caller).
        """
        logs, taps, link, driver = self.logs, self.taps, self.link, self.driver
        if logs is None or taps is None or link is None or driver is None:
            msg = "the flight's ports are not open"
            raise RuntimeError(msg)
        return OpenPorts(logs, taps, link, driver)

    async def hand_back(self) -> bool:
        """Close the MK link, releasing control; True if Config = 0 frames went out."""
        if self.link is None:
            return False
        before = self.link.stats.frames_written
        with contextlib.suppress(Exception):
            await self.link.close(release=True)
        return self.link.stats.frames_written > before

    async def close_laser(self) -> None:
        """Close the URG driver (the laser gets its QT)."""
        if self.driver is not None:
            with contextlib.suppress(Exception):
                await self.driver.close()

    def close_logs(self, summary: FlightSummary) -> None:
        """The ``end`` event, every file flushed and closed, ``flight.json``'s summary."""
        if self.logs is not None:
            self.logs.close(self._clock.now_ns(), summary)
