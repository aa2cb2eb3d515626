"""Two code trees side by side for the benchmarks: a baseline revision and the tree they run from.

The baseline is a git revision (default :data:`DEFAULT_BASELINE_REV`, the code before the
matcher and the daemon's hot path were reworked) extracted with ``git archive`` into a
temporary folder: no worktree is registered and the repository is not touched. "Current" is
the tree this file lives in, with its uncommitted changes. Both run in subprocesses with
``PYTHONPATH`` set to their own folder (``python -m mkflight``, no console script), so one
bench measures both with the same measuring code, on the same machine, in the same run.

Also here: the import time of the flight path per tree (a fresh interpreter per sample) and
the small pure helpers the tables share (ratios, medians, the machine's load).
"""

from __future__ import annotations

import io
import json
import math
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BASELINE_REV = "25abd71"
# Environment the daemon reads that must not leak from the caller into a measured run.
_SCRUBBED_ENV = ("MKFLIGHT_CONFIG", "NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")
# Modules whose import is timed: the daemon's flight path and the matcher's.
IMPORTED = {"flight": "mkflight.flight.app", "matcher": "mkflight.scanmatch"}
HEAVY = ("scipy", "numpy", "msgspec", "yaml")


class UnknownRevisionError(ValueError):
    """The baseline revision is not in the repository (a usage error)."""


@dataclass(frozen=True)
class Tree:
    """One code tree: a label for the tables, its folder, and the revision it holds."""

    label: str
    path: Path
    revision: str

    def env(self) -> dict[str, str]:
        """The environment of a subprocess that must run this tree's ``mkflight``."""
        env = {k: v for k, v in os.environ.items() if k not in _SCRUBBED_ENV}
        env["PYTHONPATH"] = str(self.path)
        return env


def _git(*args: str) -> str:
    out = subprocess.run(
        ["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def describe_current() -> str:
    """The current tree's revision: ``<short hash> (<describe>)``, plus ``dirty`` if changed."""
    try:
        head = _git("rev-parse", "--short", "HEAD")
        described = _git("describe", "--always", "--tags")
        dirty = bool(_git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return f"{head} ({described})" + (", dirty" if dirty else "")


def describe_revision(rev: str) -> str:
    """A revision as ``<short hash> (<describe>)``."""
    head = _git("rev-parse", "--short", f"{rev}^{{commit}}")
    return f"{head} ({_git('describe', '--always', '--tags', rev)})"


def extract(rev: str, into: Path) -> None:
    """Write the files of ``rev`` into ``into`` (``git archive``; the repository is untouched)."""
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev],
        capture_output=True,
        check=True,
    )
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter="data")


@contextmanager
def baseline_and_current(baseline_rev: str) -> Iterator[tuple[Tree, Tree]]:
    """The baseline revision extracted into a temporary folder, and the current tree.

    Raises:
        UnknownRevisionError: the revision is not in the repository.
    """
    try:
        revision = describe_revision(baseline_rev)
    except subprocess.CalledProcessError as err:
        msg = f"unknown baseline revision {baseline_rev!r}: {err.stderr.strip()}"
        raise UnknownRevisionError(msg) from err
    with tempfile.TemporaryDirectory(prefix="mkflight-baseline-") as tmp:
        extract(baseline_rev, Path(tmp))
        trees = (Tree("baseline", Path(tmp), revision), Tree("current", ROOT, describe_current()))
        for tree in trees:
            compile_tree(tree)
        yield trees


def compile_tree(tree: Tree) -> None:
    """Byte-compile the tree's package, so that no measured run pays for compiling it.

    A freshly extracted baseline has no ``__pycache__``: its first import would compile
    every module and count that as start-up.
    """
    subprocess.run(
        [sys.executable, "-m", "compileall", "-q", "-j", "0", str(tree.path / "mkflight")],
        check=True,
        env=tree.env(),
        capture_output=True,
    )


# ----- pure helpers for the tables ----------------------------------------------------------


def ratio(current: float | None, baseline: float | None) -> float | None:
    """current / baseline; None when either is missing or not finite, or baseline is 0."""
    if current is None or baseline is None:
        return None
    if not (math.isfinite(current) and math.isfinite(baseline)) or baseline == 0:
        return None
    return current / baseline


def median_of(values: Iterable[float | None]) -> float | None:
    """The median of the values that are present and finite (None if none are)."""
    kept = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(kept) if kept else None


def fmt(value: float | None, spec: str = ".2f", width: int = 7) -> str:
    """A number for a text table; ``-`` when it is missing."""
    return f"{'-':>{width}s}" if value is None else f"{value:{width}{spec}}"


def load_average() -> str:
    """``/proc/loadavg``'s 1, 5 and 15 minute figures (``?`` where there is none)."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


# ----- import time --------------------------------------------------------------------------

_IMPORT_PROBE = """
import json, sys, time
t0 = time.perf_counter()
import {module}
dt = time.perf_counter() - t0
print(json.dumps({{"s": dt, "heavy": [m for m in {heavy!r} if m in sys.modules]}}))
"""


def import_once(tree: Tree, module: str) -> dict[str, Any]:
    """Seconds to import ``module`` in a fresh interpreter of ``tree``; heavy modules it pulled."""
    code = _IMPORT_PROBE.format(module=module, heavy=HEAVY)
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env=tree.env(),
        cwd=tree.path,
    )
    out: dict[str, Any] = json.loads(proc.stdout)
    return out


def import_times(trees: tuple[Tree, Tree], repeat: int = 5) -> dict[str, Any]:
    """Median import time of each :data:`IMPORTED` module per tree, A B A B alternated."""
    samples: dict[str, dict[str, list[float]]] = {t.label: {k: [] for k in IMPORTED} for t in trees}
    heavy: dict[str, dict[str, list[str]]] = {t.label: {} for t in trees}
    for _ in range(repeat):
        for name, module in IMPORTED.items():
            for tree in trees:
                got = import_once(tree, module)
                samples[tree.label][name].append(got["s"])
                heavy[tree.label][name] = got["heavy"]
    base, cur = (t.label for t in trees)
    return {
        "repeat": repeat,
        "modules": IMPORTED,
        "median_s": {
            label: {k: median_of(v) for k, v in s.items()} for label, s in samples.items()
        },
        "samples_s": samples,
        "heavy_modules": heavy,
        "ratio": {
            k: ratio(median_of(samples[cur][k]), median_of(samples[base][k])) for k in IMPORTED
        },
    }
