"""The daemon in flight (SPEC §9): whole simulated flights, two variants alternated in pairs.

Each flight is one ``python -m mkflight fly --hover --sim --duration D --json`` run (the
simulator in its own process on ptys, the daemon exactly as on hardware) in a subprocess
whose ``PYTHONPATH`` is its variant's code tree (:mod:`bench_trees`). A variant is a tree
plus ``--set`` options: by default the baseline revision against the current tree, each
with its own default configuration (``--worker`` may set ``scanmatch.worker`` for both);
``--flight-compare workers`` instead flies the current tree with the matcher in its worker
process against the same tree with the matcher inline. The flights alternate in pairs
(A B, B A, A B, ...) so that the machine's drift hits both alike; each figure is the
median over a variant's flights, and the ratio is second variant / first.

From each flight's ``flight.json`` summary and ``events.jsonl``:

* CPU in HOLD, % of one core: the daemon process as ``flight.json`` reports it
  (``cpu_percent_in_hold.daemon``; with the matcher inline it includes the matcher), the
  matcher's compute, the daemon without the matcher and the two together;
* CPU per step: the daemon's own CPU in HOLD (the matcher's taken out) over the steps in
  HOLD (``step`` events in phase HOLD); CPU per scan: the matcher's CPU in HOLD over the
  scans whose result came back in HOLD (``scan`` events' ``got_ns``);
* latency DebugOut arrival -> ExternControl written, median and p99; missed steps;
* hover precision against the simulator's truth (std x, y, z in HOLD);
* start-up: from spawning ``fly`` to the ``ready`` event (both on CLOCK_MONOTONIC: the
  daemon's flight clock outside replay is ``time.monotonic_ns``), which covers the
  imports, the simulator's start, the matcher worker's warm-up and the pre-flight;
* the whole run's CPU of the process tree (daemon, simulator, worker: the children's
  rusage), as % of one core over the run's wall time: a cross-check that counts what the
  daemon's own figures cannot see (the worker's pickling, the simulator).

The live view's cost (:func:`run_live`, ``tools/bench.py --only flight --live``): the
current tree's flight with ``--live`` off and on, alternated in pairs (off-on, on-off,
...). While ``--live`` is on, a WebSocket client in this process subscribes to every topic
and reads every message (without a subscriber the SDK would build and send nothing).
Reported: command latency median and p99 per flight, their medians over the flights of
each variant, the ratios on/off and the p99 added.
"""

from __future__ import annotations

import asyncio
import json
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench_trees import ROOT, Tree, describe_current, fmt, median_of, ratio

NS_PER_S = 1_000_000_000
# A start-up outside these bounds is not one: the clocks disagree (reported as missing).
DAEMON_TARGET_PERCENT = 3.0  # the daemon's budget in HOLD on this machine
MIN_STARTUP_S = 0.01  # an interpreter alone takes longer
MAX_STARTUP_S = 300.0


@dataclass(frozen=True)
class Variant:
    """One side of the comparison: a code tree and the ``--set`` options it flies with."""

    label: str
    tree: Tree
    settings: tuple[str, ...] = ()


def fly(
    tree: Tree,
    duration_s: float,
    folder: Path,
    settings: tuple[str, ...] = (),
    extra: tuple[str, ...] = (),
) -> dict[str, Any]:
    """One simulated flight of ``tree`` into ``folder``: its summary and the bench's clocks.

    Returns ``summary`` (the ``--json`` object; None if the command printed none),
    ``exit_code``, ``stderr_tail``, ``spawn_ns`` (CLOCK_MONOTONIC at spawn), ``wall_s`` and
    ``tree_cpu_s`` (user + system CPU of the command and its waited-for children).
    """
    cmd = [sys.executable, "-m", "mkflight", "fly", "--hover", "--sim"]
    cmd += ["--duration", f"{duration_s:g}", "--log-dir", str(folder), "--json", *extra]
    for setting in settings:
        cmd += ["--set", setting]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    spawn_ns = time.monotonic_ns()
    t0 = time.perf_counter()
    proc = subprocess.run(
        cmd,
        capture_output=True,
        text=True,
        check=False,
        stdin=subprocess.DEVNULL,
        env=tree.env(),
        cwd=tree.path,
    )
    wall_s = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        summary: dict[str, Any] | None = json.loads(proc.stdout)
    except json.JSONDecodeError:
        summary = None
    return {
        "summary": summary,
        "exit_code": proc.returncode,
        "stderr_tail": proc.stderr.strip()[-500:],
        "spawn_ns": spawn_ns,
        "wall_s": wall_s,
        "tree_cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
    }


