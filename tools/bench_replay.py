"""Replay speed (SPEC §9: fast mode ≥ 200x real time): a recorded flight, played back.

The source is a flight folder (``--replay-source DIR``) or, by default, a new simulated
flight of ``--replay-duration`` s flown for the purpose (``fly --hover --sim``, real time;
the folder is kept under ``.benchmarks/replay-source-<S>s`` and reused by later runs).
Each variant replays it ``--replay-runs`` times through ``mkflight replay`` in-process
(:func:`mkflight.replay.run.replay_flight`); reported per variant: the median wall time,
the speed-up (recorded seconds per wall second), CPU per recorded second and per step,
and whether the determinism check passed:

* ``fast``: lock-step, as fast as the daemon takes it, the recorded scan poses, the
  recorded bytes straight into the daemon's streams (memory ports, ``--fast``);
* ``fast, ptys`` (the baseline of the same run): the same through two pseudo-terminals
  and the real serial stack (``--ptys``: how ``--fast`` played before memory ports);
* ``fast, rematch``: memory ports with the scan matcher run again on every replayed scan
  (what a ``--set scanmatch.*`` replay costs).
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from mkflight.replay.run import replay_flight

CACHE = Path(".benchmarks")


def record(duration_s: float) -> Path:
    """A simulated flight of ``duration_s`` (cached: reused if a complete one is there)."""
    folder = CACHE / f"replay-source-{duration_s:g}s"
    if (folder / "flight.json").exists() and "summary" in (folder / "flight.json").read_text():
        return folder
    if folder.exists():
        for p in folder.iterdir():
            p.unlink()
    CACHE.mkdir(exist_ok=True)
    cmd = [sys.executable, "-m", "mkflight", "fly", "--hover", "--sim"]
    cmd += ["--duration", f"{duration_s:g}", "--log-dir", str(folder), "--json"]
    subprocess.run(cmd, check=True, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    return folder


def _one(source: Path, rematch: bool, ptys: bool) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        r = replay_flight(source, Path(tmp) / "r", rematch=rematch, ptys=ptys)
    return {
        "wall_s": r.wall_s,
        "cpu_s": r.cpu_s,
        "recorded_s": r.recorded_s,
        "steps": r.commands.n_replayed,
        "deterministic": r.deterministic,
    }


def run(source: Path | None, duration_s: float, runs: int) -> dict[str, Any]:
    """Replay ``source`` (or a new flight) ``runs`` times per variant, alternating."""
    folder = source if source is not None else record(duration_s)
    variants = {
        "fast": (False, False),
        "fast, ptys (baseline)": (False, True),
        "fast, rematch": (True, False),
    }
    samples: dict[str, list[dict[str, Any]]] = {name: [] for name in variants}
    for _ in range(runs):  # A B C A B C: drift hits all alike
        for name, (rematch, ptys) in variants.items():
            samples[name].append(_one(folder, rematch, ptys))
    out: dict[str, Any] = {"source": str(folder)}
    for name, rs in samples.items():
        wall = statistics.median(r["wall_s"] for r in rs)
        cpu = statistics.median(r["cpu_s"] for r in rs)
        recorded = rs[0]["recorded_s"]
        out[name] = {
            "recorded_s": recorded,
            "wall_s_median": wall,
            "speedup_median": recorded / wall,
            "cpu_ms_per_recorded_s": 1000 * cpu / recorded,
            "cpu_ms_per_step": 1000 * cpu / max(1, rs[0]["steps"]),
            "runs": len(rs),
            "deterministic": all(r["deterministic"] for r in rs),
        }
    base = out["fast, ptys (baseline)"]["wall_s_median"]
    out["ratio_fast_over_baseline"] = out["fast"]["wall_s_median"] / base
    return out
