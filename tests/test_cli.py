"""The command tree: every option feeds its command, the help text, a light parser.

The commands themselves are tested by what they do (``tests/integration/test_cli_*``,
``tests/analysis``, ``tests/scanmatch``, ``tests/sim``); here the tree that
:func:`mkflight.cli.build_parser` assembles from each group's ``add_parser``.
"""

from __future__ import annotations

import argparse
import asyncio
import inspect
import re
import subprocess
import sys
from collections.abc import Iterator
from typing import Final

import pytest

from mkflight.cli import build_parser
from mkflight.commands.args import Command
from mkflight.commands.streaming import print_lines

#: Options that feed no parameter, on purpose: ``replay --fast`` names the default pace.
FEED_NOTHING: Final[dict[tuple[str, ...], set[str]]] = {("replay",): {"fast"}}
#: What the commands run on, and building the parser must not import (a cost on every call).
HEAVY: Final = (
    *("numpy", "scipy", "matplotlib", "msgspec", "yaml", "structlog", "asyncio"),
    *("mkflight.flight", "mkflight.sim", "mkflight.replay", "mkflight.scanmatch"),
    *("mkflight.io", "mkflight.mk", "mkflight.urg", "mkflight.logs", "mkflight.config"),
)
#: What naming the original document as "the seed" looks like.
SEED_WORDING: Final = re.compile(r"\bthe seed\b|\bseed's|\bseed §|\bseed TABLE|\bseed eq")


def _parsers(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def _commands() -> list[tuple[tuple[str, ...], argparse.ArgumentParser, Command]]:
    out = []
    for path, parser in _parsers(build_parser()):
        func = parser.get_default("func")
        if func is not None:
            assert isinstance(func, Command), path
            out.append((path, parser, func))
    return out


def test_every_command_of_the_tree_is_there() -> None:
    paths = {" ".join(path) for path, _, _ in _commands()}
    assert paths == {
        "mk info",
        "laser scan",
        "scanmatch",
        "fly",
        "sim",
        "sim hover",
        "sim envelope",
        "replay",
        "calibrate acc",
        "flight-time",
        "plot",
        "analyze precision",
        "analyze latency",
        "tune",
        "export",
        "report",
        "config show",
        "config check",
        "mk release",
        "flights",
    }


@pytest.mark.parametrize(
    ("path", "parser", "command"),
    _commands(),
    ids=lambda v: " ".join(v) if isinstance(v, tuple) else "",
)
def test_each_option_feeds_the_parameter_of_its_name(
    path: tuple[str, ...], parser: argparse.ArgumentParser, command: Command
) -> None:
    """Every parameter has its option (dest = name); every option has its parameter."""
    dests = {
        a.dest
        for a in parser._actions
        if not isinstance(a, argparse._HelpAction | argparse._SubParsersAction)
    }
    parameters = set(inspect.signature(command.function).parameters)
    if "config_path" in dests:  # --config also feeds how the file was found (Command)
        dests.add("config_source")
        parameters.add("config_source")
    assert parameters - dests == set(), f"{path}: parameters no option feeds"
    assert dests - parameters == FEED_NOTHING.get(path, set()), f"{path}: options fed nowhere"


def test_a_subcommand_takes_its_own_options_not_its_groups() -> None:
    """``sim --seed 3 hover``: the hover's own ``--seed`` (unset), not the live sim's."""
    args = build_parser().parse_args(["sim", "--seed", "3", "--duration", "7", "hover"])
    assert args.func.function.__name__ == "cmd_sim_hover"
    assert args.seed is None
    assert args.duration_s == 60.0


def test_help_names_the_document_never_the_seed() -> None:
    for path, parser in _parsers(build_parser()):
        text = parser.format_help()
        assert not SEED_WORDING.search(text), f"{' '.join(path)}: {SEED_WORDING.search(text)}"
    top = build_parser().format_help()
    assert "the 2011 QUT CyPhy MikroKopter documentation" in " ".join(top.split())


def test_building_the_parser_loads_no_command_library() -> None:
    """``mkflight --help`` and the light commands do not import what the heavy ones run on."""
    code = (
        "import sys\n"
        "from mkflight.cli import build_parser\n"
        "build_parser()\n"
        f"print(' '.join(m for m in sorted(sys.modules) if m.split('.')[0] in {HEAVY!r}\n"
        f"    or '.'.join(m.split('.')[:2]) in {HEAVY!r}))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.split() == []


def test_print_lines_stops_at_the_count_and_on_stop(capsys: pytest.CaptureFixture[str]) -> None:
    async def run(count: int, stop_after: int | None) -> None:
        stop = asyncio.Event()
        n = 0

        async def next_line() -> str:
            nonlocal n
            n += 1
            if n == stop_after:
                stop.set()
                await asyncio.Event().wait()  # never set: cancelled by the stop
            return f"line {n}"

        await print_lines(next_line, count, stop)

    asyncio.run(run(3, None))
    assert capsys.readouterr().out.splitlines() == ["line 1", "line 2", "line 3"]
    asyncio.run(run(0, 3))
    assert capsys.readouterr().out.splitlines() == ["line 1", "line 2"]