def read_events(folder: Path) -> list[dict[str, Any]]:
    """The flight's ``events.jsonl`` records (empty when there is none)."""
    path = folder / "events.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def hold_counts(events: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Steps in HOLD, scans whose result came back in HOLD, and the READY/pre-flight times.

    HOLD is the daemon's CPU window: from the first step in phase HOLD to the first step
    after it in another phase (or the last event).
    """
    steps = scans = 0
    start_ns: int | None = None
    end_ns: int | None = None
    ready_ns: int | None = None
    preflight_ns: int | None = None
    got: list[int] = []
    for e in events:
        kind = e.get("event")
        if kind == "ready" and ready_ns is None:
            ready_ns = e["t_ns"]
        elif kind == "preflight" and preflight_ns is None:
            preflight_ns = e["t_ns"]
        elif kind == "scan" and e.get("got_ns") is not None:
            got.append(e["got_ns"])
        elif kind == "step" and end_ns is None:
            if e.get("phase") == "HOLD":
                start_ns = e["t_ns"] if start_ns is None else start_ns
                steps += 1
            elif start_ns is not None:
                end_ns = e["t_ns"]
    if start_ns is not None:
        stop = end_ns if end_ns is not None else max(got, default=start_ns) + 1
        scans = sum(start_ns <= g < stop for g in got)
    return {
        "steps_in_hold": steps,
        "scans_in_hold": scans,
        "ready_ns": ready_ns,
        "preflight_ns": preflight_ns,
    }


def _since_spawn_s(t_ns: int | None, spawn_ns: int) -> float | None:
    if t_ns is None:
        return None
    dt_s = (t_ns - spawn_ns) / NS_PER_S
    return dt_s if MIN_STARTUP_S < dt_s < MAX_STARTUP_S else None


def _hold_cpu(
    summary: dict[str, Any], worker: str | None, counts: dict[str, Any]
) -> dict[str, Any]:
    """CPU in HOLD: % of one core, per step and per scan (module docstring)."""
    hold = summary.get("cpu_percent_in_hold") or {}
    daemon, matcher, hold_s = hold.get("daemon"), hold.get("matcher"), hold.get("hold_s")
    if daemon is None or matcher is None or not hold_s:
        return {"daemon_percent": daemon, "matcher_percent": matcher, "hold_s": hold_s}
    inline = worker == "inline"
    own = daemon - matcher if inline else daemon
    steps, scans = counts["steps_in_hold"], counts["scans_in_hold"]
    return {
        "daemon_percent": daemon,
        "matcher_percent": matcher,
        "daemon_without_matcher_percent": own,
        "daemon_with_matcher_percent": daemon if inline else daemon + matcher,
        "hold_s": hold_s,
        "cpu_us_per_step": own / 100 * hold_s / steps * 1e6 if steps else None,
        "matcher_cpu_ms_per_scan": matcher / 100 * hold_s / scans * 1e3 if scans else None,
    }


def flight_figures(
    run: dict[str, Any], config: dict[str, Any], events: list[dict[str, Any]]
) -> dict[str, Any]:
    """One flight's figures from :func:`fly`'s result, ``flight.json``'s config and events."""
    s = run["summary"]
    if s is None:
        return {"error": f"no summary (exit {run['exit_code']}): {run['stderr_tail']}"}
    worker = config.get("scanmatch", {}).get("worker")
    counts = hold_counts(events)
    t = s["timing"]
    truth = s.get("truth_precision") or {}
    return {
        "exit_code": run["exit_code"],
        "end_reason": s.get("end_reason"),
        "worker": worker,
        **_hold_cpu(s, worker, counts),
        "steps_in_hold": counts["steps_in_hold"],
        "scans_in_hold": counts["scans_in_hold"],
        "matcher_cpu_ms_per_scan_flight": (s.get("matcher") or {}).get("cpu_ms_per_scan"),
        "latency_median_ms": t["latency_median_ms"],
        "latency_p99_ms": t["latency_p99_ms"],
        "latency_max_ms": t["latency_max_ms"],
        "added_jitter_p99_ms": t.get("added_jitter_p99_ms"),
        "missed_steps": t["missed_steps"],
        "overruns": t.get("overruns"),
        "steps": t["steps"],
        "cpu_percent_main": s.get("cpu_percent_of_one_core"),
        "truth_std_x_mm": _mm(truth.get("std_x_m")),
        "truth_std_y_mm": _mm(truth.get("std_y_m")),
        "truth_std_z_mm": _mm(truth.get("std_z_m")),
        "startup_s": _since_spawn_s(counts["ready_ns"], run["spawn_ns"]),
        "spawn_to_preflight_s": _since_spawn_s(counts["preflight_ns"], run["spawn_ns"]),
        "wall_s": run["wall_s"],
        "tree_cpu_percent": 100 * run["tree_cpu_s"] / run["wall_s"] if run["wall_s"] else None,
    }


