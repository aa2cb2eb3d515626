"""Opening the daemon's two ports as links (SPEC §2): the FC's and the URG's.

Each link gets its port's raw-recording tap, an opener to re-open the port after it
vanished (a USB unplug), and an 'o' mark in the recording for every open. A port that
cannot be opened is a failed pre-flight check, named.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable

from mkflight.clock import Clock
from mkflight.config import Config
from mkflight.errors import LinkError, PreflightError
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream, Tap
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.units import MkCalibration
from mkflight.urg.driver import UrgDriver

URG_BAUDRATE = 115200  # USB CDC-ACM ignores it (scip2.md §1)

#: Records that a port was (re)opened: ``mark(path)``.
Mark = Callable[[str], None]
#: Opens a port: ``open_port(path, baudrate)`` (a serial port; a replay's memory port).
PortOpener = Callable[[str, int], Awaitable[ByteStream]]


async def _open(path: str, baudrate: int, check: str, open_port: PortOpener) -> ByteStream:
    try:
        return await open_port(path, baudrate)
    except LinkError as err:
        raise PreflightError(check=check, detail=str(err)) from err


async def open_mk(
    path: str,
    cfg: Config,
    clock: Clock,
    tap: Tap,
    mark: Mark,
    open_port: PortOpener = open_serial,
) -> MkLink:
    """The FlightCtrl link on ``path``, started (its reader running).

    Raises:
        PreflightError: the port cannot be opened ('FC port').
    """
    stream = await _open(path, cfg.mk.baudrate, "FC port", open_port)
    mark(path)

    async def reopen() -> ByteStream:
        again = await open_port(path, cfg.mk.baudrate)
        mark(path)
        return again

    link = MkLink(
        stream,
        LinkSettings.from_config(cfg),
        MkCalibration.from_config(cfg.mk),
        clock,
        reopen=reopen,
        tap=tap,
    )
    link.start()
    return link


async def open_laser(
    path: str,
    cfg: Config,
    clock: Clock,
    tap: Tap,
    mark: Mark,
    open_port: PortOpener = open_serial,
) -> UrgDriver:
    """The URG driver on ``path``, started.

    Raises:
        PreflightError: the port cannot be opened ('laser port').
    """
    stream = await _open(path, URG_BAUDRATE, "laser port", open_port)
    mark(path)

    async def reopen() -> ByteStream:
        again = await open_port(path, URG_BAUDRATE)
        mark(path)
        return again

    driver = UrgDriver(stream, cfg.laser, clock, reopen=reopen, tap=tap)
    driver.start()
    return driver
