"""The ``mkflight`` command line: argparse only; each subcommand calls a ``cmd_*() -> int``.

Exit codes (SPEC §7): 0 success, 1 a runtime failure, 2 bad usage or configuration.
Errors print as one ``error:`` line on stderr, never a traceback (``--debug`` shows it).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import NoReturn

from mkflight import __version__, cli_types
from mkflight.cli_flight import add_flight_commands, add_replay_command
from mkflight.errors import ConfigError, MkflightError, PortNotFoundError

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_USAGE = 2


def _err() -> str:
    """The journal's error priority prefix for an ``error:`` line, if stderr is the journal."""
    from mkflight.eventlog import stderr_prefix  # structlog stays off a usage error's path

    return stderr_prefix("error")


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one ``error:`` line and exit 2."""

    def error(self, message: str) -> NoReturn:
        print(f"{_err()}error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def _config_options() -> _Parser:
    """``--config`` and ``--set``, shared by every command that uses the configuration."""
    p = _Parser(add_help=False)
    p.add_argument("--config", metavar="FILE", help="YAML configuration (default: built-in)")
    p.add_argument(
        "--set",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        dest="overrides",
        help="override one key for this run, e.g. --set control.kp_xy=1.2 (repeatable)",
    )
    return p


def build_parser() -> argparse.ArgumentParser:
    """The whole command tree."""
    parser = _Parser(
        prog="mkflight",
        description="Onboard flight software for a laser-guided MikroKopter quadrotor.",
    )
    parser.add_argument("--version", action="version", version=f"mkflight {__version__}")
    parser.add_argument(
        "--log-level",
        choices=("debug", "info", "warning"),
        default="warning",
        help="events shown on stderr (default: warning; errors are always one error: line)",
    )
    parser.add_argument(
        "--log-json", action="store_true", help="events as JSON lines even on a terminal"
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    commands.required = True
    config_opts = _config_options()

    mk = commands.add_parser("mk", help="the MikroKopter FlightCtrl link")
    mk_commands = mk.add_subparsers(dest="mk_command", metavar="COMMAND", parser_class=_Parser)
    mk_commands.required = True
    info = mk_commands.add_parser(
        "info",
        parents=[config_opts],
        help="print the FC version and DebugOut samples in SI units",
        description="Connect to a FlightCtrl, print its version, then N DebugOut samples "
        "converted to SI units (SPEC §1). Takes no control: on exit it sends Config = 0.",
    )
    where = info.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="DEV", help="serial device of the FC, e.g. /dev/ttyUSB0")
    where.add_argument("--sim", action="store_true", help="use the built-in FC emulator on a pty")
    info.add_argument(
        "--count",
        type=cli_types.count,
        default=10,
        metavar="N",
        help="samples to print (0: until Ctrl-C)",
    )
    info.add_argument("--json", action="store_true", help="one JSON object per sample and line")
    info.set_defaults(
        func=_command(
            "mkflight.commands.mk_info:cmd_mk_info",
            port="port",
            sim="sim",
            count="count",
            as_json="json",
            **_CONFIG_ARGS,
        )
    )

    laser = commands.add_parser("laser", help="the Hokuyo URG laser")
    laser_commands = laser.add_subparsers(
        dest="laser_command", metavar="COMMAND", parser_class=_Parser
    )
    laser_commands.required = True
    scan = laser_commands.add_parser(
        "scan",
        parents=[config_opts],
        help="print the sensor's identity and scans with the hat's height",
        description="Start the URG (SCIP 2.0), print its identity, then N scans: the scan "
        "steps' ranges and the height from the laser hat (SPEC §7).",
    )
    scan_where = scan.add_mutually_exclusive_group(required=True)
    scan_where.add_argument("--port", metavar="DEV", help="serial device, e.g. /dev/ttyACM0")
    scan_where.add_argument(
        "--sim", action="store_true", help="use the built-in URG emulator on a pty"
    )
    scan.add_argument(
        "--count",
        type=cli_types.count,
        default=5,
        metavar="N",
        help="scans to print (0: until Ctrl-C)",
    )
    scan.add_argument("--json", action="store_true", help="one JSON object per scan and line")
    scan.set_defaults(
        func=_command(
            "mkflight.commands.laser_scan:cmd_laser_scan",
            port="port",
            sim="sim",
            count="count",
            as_json="json",
            **_CONFIG_ARGS,
        )
    )

    match = commands.add_parser(
        "scanmatch",
        parents=[config_opts],
        help="run the scan matcher over a recorded laser log",
        description="Match every scan of a CARMEN log (FLASER/ROBOTLASER1 lines, plain or "
        ".gz) and write 't x y theta' per scan in the log's own frame (SPEC §7).",
    )
    match.add_argument("log", metavar="LOG", help="the laser log")
    match.add_argument(
        "--odom", metavar="FILE", help="'t x y theta' odometry whose increments are the prior"
    )
    match.add_argument("-o", "--output", metavar="TRAJ", help="write here instead of stdout")
    match.set_defaults(
        func=_command(
            "mkflight.commands.scanmatch:cmd_scanmatch",
            log="log",
            odom="odom",
            out="output",
            **_CONFIG_ARGS,
        )
    )

    add_flight_commands(commands, config_opts, _command, _Parser, _CONFIG_ARGS)
    add_replay_command(commands, _command, cli_types.positive)

    calibrate = commands.add_parser("calibrate", help="calibrations from measurements")
    calibrate_commands = calibrate.add_subparsers(
        dest="calibrate_command", metavar="COMMAND", parser_class=_Parser
    )
    calibrate_commands.required = True
    acc = calibrate_commands.add_parser(
        "acc",
        help="fit the accelerometer scale k (counts/g) to a tilt table",
        description="Least-squares fit of counts = -k*sin(angle) (seed §D, eq 7, TABLE I/II) "
        "to rows of 'angle_deg counts' (spaces, tabs or a comma; optional header; # "
        "comments); prints k, the residual RMS and each row's error.",
    )
    acc.add_argument("file", metavar="FILE", help="the table: one 'angle_deg counts' row a line")
    acc.add_argument(
        "--axis",
        choices=("nick", "roll"),
        default="nick",
        help="nick (pitch, TABLE I) or roll (TABLE II): the config key to write (default nick)",
    )
    acc.add_argument("--json", action="store_true", help="one JSON object")
    acc.add_argument(
        "--write-config",
        metavar="F",
        help="set mk.acc_<axis>_counts_per_g in the YAML file F (comments are not kept)",
    )
    acc.set_defaults(
        func=_command(
            "mkflight.commands.calibrate:cmd_calibrate_acc",
            file="file",
            axis="axis",
            as_json="json",
            write_config="write_config",
        )
    )

    flight = commands.add_parser(
        "flight-time",
        help="flight time from battery capacity and current (eq 27)",
        description="t = B / C (seed §L, eq 27): the ideal time, the time derated by "
        "--usable, and the thrust each of the 4 motors gives to hover --mass-g.",
    )
    flight.add_argument(
        "--capacity-ah",
        type=cli_types.positive,
        required=True,
        metavar="C",
        help="battery capacity, Ah",
    )
    flight.add_argument(
        "--current-a",
        type=cli_types.positive,
        required=True,
        metavar="I",
        help="motors' current, A",
    )
    flight.add_argument(
        "--usable",
        type=cli_types.fraction,
        default=0.9,
        metavar="F",
        help="derating factor in (0, 1] (default 0.9, the seed's)",
    )
    flight.add_argument(
        "--extra-current-a",
        type=cli_types.non_negative,
        default=0.0,
        metavar="A",
        help="other electronics' current, added to I (the seed: 0.5)",
    )
    flight.add_argument(
        "--mass-g", type=cli_types.positive, metavar="M", help="take-off mass, g: thrust per motor"
    )
    flight.add_argument("--json", action="store_true", help="one JSON object")
    flight.set_defaults(
        func=_command(
            "mkflight.commands.flight_time:cmd_flight_time",
            capacity_ah="capacity_ah",
            current_a="current_a",
            usable="usable",
            mass_g="mass_g",
            extra_current_a="extra_current_a",
            as_json="json",
        )
    )

    plot = commands.add_parser(
        "plot",
        help="draw a flight folder's figures as PNG files (needs the plot extra)",
        description="PNG figures of one flight folder (seed §O-P, Fig 18/19): trajectory "
        "x-y, position and height with set-points, laser vs filtered velocity, commands and "
        "sticks, battery. Prints the paths. Needs matplotlib: pip install 'mkflight[plot]'.",
    )
    plot.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    plot.add_argument(
        "-o", "--out-dir", metavar="DIR", help="where the PNGs go (default: LOGDIR/plots)"
    )
    plot.set_defaults(
        func=_command("mkflight.commands.plot:cmd_plot", log_dir="log_dir", out_dir="out_dir")
    )

    analyze = commands.add_parser("analyze", help="the seed's analyses of a flight folder")
    analyze_commands = analyze.add_subparsers(
        dest="analyze_command", metavar="COMMAND", parser_class=_Parser
    )
    analyze_commands.required = True
    precision = analyze_commands.add_parser(
        "precision",
        help="hover precision (mean, std, RMS, max error) beside the seed's TABLE IX",
        description="Mean, std, RMS and max of the x, y and height error about the set-point "
        "during HOLD (from 3 s after HOLD begins, as 'sim hover' measures), against the "
        "flight's estimate or a 't x y z' truth file (seed §O-P, TABLE IX).",
    )
    precision.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    precision.add_argument(
        "--truth", metavar="FILE", help="'t x y z' ground truth (z = height up), e.g. truth.txt"
    )
    precision.add_argument("--json", action="store_true", help="one JSON object")
    precision.set_defaults(
        func=_command(
            "mkflight.commands.analyze:cmd_analyze_precision",
            log_dir="log_dir",
            truth="truth",
            as_json="json",
        )
    )
    latency = analyze_commands.add_parser(
        "latency",
        help="the vehicle's response lag by cross-correlation (seed §F, Fig 8)",
        description="Normalised cross-correlation of the commanded pitch (roll) with the "
        "laser's body-frame acceleration along x (y), i.e. the body velocity differenced, for "
        "lags 0..20 steps: the peak is the response lag (delay + lag of the attitude loop). "
        "Also the FC's own angles against the command, and the seed's Fig 8 curve (command "
        "against velocity, which adds the integration). Needs excitation: a calm hover "
        "barely moves ('sim hover --excite 0.2').",
    )
    latency.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    latency.add_argument("--json", action="store_true", help="one JSON object")
    latency.set_defaults(
        func=_command(
            "mkflight.commands.analyze:cmd_analyze_latency", log_dir="log_dir", as_json="json"
        )
    )

    tune = commands.add_parser(
        "tune",
        parents=[config_opts],
        help="identify a flight's airframe and write a config tuned for it",
        description="From the HOLD phase of a flight folder: the attitude response per axis "
        "(delay + first-order lag and gain, seed §F), the hover gas, the accelerometers' "
        "vibration and biases; then the overrides of the base config (--config, --set) for "
        "that airframe by a documented rule (mkflight.analysis.tune).",
    )
    tune.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    tune.add_argument(
        "--write-config",
        metavar="F",
        help="write the tuned configuration (all keys) to the new file F; an existing F is "
        "refused unless it is the --config file itself",
    )
    tune.add_argument("--json", action="store_true", help="one JSON object")
    tune.set_defaults(
        func=_command(
            "mkflight.commands.tune:cmd_tune",
            log_dir="log_dir",
            write_config="write_config",
            as_json="json",
            **_CONFIG_ARGS,
        )
    )
    return parser


#: The options every config-using command passes on: cmd parameter -> argparse dest.
_CONFIG_ARGS = {"config_path": "config", "overrides": "overrides"}


def _command(target: str, **params: str) -> Callable[[argparse.Namespace], int]:
    """A subcommand's runner: import ``module:cmd_function`` lazily, pass it its options.

    ``params`` maps each keyword parameter of the ``cmd_*`` function to the argparse
    destination it takes its value from. The import happens only when the command runs,
    so ``mkflight --help`` and the light commands never load numpy, scipy or matplotlib.
    """
    module_name, function_name = target.split(":")

    def run(args: argparse.Namespace) -> int:
        function = getattr(importlib.import_module(module_name), function_name)
        code = function(**{param: getattr(args, dest) for param, dest in params.items()})
        return int(code)

    return run


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return exit_.code if isinstance(exit_.code, int) else EXIT_USAGE
    from mkflight.eventlog import configure_events

    configure_events(level=args.log_level, json_lines=True if args.log_json else None)
    try:
        code: int = args.func(args)
    except (ConfigError, PortNotFoundError) as err:
        return _fail(err, EXIT_USAGE, args.debug)
    except MkflightError as err:
        return _fail(err, EXIT_RUNTIME, args.debug)
    except KeyboardInterrupt:
        print(f"{_err()}error: interrupted", file=sys.stderr)
        return EXIT_RUNTIME
    except BrokenPipeError:
        # The reader of our stdout went away (e.g. `| head`): not an error of ours.
        # Point stdout at /dev/null so that the interpreter's final flush stays quiet.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except Exception as err:  # a bug: still one line, the traceback on request
        if args.debug:
            traceback.print_exc()
        print(
            f"{_err()}error: internal error: {cli_types.printable(repr(err))} "
            "(run with --debug for details)",
            file=sys.stderr,
        )
        return EXIT_RUNTIME
    return code


def _fail(err: BaseException, code: int, debug: bool) -> int:
    if debug:
        traceback.print_exc()
    print(f"{_err()}error: {cli_types.printable(str(err))}", file=sys.stderr)  # may quote a log
    return code