def _mm(value_m: float | None) -> float | None:
    return None if value_m is None else 1000 * value_m


def fly_variant(variant: Variant, duration_s: float, folder: Path) -> dict[str, Any]:
    """One flight of ``variant``: :func:`flight_figures`."""
    run = fly(variant.tree, duration_s, folder, variant.settings)
    config: dict[str, Any] = {}
    if (folder / "flight.json").exists():
        config = json.loads((folder / "flight.json").read_text()).get("config", {})
    return flight_figures(run, config, read_events(folder))


# (key, label, format) of the comparison table, in its order.
METRICS: tuple[tuple[str, str, str], ...] = (
    ("daemon_percent", "CPU in HOLD, daemon (flight.json) %", ".2f"),
    ("matcher_percent", "CPU in HOLD, matcher %", ".2f"),
    ("daemon_without_matcher_percent", "CPU in HOLD, daemon without matcher %", ".2f"),
    ("daemon_with_matcher_percent", "CPU in HOLD, daemon + matcher %", ".2f"),
    ("cpu_us_per_step", "CPU per step, daemon without matcher, us", ".0f"),
    ("matcher_cpu_ms_per_scan", "CPU per scan, matcher, ms (HOLD)", ".3f"),
    ("latency_median_ms", "latency median, ms", ".3f"),
    ("latency_p99_ms", "latency p99, ms", ".3f"),
    ("missed_steps", "missed steps", ".1f"),
    ("truth_std_x_mm", "hover std x vs truth, mm", ".2f"),
    ("truth_std_y_mm", "hover std y vs truth, mm", ".2f"),
    ("truth_std_z_mm", "hover std z vs truth, mm", ".2f"),
    ("startup_s", "start-up, fly -> READY, s", ".3f"),
    ("tree_cpu_percent", "whole run, process tree CPU % (incl. sim)", ".2f"),
)


def medians(flights: list[dict[str, Any]]) -> dict[str, float | None]:
    """The median of every :data:`METRICS` figure over the flights that have it."""
    ok = [f for f in flights if "error" not in f]
    return {key: median_of(f.get(key) for f in ok) for key, _, _ in METRICS}


def run_pairs(variants: tuple[Variant, Variant], pairs: int, duration_s: float) -> dict[str, Any]:
    """``pairs`` pairs of flights of the two variants, A B, B A, ... (module docstring)."""
    flights: dict[str, list[dict[str, Any]]] = {v.label: [] for v in variants}
    with tempfile.TemporaryDirectory(prefix="mkflight-bench-") as tmp:
        for k in range(pairs):
            order = variants if k % 2 == 0 else variants[::-1]
            for v in order:
                folder = Path(tmp) / f"{v.label}-{k}"
                flights[v.label].append(fly_variant(v, duration_s, folder))
    med = {label: medians(fs) for label, fs in flights.items()}
    a, b = (med[v.label] for v in variants)
    return {
        "duration_s": duration_s,
        "pairs": pairs,
        "variants": {
            v.label: {
                "tree": str(v.tree.path),
                "revision": v.tree.revision,
                "settings": list(v.settings),
                "workers": sorted({str(f.get("worker")) for f in flights[v.label]}),
            }
            for v in variants
        },
        "flights": flights,
        "medians": med,
        "ratio": {key: ratio(b[key], a[key]) for key, _, _ in METRICS},
    }


