"""The ``mkflight`` command line: argparse only; each subcommand calls a ``cmd_*() -> int``.

Exit codes (SPEC §7): 0 success, 1 a runtime failure, 2 bad usage or configuration.
Each command group adds its own subcommands (``add_parser`` in its
:mod:`mkflight.commands` module, from the pieces of :mod:`mkflight.commands.args`).
Errors print as one ``error:`` line on stderr, never a traceback (``--debug`` shows it).
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Callable, Sequence

from mkflight import __version__, cli_types
from mkflight.commands import (
    analyze,
    calibrate,
    config_cmd,
    export,
    flight_time,
    flights,
    fly,
    laser_scan,
    mk_info,
    plot,
    replay,
    report,
    scanmatch,
    sim_run,
    tune,
)
from mkflight.commands.args import (
    DOCUMENT,
    EXIT_USAGE,
    Parser,
    Subparsers,
    error_prefix,
    subcommands,
)
from mkflight.errors import ConfigError, MkflightError, PortNotFoundError

EXIT_OK = 0
EXIT_RUNTIME = 1

#: Each command group's ``add_parser``, in the order ``mkflight --help`` lists them.
GROUPS: tuple[Callable[[Subparsers], None], ...] = (
    mk_info.add_parser,
    laser_scan.add_parser,
    scanmatch.add_parser,
    fly.add_parser,
    sim_run.add_parser,
    replay.add_parser,
    calibrate.add_parser,
    flight_time.add_parser,
    plot.add_parser,
    analyze.add_parser,
    tune.add_parser,
    export.add_parser,
    report.add_parser,
    config_cmd.add_parser,
    flights.add_parser,
)


def build_parser() -> argparse.ArgumentParser:
    """The whole command tree: the global options, then each group's ``add_parser``."""
    parser = Parser(
        prog="mkflight",
        description="Onboard flight software for a laser-guided MikroKopter quadrotor. "
        "Section, equation, table and figure numbers (§F, eq 27, TABLE IX, Fig 8) are "
        f"those of {DOCUMENT}.",
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
    commands = subcommands(parser, "command")
    for add_group in GROUPS:
        add_group(commands)
    return parser


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
        print(f"{error_prefix()}error: interrupted", file=sys.stderr)
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
            f"{error_prefix()}error: internal error: {cli_types.printable(repr(err))} "
            "(run with --debug for details)",
            file=sys.stderr,
        )
        return EXIT_RUNTIME
    return code


def _fail(err: BaseException, code: int, debug: bool) -> int:
    if debug:
        traceback.print_exc()
    # The message may quote a log: printable() keeps it one inert line.
    print(f"{error_prefix()}error: {cli_types.printable(str(err))}", file=sys.stderr)
    return code
