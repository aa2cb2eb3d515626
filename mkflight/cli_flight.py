"""The ``fly`` and ``sim`` subcommands' arguments (split from :mod:`mkflight.cli`).

argparse only, like ``cli.py``: each parser's runner imports its ``cmd_*`` lazily.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

Runner = Callable[[argparse.Namespace], int]


def add_flight_commands(
    commands: Any,
    config_opts: argparse.ArgumentParser,
    command: Callable[..., Runner],
    parser_class: type[argparse.ArgumentParser],
    config_args: dict[str, str],
) -> None:
    """Add ``fly`` and ``sim`` (live, and ``sim hover``) to the command tree."""
    fly = commands.add_parser(
        "fly",
        parents=[config_opts],
        help="fly: pre-flight checks, take-off, hold, soft landing, release",
        description="The flight daemon (SPEC §7): pre-flight checks (FC version and "
        "DebugOut rate, level, battery, laser info and scan rate, hat height on the ground, "
        "scan match), the neutral handshake, take-off to --height, hold at the take-off "
        "x, y, psi, and a soft landing and release on SIGINT/SIGTERM, --duration or a "
        "failsafe. Writes a flight folder (TABLE III/IV, events.jsonl, flight.json, raw "
        "recordings of both ports). Exit 0 after a landing, 1 on a failure (after the "
        "landing and release), 2 on bad usage.",
    )
    fly.add_argument("--hover", action="store_true", help="the mission: hold position")
    fly.add_argument(
        "--sim", action="store_true", help="fly the simulated vehicle (its own process, ptys)"
    )
    fly.add_argument("--mk-port", metavar="DEV", help="the FlightCtrl's port (default mk.port)")
    fly.add_argument("--laser-port", metavar="DEV", help="the URG's port (default laser.port)")
    fly.add_argument("--height", type=float, metavar="M", help="hover height (default 0.6)")
    fly.add_argument("--duration", type=float, metavar="S", help="land this long after the checks")
    fly.add_argument("--log-dir", metavar="DIR", help="flight folder (default: new, dated)")
    fly.add_argument("--json", action="store_true", help="the summary as one JSON object")
    fly.set_defaults(
        func=command(
            "mkflight.commands.fly:cmd_fly",
            hover="hover",
            sim="sim",
            mk_port="mk_port",
            laser_port="laser_port",
            height_m="height",
            duration_s="duration",
            log_dir="log_dir",
            as_json="json",
            **config_args,
        )
    )

    sim = commands.add_parser(
        "sim",
        parents=[config_opts],
        help="the simulator: the vehicle on two ptys, or 'sim hover' in lock-step",
        description="Without a subcommand: the simulated vehicle (vehicle model, FC "
        "emulator, URG emulator in a room) in real time on two pseudo-terminals; prints "
        "'mk PATH' and 'laser PATH' and runs until SIGINT/SIGTERM or --duration. Fly it "
        "with 'mkflight fly --hover --mk-port PATH --laser-port PATH'.",
    )
    sim.add_argument(
        "--seed",
        dest="live_seed",
        type=int,
        metavar="N",
        help="seeds this run: noise, gusts, the vehicle's errors (default sim.seed); with "
        "--airframe random also the airframe, unless --set sim.seed=M picks it",
    )
    sim.add_argument(
        "--airframe",
        dest="live_airframe",
        choices=("nominal", "random"),
        help="the simulated airframe: 'nominal' (sim.vehicle) or 'random' (drawn from the "
        "envelope with sim.seed); short for --set sim.airframe=...",
    )
    sim.add_argument("--mk-link", metavar="PATH", help="a stable symlink to the FC's pty")
    sim.add_argument("--laser-link", metavar="PATH", help="a stable symlink to the URG's pty")
    sim.add_argument("--truth", metavar="FILE", help="write the ground truth (t x y z) here")
    sim.add_argument(
        "--fault",
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
        "--duration", dest="live_duration", type=float, metavar="S", help="stop after S s"
    )
    sim.add_argument(
        "--exit-on-eof",
        action="store_true",
        help="also stop when standard input ends (fly --sim: never outlive the daemon)",
    )
    sim.set_defaults(
        func=command(
            "mkflight.commands.sim_run:cmd_sim",
            exit_on_eof="exit_on_eof",
            faults_on_sigusr1="faults_on_sigusr1",
            seed="live_seed",
            airframe="live_airframe",
            mk_link="mk_link",
            laser_link="laser_link",
            truth="truth",
            faults="fault",
            duration_s="live_duration",
            **config_args,
        )
    )
    sim_commands = sim.add_subparsers(
        dest="sim_command", metavar="COMMAND", parser_class=parser_class
    )
    hover = sim_commands.add_parser(
        "hover",
        parents=[config_opts],
        help="fly a simulated hover in lock-step and print its precision",
        description="Estimator, controllers, failsafe and vehicle model in lock-step, far "
        "faster than real time: take off, hold, land; writes the flight folder (TABLE III "
        "and IV, flight.json, truth.txt) and prints the hover precision against truth.",
    )
    hover.add_argument("--duration", type=float, default=60.0, metavar="S", help="flight time")
    hover.add_argument(
        "--seed",
        type=int,
        metavar="N",
        help="seeds the flight: noise, gusts, the vehicle's errors (default sim.seed); with "
        "--airframe random also the airframe, unless --set sim.seed=M picks it "
        "(--airframe random --set sim.seed=3 --seed 1: airframe 3, flight 1)",
    )
    hover.add_argument(
        "--airframe",
        choices=("nominal", "random"),
        help="the simulated airframe: 'nominal' (sim.vehicle) or 'random' (drawn from the "
        "envelope with sim.seed); short for --set sim.airframe=...",
    )
    hover.add_argument(
        "--scans",
        action="store_true",
        help="ray-cast URG scans in the room through the real scan matcher and hat "
        "(slower) instead of the true pose plus noise",
    )
    hover.add_argument("--height", type=float, metavar="M", help="hover height (default 0.6)")
    hover.add_argument("--log-dir", metavar="DIR", help="flight folder (default: new, dated)")
    hover.add_argument(
        "--excite",
        type=float,
        default=0.0,
        metavar="M",
        help="move the HOLD set-point between +-M m in x and y (random 1.5-3 s dwell): "
        "a response test for 'analyze latency'",
    )
    hover.add_argument("--json", action="store_true", help="one JSON object")
    hover.set_defaults(
        func=command(
            "mkflight.commands.sim_hover:cmd_sim_hover",
            duration_s="duration",
            excite_m="excite",
            seed="seed",
            airframe="airframe",
            scans="scans",
            height_m="height",
            log_dir="log_dir",
            as_json="json",
            **config_args,
        )
    )
    _add_sim_envelope(sim_commands, config_opts, command, config_args)


def _add_sim_envelope(
    sim_commands: Any,
    config_opts: argparse.ArgumentParser,
    command: Callable[..., Runner],
    config_args: dict[str, str],
) -> None:
    """Add ``sim envelope`` (issue 17): the flight judged on N random airframes."""
    envelope = sim_commands.add_parser(
        "envelope",
        parents=[config_opts],
        help="fly N random airframes (hover, laser stall, tuned, oracle) and judge the flight",
        description="For each of N random airframes (seeds S..S+N-1), in parallel processes, "
        "in lock-step: a hover (take-off, hold, land), a second flight with the laser dead "
        "from 10 s into the hold, a third with the config 'mkflight tune' makes from the "
        "first, and the oracle (the same airframe and gusts flown on the true state with "
        "searched gains). Reports truth std, touchdown speeds, ends and failsafes per "
        "airframe, the pass rates, the worst five and summary statistics. Exit 0 when the "
        "criteria hold (precision on >= 95 %, every touchdown <= 0.5 m/s, every stall "
        "landed, the tuned config at least as good on >= 95 %), 1 when not.",
    )
    envelope.add_argument("--n", dest="env_n", type=int, default=50, metavar="N", help="airframes")
    envelope.add_argument(
        "--seed", dest="env_seed", type=int, default=1, metavar="S", help="first airframe seed"
    )
    envelope.add_argument(
        "--jobs", dest="env_jobs", type=int, metavar="J", help="processes (default: CPUs)"
    )
    envelope.add_argument(
        "--hold", dest="env_hold", type=float, default=60.0, metavar="S", help="hold time, s"
    )
    shown = envelope.add_mutually_exclusive_group()
    shown.add_argument("--json", dest="env_json", action="store_true", help="one JSON object")
    shown.add_argument(
        "--markdown", action="store_true", help="the README's table (markdown) instead"
    )
    envelope.add_argument("--plot", dest="env_plot", metavar="DIR", help="write PNG figures here")
    envelope.add_argument(
        "--out", dest="env_out", metavar="DIR", help="keep the flight folders here (default: none)"
    )
    envelope.set_defaults(
        func=command(
            "mkflight.commands.sim_envelope:cmd_sim_envelope",
            n="env_n",
            seed="env_seed",
            jobs="env_jobs",
            hold_s="env_hold",
            as_json="env_json",
            markdown="markdown",
            plot_dir="env_plot",
            out_dir="env_out",
            **config_args,
        )
    )


def add_replay_command(
    commands: Any,
    command: Callable[..., Runner],
    positive: Callable[[str], float],
) -> None:
    """Add ``replay`` (SPEC §6, §7)."""
    replay = commands.add_parser(
        "replay",
        help="replay a recorded flight through mock serial ports into the daemon",
        description="Plays a flight folder's recorded FC and URG bytes (mk.raw, laser.raw) "
        "into the unchanged flight daemon (from memory with --fast, the default; through two "
        "pseudo-terminals with --speed or --ptys), on a lock-step clock "
        "that gives every byte its recorded time, and writes a new flight folder. With the "
        "recorded configuration the ExternControl bytes and both tables must come out "
        "identical (the determinism check: exit 1 and the first difference if not); with "
        "--set it shows what the controller would have sent instead. The scan poses are "
        "the recorded ones unless --set changes the mk, laser or scanmatch sections or "
        "--rematch is given.",
    )
    replay.add_argument("log_dir", metavar="LOGDIR", help="the recorded flight folder")
    pace = replay.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed",
        type=positive,
        metavar="X",
        help="play at X times the recorded pace (1 = real time)",
    )
    pace.add_argument(
        "--fast", action="store_true", help="as fast as the daemon takes it (the default)"
    )
    replay.add_argument(
        "--set",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        dest="overrides",
        help="what if: override a key of the recorded config, e.g. --set control.kp_xy=1.2",
    )
    replay.add_argument(
        "--out", metavar="DIR", help="the new flight folder (default LOGDIR-replay)"
    )
    replay.add_argument(
        "--rematch", action="store_true", help="run the scan matcher again on the replayed scans"
    )
    replay.add_argument(
        "--ptys",
        action="store_true",
        help="play through two pseudo-terminals and the real serial stack even with --fast "
        "(slower; --speed always does)",
    )
    replay.add_argument("--json", action="store_true", help="the report as one JSON object")
    replay.set_defaults(
        func=command(
            "mkflight.commands.replay:cmd_replay",
            log_dir="log_dir",
            speed="speed",
            overrides="overrides",
            out="out",
            rematch="rematch",
            ptys="ptys",
            as_json="json",
        )
    )
