"""The flight runs on monotonic clocks: a wall-clock step (NTP, an RTC set late) cannot
touch it (issue 18).

Two halves. Here, statically: every read of the wall clock in ``mkflight/`` (``time.time``,
``time.time_ns``, ``datetime.now`` and the like, structlog's ``TimeStamper``) is one of
the named stamp sites below, which only label things (a folder name, ``flight.json``'s
start, a raw recording's header, log lines); a new one fails until it is looked at and
named. In flight: the campaign's ``wall-clock-jump`` row steps the daemon's wall clock an
hour ahead 2 s into the hold (:func:`tests.faults.inject.shift_wall_clock`) and checks
that the flight runs as the baseline's (its ``--duration`` stop on time on the monotonic
clock, no failsafe) while its log lines' stamps jump by the hour. The static half covers
what the dynamic one cannot reach (a ``from time import time`` bound before the step, a
C extension); the dynamic half, what a name scan cannot see (a library's clock).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path
from typing import Final

from tests.faults.campaign import REPO

WALL_CLOCK: Final = {
    ("time", "time"),
    ("time", "time_ns"),
    ("time", "localtime"),
    ("time", "gmtime"),
    ("time", "ctime"),
    ("time", "asctime"),
    ("time", "strftime"),
    ("time", "CLOCK_REALTIME"),
    ("datetime", "now"),
    ("datetime", "utcnow"),
    ("datetime", "today"),
    ("date", "today"),
    ("processors", "TimeStamper"),
}
"""(the name before the dot, the attribute) of every wall-clock read we look for."""

STAMP_SITES: Final = {
    ("mkflight/commands/tune.py", "cmd_tune"): "the tuned config's header date",
    ("mkflight/eventlog.py", "configure_events"): "log lines' timestamps (labels)",
    ("mkflight/flight/flight_logs.py", "FlightLogs.__init__"): "flight.json start_utc",
    ("mkflight/logs/folders.py", "create_flight_folder"): "a flight folder's name (fly, sim)",
    ("mkflight/logs/raw.py", "RawRecorder.__init__"): "a raw recording header's start",
    ("mkflight/sim/hover_flight.py", "FlightSide.__init__"): "sim hover's flight.json start",
}
"""Where ``mkflight`` may read the wall clock: (file, enclosing function) -> what it stamps."""


class _WallClockReads(ast.NodeVisitor):
    """Collects (enclosing qualified function name, line) of each wall-clock read."""

    def __init__(self) -> None:
        self.scope: list[str] = []
        self.found: list[tuple[str, int, str]] = []

    def _scoped(self, node: ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        self.scope.append(node.name)
        self.generic_visit(node)
        self.scope.pop()

    visit_ClassDef = visit_FunctionDef = visit_AsyncFunctionDef = _scoped

    def visit_Attribute(self, node: ast.Attribute) -> None:
        base = node.value
        name = base.id if isinstance(base, ast.Name) else getattr(base, "attr", None)
        if (name, node.attr) in WALL_CLOCK:
            self.found.append(
                (".".join(self.scope) or "<module>", node.lineno, f"{name}.{node.attr}")
            )
        self.generic_visit(node)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        for alias in node.names:
            if (node.module, alias.name) in WALL_CLOCK:
                where = ".".join(self.scope) or "<module>"
                self.found.append((where, node.lineno, f"from {node.module} import {alias.name}"))


def wall_clock_reads(root: Path) -> dict[tuple[str, str], list[str]]:
    """Every wall-clock read under ``root/mkflight``: (file, function) -> ``line: what``."""
    reads: dict[tuple[str, str], list[str]] = {}
    for path in sorted((root / "mkflight").rglob("*.py")):
        finder = _WallClockReads()
        finder.visit(ast.parse(path.read_text(encoding="utf-8"), str(path)))
        for scope, line, what in finder.found:
            key = (path.relative_to(root).as_posix(), scope)
            reads.setdefault(key, []).append(f"{line}: {what}")
    return reads


def test_the_flight_code_reads_the_wall_clock_only_to_stamp_things() -> None:
    reads = wall_clock_reads(REPO)
    unnamed = {k: v for k, v in reads.items() if k not in STAMP_SITES}
    assert not unnamed, (
        f"wall-clock reads outside the stamp sites (use a monotonic clock): {unnamed}"
    )
    gone = set(STAMP_SITES) - set(reads)
    assert not gone, f"stamp sites that no longer read the wall clock (drop them): {gone}"


def test_the_scan_finds_each_way_of_reading_the_wall_clock(tmp_path: Path) -> None:
    """The scan itself: attribute reads, a function passed as a value, ``from`` imports."""
    src = tmp_path / "mkflight" / "x.py"
    src.parent.mkdir()
    src.write_text(
        "import time\nfrom time import time_ns\nfrom datetime import datetime\n"
        "class A:\n    def f(self, clock=time.time):\n        return datetime.now()\n"
        "def g():\n    return time.monotonic() + time.perf_counter()\n",
        encoding="utf-8",
    )
    assert wall_clock_reads(tmp_path) == {
        ("mkflight/x.py", "<module>"): ["2: from time import time_ns"],
        ("mkflight/x.py", "A.f"): ["5: time.time", "6: datetime.now"],
    }


PROBE: Final = """
import datetime, json, time
import structlog
import mkflight.flight.flight_logs as flight_logs
from tests.faults.inject import shift_wall_clock

stamp = structlog.processors.TimeStamper(fmt="iso", utc=True)
def read():
    return {
        "time": time.time(),
        "time_ns": time.time_ns() / 1e9,
        "now": datetime.datetime.now(datetime.UTC).timestamp(),
        "utcnow": datetime.datetime.utcnow().replace(tzinfo=datetime.UTC).timestamp(),
        "flight_logs": flight_logs.datetime.now(datetime.UTC).timestamp(),
        "structlog": datetime.datetime.fromisoformat(
            stamp(None, "", {})["timestamp"].replace("Z", "+00:00")).timestamp(),
        "monotonic": time.monotonic(),
    }
before = read()
shift_wall_clock(3600.0)
after = read()
print(json.dumps({k: after[k] - before[k] for k in before}))
"""


def test_the_wall_clock_step_reaches_every_python_reader() -> None:
    """:func:`~tests.faults.inject.shift_wall_clock` (in a process of its own: it cannot be
    undone): time.time, time_ns, datetime.now and utcnow, a module's imported datetime and
    structlog's stamps all read an hour later; the monotonic clock does not move."""
    proc = subprocess.run(
        [sys.executable, "-c", PROBE],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    steps = json.loads(proc.stdout)
    assert steps.pop("monotonic") < 1.0
    for name, step_s in steps.items():
        assert 3599.0 < step_s < 3601.0, (name, step_s)
