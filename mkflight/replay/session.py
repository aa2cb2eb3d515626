"""One replay's plumbing: the new flight folder, and the daemon run on a lock-step loop."""

from __future__ import annotations

import asyncio
import contextlib
import shutil
from pathlib import Path

from mkflight.errors import ConfigError
from mkflight.flight.app import FlightReport
from mkflight.replay.daemon import ReplayApp
from mkflight.replay.feeder import Feeder
from mkflight.replay.vloop import LockstepLoop, VirtualClock


def default_out_dir(source: Path) -> Path:
    """``<flight>-replay`` beside the flight, or ``-replay-2``, ``-3``... if taken."""
    source = source.resolve()  # "." has no name
    base = source.parent / f"{source.name}-replay"
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def out_dir_for(source: Path, out_dir: str | Path | None) -> Path:
    """The new flight folder, created (empty); a usage error if that cannot be."""
    out = Path(out_dir) if out_dir is not None else default_out_dir(source)
    if out.exists() and not out.is_dir():
        msg = f"output folder {str(out)!r} is a file"
        raise ConfigError(msg)
    if out.exists() and any(out.iterdir()):
        msg = f"output folder {str(out)!r} is not empty: a flight folder is never overwritten"
        raise ConfigError(msg)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f"output folder {str(out)!r} cannot be created: {err.strerror or err}"
        raise ConfigError(msg) from err
    return out


async def _run(app: ReplayApp, feeder: Feeder) -> FlightReport:
    feeder.open_devices()
    try:
        return await app.fly()
    finally:
        feeder.close_devices()


def run_lockstep(
    app: ReplayApp, feeder: Feeder, clock: VirtualClock, link_dir: Path
) -> FlightReport:
    """Fly ``app`` on a lock-step loop fed by ``feeder``; always clean up.

    SIGINT/SIGTERM stop the replay, not the replayed vehicle (:class:`ReplayApp`): the
    daemon is cancelled - it still closes its ports and its folder - and
    KeyboardInterrupt goes on to the caller.
    """
    loop = LockstepLoop(clock, feeder)
    asyncio.set_event_loop(loop)
    main = loop.create_task(_run(app, feeder))
    try:
        return loop.run_until_complete(main)
    except KeyboardInterrupt:
        main.cancel()
        with contextlib.suppress(BaseException):
            loop.run_until_complete(main)
        raise
    finally:
        with contextlib.suppress(Exception):
            loop.run_until_complete(loop.shutdown_asyncgens())
        asyncio.set_event_loop(None)
        loop.close()
        shutil.rmtree(link_dir, ignore_errors=True)