def format_table(result: dict[str, Any]) -> str:
    """The comparison as text: one row per figure, both medians and their ratio."""
    (la, va), (lb, vb) = result["variants"].items()
    ma, mb = result["medians"][la], result["medians"][lb]
    width = max(len(la), len(lb), 9)
    lines = [
        f"Simulated flights (fly --hover --sim, {result['duration_s']:g} s, "
        f"{result['pairs']} pairs alternated; medians, ratio = {lb} / {la}):",
        f"  {'figure':44s} {la:>{width}s} {lb:>{width}s} {'ratio':>6s}",
        f"  {'matcher worker':44s} {','.join(va['workers']):>{width}s} "
        f"{','.join(vb['workers']):>{width}s}",
    ]
    for key, label, spec in METRICS:
        lines.append(
            f"  {label:44s} {fmt(ma[key], spec, width)} {fmt(mb[key], spec, width)} "
            f"{fmt(result['ratio'][key], '.2f', 6)}"
        )
    verdicts = [
        f"{label} {'yes' if m['daemon_percent'] <= DAEMON_TARGET_PERCENT else 'NO'}"
        for label, m in ((la, ma), (lb, mb))
        if m["daemon_percent"] is not None
    ]
    lines.append(
        f"  daemon in HOLD (flight.json) <= {DAEMON_TARGET_PERCENT:g} % of a core: "
        + (", ".join(verdicts) or "-")
    )
    for name, fs in result["flights"].items():
        bad = [f for f in fs if "error" in f or f.get("exit_code")]
        for f in bad:
            lines.append(
                f"  {name}: flight "
                + (f["error"] if "error" in f else f"exit {f['exit_code']}: {f['end_reason']}")
            )
    return "\n".join(lines)


