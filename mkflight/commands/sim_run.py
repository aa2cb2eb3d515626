"""``mkflight sim``: the simulated vehicle on two pseudo-terminals until stopped (SPEC §8).

It prints exactly two lines on stdout, ``mk PATH`` and ``laser PATH`` (a parent such as
``fly --sim`` reads them), then serves both devices in real time until SIGINT, SIGTERM
or ``--duration``, and stops cleanly (exit 0). Nothing else goes to stdout; events go
to stderr.
"""

from __future__ import annotations

import asyncio
import math
import os
import signal
import sys
from typing import TYPE_CHECKING

from mkflight.config import Config, load_config
from mkflight.errors import ConfigError

if TYPE_CHECKING:
    from mkflight.sim.live import Fault


def airframe_overrides(overrides: list[str], airframe: str | None, seed: int | None) -> list[str]:
    """``overrides`` plus what ``--airframe`` means: ``sim.airframe``, and maybe ``sim.seed``.

    ``--airframe random --seed N`` flies airframe N (``sim.seed=N``) unless a ``--set
    sim.seed=M`` already picks the airframe; ``--seed`` alone seeds only the flight.
    """
    if airframe is None:
        return list(overrides)
    out = [*overrides, f"sim.airframe={airframe}"]
    picked = any(o.replace(" ", "").startswith("sim.seed=") for o in overrides)
    if airframe == "random" and seed is not None and not picked:
        out.append(f"sim.seed={seed}")
    return out


def cmd_sim(
    *,
    config_path: str | None,
    overrides: list[str],
    seed: int | None,
    airframe: str | None = None,
    mk_link: str | None,
    laser_link: str | None,
    truth: str | None,
    faults: list[str],
    duration_s: float | None,
    exit_on_eof: bool = False,
    faults_on_sigusr1: bool = False,
) -> int:
    """Run the live simulator (:class:`~mkflight.sim.live.LiveSim`) until stopped.

    ``airframe``: ``--airframe`` (:func:`airframe_overrides`).

    Raises:
        ConfigError: a bad config, fault string or duration; the truth file exists.
    """
    import asyncio

    from mkflight.sim.live import parse_faults

    cfg = load_config(config_path, airframe_overrides(overrides, airframe, seed))
    schedule = parse_faults(faults)
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        msg = f"--duration must be a finite number of seconds > 0, got {duration_s}"
        raise ConfigError(msg)
    return asyncio.run(
        _serve(
            cfg,
            seed=seed,
            mk_link=mk_link,
            laser_link=laser_link,
            truth=truth,
            faults=schedule,
            duration_s=duration_s,
            exit_on_eof=exit_on_eof,
            faults_on_sigusr1=faults_on_sigusr1,
        )
    )


async def _serve(
    cfg: Config,
    *,
    seed: int | None,
    mk_link: str | None,
    laser_link: str | None,
    truth: str | None,
    faults: list[Fault],
    duration_s: float | None,
    exit_on_eof: bool,
    faults_on_sigusr1: bool = False,
) -> int:
    """Start, print the two paths, serve until a signal, the duration or the stdin's end.

    ``exit_on_eof``: the end of standard input means the parent that started us with a
    pipe has gone.
    """
    from mkflight.commands.interrupt import stop_on_signals
    from mkflight.sim.live import LiveSim

    stop = stop_on_signals()
    if exit_on_eof:
        _stop_on_stdin_eof(stop)
    fault_clock: asyncio.Event | None = None
    if faults_on_sigusr1:
        fault_clock = asyncio.Event()
        asyncio.get_running_loop().add_signal_handler(signal.SIGUSR1, fault_clock.set)
    sim = LiveSim(
        cfg,
        seed=seed,
        mk_link=mk_link,
        laser_link=laser_link,
        truth_path=truth,
        truth_origin_ns=0,  # t = host monotonic seconds, the flight logs' own time base
        faults=faults,
        fault_clock=fault_clock,
    )
    mk_path, laser_path = await sim.start()
    try:
        print(f"mk {mk_path}", flush=True)
        print(f"laser {laser_path}", flush=True)
        await sim.serve(stop, duration_s)
    finally:
        await sim.stop()
    return 0


def _stop_on_stdin_eof(stop: asyncio.Event) -> None:
    """Set ``stop`` when standard input reaches its end (the writing parent exited)."""
    loop = asyncio.get_running_loop()
    fd = sys.stdin.fileno()

    def readable() -> None:
        try:
            data = os.read(fd, 4096)
        except OSError:
            data = b""
        if not data:
            loop.remove_reader(fd)
            stop.set()

    loop.add_reader(fd, readable)
