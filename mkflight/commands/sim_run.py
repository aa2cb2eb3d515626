"""``mkflight sim``: the simulated vehicle on two pseudo-terminals until stopped (SPEC §8).

It prints exactly two lines on stdout, ``mk PATH`` and ``laser PATH`` (a parent such as
``fly --sim`` reads them), then serves both devices in real time until SIGINT, SIGTERM
or ``--duration``, and stops cleanly (exit 0). Nothing else goes to stdout; events go
to stderr.
"""

from __future__ import annotations

import math
import os
import signal
import sys
from typing import TYPE_CHECKING

from mkflight.commands import sim_envelope, sim_hover
from mkflight.commands.args import (
    Command,
    Subparsers,
    add_airframe,
    airframe_overrides,
    config_options,
    subcommands,
)
from mkflight.errors import ConfigError

if TYPE_CHECKING:
    import asyncio

    from mkflight.config import Config
    from mkflight.sim.live import Fault


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

    ``airframe``: ``--airframe`` (:func:`~mkflight.commands.args.airframe_overrides`).

    Raises:
        ConfigError: a bad config, fault string or duration; the truth file exists.
    """
    import asyncio

    from mkflight.config import load_config
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
    import asyncio

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
    import asyncio

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


def add_parser(subparsers: Subparsers) -> None:
    """``sim``: the live simulator, and its subcommands ``sim hover`` and ``sim envelope``."""
    sim = subparsers.add_parser(
        "sim",
        parents=[config_options()],
        help="the simulator: the vehicle on two ptys, or 'sim hover' in lock-step",
        description="Without a subcommand: the simulated vehicle (vehicle model, FC "
        "emulator, URG emulator in a room) in real time on two pseudo-terminals; prints "
        "'mk PATH' and 'laser PATH' and runs until SIGINT/SIGTERM or --duration. Fly it "
        "with 'mkflight fly --hover --mk-port PATH --laser-port PATH'.",
    )
    sim.add_argument(
        "--seed",
        type=int,
        metavar="N",
        help="seeds this run: noise, gusts, the vehicle's errors (default sim.seed); with "
        "--airframe random also the airframe, unless --set sim.seed=M picks it",
    )
    add_airframe(sim)
    sim.add_argument("--mk-link", metavar="PATH", help="a stable symlink to the FC's pty")
    sim.add_argument("--laser-link", metavar="PATH", help="a stable symlink to the URG's pty")
    sim.add_argument("--truth", metavar="FILE", help="write the ground truth (t x y z) here")
    sim.add_argument(
        "--fault",
        dest="faults",
        action="append",
        default=[],
        metavar="KIND@T[:ARG]",
        help="inject a fault T s after start, e.g. laser-stall@20:2, fc-vanish@30, battery@25:10.0",
    )
    sim.add_argument(
        "--faults-on-sigusr1",
        action="store_true",
        help="count the --fault times from a SIGUSR1 instead of the start (a test arms "
        "them once the vehicle hovers)",
    )
    sim.add_argument(
        "--duration", dest="duration_s", type=float, metavar="S", help="stop after S s"
    )
    sim.add_argument(
        "--exit-on-eof",
        action="store_true",
        help="also stop when standard input ends (fly --sim: never outlive the daemon)",
    )
    sim.set_defaults(func=Command(cmd_sim))
    # A subcommand's options overwrite the same dests of sim's own (argparse parses them
    # into a fresh namespace, then copies it over): 'sim --seed 3 hover' flies seed None.
    sim_commands = subcommands(sim, "sim_command", required=False)
    sim_hover.add_parser(sim_commands)
    sim_envelope.add_parser(sim_commands)