def startup(
    variants: tuple[Variant, Variant],
    pairs: int,
    import_repeat: int,
    flown: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Start-up per variant: import time of the flight path and spawn -> READY.

    The READY times come from ``flown`` (a :func:`run_pairs` result of this run) when
    given, else from ``pairs`` pairs of 1 s flights flown here.
    """
    from bench_trees import import_times

    if flown is None:
        flown = run_pairs(variants, pairs, 1.0)
    a, b = variants
    out: dict[str, Any] = {
        "imports": import_times((a.tree, b.tree), import_repeat),
        "flights": len(flown["flights"][a.label]),
        "startup_s": {},
        "spawn_to_preflight_s": {},
    }
    for key in ("startup_s", "spawn_to_preflight_s"):
        for v in variants:
            out[key][v.label] = median_of(f.get(key) for f in flown["flights"][v.label])
        out[key]["ratio"] = ratio(out[key][b.label], out[key][a.label])
    return out


def format_startup(result: dict[str, Any], labels: tuple[str, str]) -> str:
    """Start-up as text: import times, spawn -> pre-flight done, spawn -> READY."""
    la, lb = labels
    imp = result["imports"]
    lines = [
        f"Start-up (medians; ratio = {lb} / {la}):",
        f"  {'figure':44s} {la:>9s} {lb:>9s} {'ratio':>6s}",
    ]
    for name, module in imp["modules"].items():
        lines.append(
            f"  {'import ' + module + ', s':44s} {fmt(imp['median_s'][la][name], '.3f', 9)} "
            f"{fmt(imp['median_s'][lb][name], '.3f', 9)} {fmt(imp['ratio'][name], '.2f', 6)}"
        )
    for key, label in (
        ("spawn_to_preflight_s", "fly -> pre-flight done, s"),
        ("startup_s", "fly -> READY, s"),
    ):
        r = result[key]
        lines.append(
            f"  {label:44s} {fmt(r[la], '.3f', 9)} {fmt(r[lb], '.3f', 9)} "
            f"{fmt(r['ratio'], '.2f', 6)}"
        )
    for name, module in imp["modules"].items():
        heavy = {label: ", ".join(imp["heavy_modules"][label][name]) or "none" for label in labels}
        lines.append(f"  {module} pulls in: {la} {heavy[la]}; {lb} {heavy[lb]}")
    lines.append(f"  ({imp['repeat']} fresh interpreters per import, {result['flights']} flights)")
    return "\n".join(lines)


# ----- the live view's cost -----------------------------------------------------------------


def _free_port() -> int:
    """A TCP port nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Watcher(threading.Thread):
    """A Foxglove client on its own thread: subscribes to every topic, reads every message."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.messages = 0
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            asyncio.run(self._watch())
        except Exception as err:  # reported beside the figures
            self.error = err

    async def _watch(self) -> None:
        import websockets
        from websockets.typing import Subprotocol

        from mkflight.ground.live_client import SUBPROTOCOL, subscribe

        url = f"ws://127.0.0.1:{self.port}"
        for _ in range(600):  # the server starts with the command: 60 s at most
            try:
                ws = await websockets.connect(url, subprotocols=[Subprotocol(SUBPROTOCOL)])
                break
            except OSError:
                await asyncio.sleep(0.1)
        else:
            msg = f"no live view at {url}"
            raise RuntimeError(msg)
        await subscribe(ws)
        try:
            async for frame in ws:
                if isinstance(frame, bytes):
                    self.messages += 1
        except websockets.ConnectionClosed:
            pass


def _live_flight(duration_s: float, folder: Path, live: bool) -> dict[str, Any]:
    """One flight, with ``--live`` and a reading client or without; its figures."""
    watcher = None
    extra: tuple[str, ...] = ()
    if live:
        port = _free_port()
        watcher = Watcher(port)
        watcher.start()
        extra = ("--live", f"127.0.0.1:{port}")
    run = fly(Tree("current", ROOT, describe_current()), duration_s, folder, (), extra)
    s = run["summary"]
    if s is None or run["exit_code"] != 0:
        msg = f"flight failed ({run['exit_code']}): {run['stderr_tail']}"
        raise RuntimeError(msg)
    t = s["timing"]
    figures: dict[str, Any] = {
        "steps": t["steps"],
        "latency_median_ms": t["latency_median_ms"],
        "latency_p99_ms": t["latency_p99_ms"],
        "latency_max_ms": t["latency_max_ms"],
        "missed_steps": t["missed_steps"],
        "cpu_percent_main": s["cpu_percent_of_one_core"],
    }
    if watcher is not None:
        watcher.join(timeout=30)
        if watcher.error is not None:
            msg = f"the live client failed: {watcher.error!r}"
            raise RuntimeError(msg)
        figures["messages_received"] = watcher.messages
    return figures


def run_live(duration_s: float = 120.0, pairs: int = 3) -> dict[str, Any]:
    """``pairs`` pairs of flights, ``--live`` off and on alternated (module docstring)."""
    flights: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory(prefix="mkflight-bench-live-") as tmp:
        for k in range(pairs):
            order = ("off", "on") if k % 2 == 0 else ("on", "off")
            for name in order:
                folder = Path(tmp) / f"{name}-{k}"
                flights[name].append(_live_flight(duration_s, folder, live=name == "on"))
    medians = {
        name: {
            q: statistics.median(f[q] for f in runs)
            for q in ("latency_median_ms", "latency_p99_ms", "cpu_percent_main")
        }
        for name, runs in flights.items()
    }
    on, off = medians["on"], medians["off"]
    return {
        "duration_s": duration_s,
        "pairs": pairs,
        "flights": flights,
        "medians": medians,
        "ratio_on_over_off": {
            q: on[q] / off[q] for q in ("latency_median_ms", "latency_p99_ms") if off[q]
        },
        "added_p99_ms": on["latency_p99_ms"] - off["latency_p99_ms"],
        "added_p99_ms_per_pair": [
            a["latency_p99_ms"] - b["latency_p99_ms"]
            for a, b in zip(flights["on"], flights["off"], strict=True)
        ],
    }


def format_live_table(result: dict[str, Any]) -> str:
    """The live view's figures as a text table."""
    lines = [
        f"Live view: {result['pairs']} pairs of simulated flights of {result['duration_s']:g} s, "
        "--live off and on alternated (on: a client subscribed to every topic):",
        f"  {'flight':8s} {'lat med':>8s} {'lat p99':>8s} {'lat max':>8s} {'missed':>6s} "
        f"{'CPU %':>6s} {'msgs':>7s}",
    ]
    for name, runs in result["flights"].items():
        for k, f in enumerate(runs):
            lines.append(
                f"  {name + ' ' + str(k + 1):8s} {f['latency_median_ms']:8.3f} "
                f"{f['latency_p99_ms']:8.3f} {f['latency_max_ms']:8.3f} {f['missed_steps']:6d} "
                f"{f['cpu_percent_main']:6.2f} {f.get('messages_received', 0):7d}"
            )
    for name, m in result["medians"].items():
        lines.append(
            f"  median {name}: latency median {m['latency_median_ms']:.3f} ms, "
            f"p99 {m['latency_p99_ms']:.3f} ms, CPU {m['cpu_percent_main']:.2f} %"
        )
    r = result["ratio_on_over_off"]
    lines.append(
        f"  ratio on/off: median {r.get('latency_median_ms', float('nan')):.3f}, "
        f"p99 {r.get('latency_p99_ms', float('nan')):.3f}; added p99 "
        f"{result['added_p99_ms']:+.3f} ms (per pair: "
        + ", ".join(f"{x:+.3f}" for x in result["added_p99_ms_per_pair"])
        + ")"
    )
    return "\n".join(lines)
