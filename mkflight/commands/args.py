"""The argparse pieces every command group shares: parser class, config options, ports.

Each command module has an ``add_parser(subparsers)`` that adds its group to the tree with
these; :func:`mkflight.cli.build_parser` calls them in turn. A subcommand's ``func`` is a
:class:`Command` of its ``cmd_*`` function: every option's dest is the name of the
parameter it feeds (``--json`` -> ``as_json``, ``--height`` -> ``height_m``), so the
parsed options pass by name and no table maps one onto the other.

Building the tree runs on every ``mkflight`` call, ``--help`` included, so a command module
imports at its top only what its parser needs: the libraries a command runs on (numpy,
scipy, the flight, the simulator) are imported inside its ``cmd_*`` function.
"""

from __future__ import annotations

import argparse
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Literal, NoReturn, TypeAlias

from mkflight import cli_types

if TYPE_CHECKING:
    from mkflight.config_search import ConfigSource

#: Exit code of a usage or configuration error (SPEC §7).
EXIT_USAGE: Final = 2
#: The original system's document, named once in a help page; then only its sections
#: (§L), equations (eq 27), tables (TABLE IX) and figures (Fig 8).
DOCUMENT: Final = "the 2011 QUT CyPhy MikroKopter documentation"


def error_prefix() -> str:
    """The journal's error priority prefix for an ``error:`` line, if stderr is the journal."""
    from mkflight.eventlog import stderr_prefix  # structlog stays off a usage error's path

    return stderr_prefix("error")


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one ``error:`` line and exit 2."""

    def error(self, message: str) -> NoReturn:
        """Print ``error: MESSAGE (see 'PROG --help')`` on stderr and exit 2."""
        print(f"{error_prefix()}error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


#: A group's subcommands, as ``add_subparsers`` of a :class:`Parser` returns them.
Subparsers: TypeAlias = "argparse._SubParsersAction[Parser]"


def subcommands(parser: Parser, dest: str, *, required: bool = True) -> Subparsers:
    """The ``COMMAND`` choice under ``parser``, its name stored as ``dest``."""
    commands = parser.add_subparsers(dest=dest, metavar="COMMAND")
    commands.required = required
    return commands


@dataclass(frozen=True, slots=True)
class Command:
    """A subcommand's ``func``: ``function`` called with the options its parameters name.

    The options of the tree that ``function`` does not take (``--log-level``, a parent
    group's) are left out; a parameter no option feeds is a bug that ``tests/test_cli.py``
    finds for every subcommand.
    """

    function: Callable[..., int]

    def __call__(self, args: argparse.Namespace) -> int:
        """Run the command on the parsed ``args``; its exit code.

        A command of :func:`config_options` gets, as ``config_path``, the file the search
        found (:func:`use_config`), and as ``config_source`` (if it takes one) how.
        """
        names = inspect.signature(self.function).parameters
        given: dict[str, Any] = vars(args)
        kwargs = {k: v for k, v in given.items() if k in names}
        if "config_path" in names:
            source = use_config(given["config_path"], given.get("overrides", []))
            kwargs["config_path"] = source.file
            if "config_source" in names:
                kwargs["config_source"] = source
        return int(self.function(**kwargs))


def use_config(config_path: str | None, overrides: list[str]) -> ConfigSource:
    """Find the config (``--config``, ``$MKFLIGHT_CONFIG``, /etc, defaults), check it, say it.

    The ``config: ...`` line goes to stderr (stdout may be a command's JSON), at the
    journal's info priority, once the config loaded: a bad one is only its error line.

    Raises:
        ConfigError: ``$MKFLIGHT_CONFIG`` names no file, or the config is invalid.
    """
    from mkflight.config_search import load_located, locate_config
    from mkflight.eventlog import stderr_prefix

    source = locate_config(config_path, overrides)
    load_located(source)
    print(f"{stderr_prefix('info')}config: {source.describe()}", file=sys.stderr, flush=True)
    return source


def config_options() -> Parser:
    """``--config`` and ``--set``: the parent parser of every command that reads the config."""
    p = Parser(add_help=False)
    p.add_argument(
        "--config",
        dest="config_path",
        metavar="FILE",
        help="YAML configuration (default: $MKFLIGHT_CONFIG, else /etc/mkflight/config.yaml "
        "if it exists, else the built-in defaults)",
    )
    p.add_argument(
        "--set",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        dest="overrides",
        help="override one key for this run, e.g. --set control.kp_xy=1.2 (repeatable)",
    )
    return p


Device = Literal["mk", "laser"]


@dataclass(frozen=True, slots=True)
class _PortHelp:
    named: str  # --mk-port / --laser-port (default: the config's)
    alone: str  # --port of a command that talks to this device alone
    emulator: str  # --sim of such a command


_PORTS: Final[dict[Device, _PortHelp]] = {
    "mk": _PortHelp(
        named="the FlightCtrl's port (default mk.port)",
        alone="serial device of the FC, e.g. /dev/ttyUSB0",
        emulator="use the built-in FC emulator on a pty",
    ),
    "laser": _PortHelp(
        named="the URG's port (default laser.port)",
        alone="serial device, e.g. /dev/ttyACM0",
        emulator="use the built-in URG emulator on a pty",
    ),
}


def add_ports(parser: argparse.ArgumentParser, *devices: Device) -> None:
    """``--mk-port DEV`` and/or ``--laser-port DEV`` (dests ``mk_port``, ``laser_port``).

    Not given, a port is None: the command takes the config's ``mk.port`` / ``laser.port``.
    """
    for device in devices:
        parser.add_argument(
            f"--{device}-port",
            dest=f"{device}_port",
            metavar="DEV",
            help=_PORTS[device].named,
        )


def add_port_or_sim(parser: argparse.ArgumentParser, device: Device) -> None:
    """``--port DEV`` or ``--sim`` (one of them required): one device, or its emulator."""
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="DEV", help=_PORTS[device].alone)
    where.add_argument("--sim", action="store_true", help=_PORTS[device].emulator)


def add_count(parser: argparse.ArgumentParser, *, default: int, items: str) -> None:
    """``--count N``: how many ``items`` a streaming command prints (0: until Ctrl-C)."""
    parser.add_argument(
        "--count",
        type=cli_types.count,
        default=default,
        metavar="N",
        help=f"{items} to print (0: until Ctrl-C)",
    )


def add_json(parser: argparse.ArgumentParser, what: str = "one JSON object") -> None:
    """``--json`` (dest ``as_json``): print ``what`` instead of text."""
    parser.add_argument("--json", dest="as_json", action="store_true", help=what)


def add_airframe(parser: argparse.ArgumentParser) -> None:
    """``--airframe nominal|random`` of the simulator's commands (:func:`airframe_overrides`)."""
    parser.add_argument(
        "--airframe",
        choices=("nominal", "random"),
        help="the simulated airframe: 'nominal' (sim.vehicle) or 'random' (drawn from the "
        "envelope with sim.seed); short for --set sim.airframe=...",
    )


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
