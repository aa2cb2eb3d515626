"""The daemon in flight (SPEC §9): whole simulated flights, matcher in a process vs inline.

Each variant is one ``mkflight fly --hover --sim --duration D --json`` run (the simulator
in its own process on ptys, the daemon exactly as on hardware); its ``flight.json``
summary gives the figures:

* latency: DebugOut arrival -> ExternControl written, median and p99, with ICP running;
* step period: the DebugOut interval's p99 deviation from its median (the FC's and its
  wire's timing as the daemon sees it, re-subscriptions excluded), the jitter the daemon
  adds (p99 of the step-to-step change of latency), missed steps (an interval > 1.5
  periods);
* CPU: the daemon's main process as % of one core over the whole run, plus the matcher
  worker's CPU per scan (x 10 scans/s = its % of a core);
* hover precision against the simulator's truth.

The baseline, measured in the same run: the same flight with ``scanmatch.worker=inline``
(ICP on the event loop, as a single-process daemon would do it).

The live view's cost (:func:`run_live`, ``tools/bench.py --only flight --live``): the same
flight with ``--live`` off and on, alternated in pairs (off-on, on-off, ...) so that the
machine's drift hits both alike. While ``--live`` is on, a WebSocket client in this
process subscribes to every topic and reads every message (without a subscriber the
SDK would build and send nothing). Reported: command latency median and p99 per flight,
their medians over the flights of each variant, the ratios on/off and the p99 added.
"""

from __future__ import annotations

import asyncio
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

VARIANTS = {"process": "scanmatch.worker=process", "inline (baseline)": "scanmatch.worker=inline"}


def fly(
    duration_s: float, setting: str, folder: Path, extra: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One simulated flight (``extra``: more options); its ``--json`` summary."""
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkflight",
            "fly",
            "--hover",
            "--sim",
            "--duration",
            str(duration_s),
            "--log-dir",
            str(folder),
            "--set",
            setting,
            "--json",
            *extra,
        ],
        capture_output=True,
        text=True,
        check=False,
        stdin=subprocess.DEVNULL,
    )
    if proc.returncode != 0:
        msg = f"flight failed ({proc.returncode}): {proc.stderr.strip()[-500:]}"
        raise RuntimeError(msg)
    summary: dict[str, Any] = json.loads(proc.stdout)
    return summary


def run(duration_s: float = 600.0, baseline_s: float | None = None) -> dict[str, Any]:
    """Both variants, one flight each (the baseline ``baseline_s`` long, default the same)."""
    durations = {"process": duration_s, "inline (baseline)": baseline_s or duration_s}
    out: dict[str, Any] = {"durations_s": durations, "variants": {}}
    with tempfile.TemporaryDirectory(prefix="mkflight-bench-") as tmp:
        for name, setting in VARIANTS.items():
            s = fly(durations[name], setting, Path(tmp) / name.split()[0])
            t = s["timing"]
            matcher = s["matcher"]
            out["variants"][name] = {
                "steps": t["steps"],
                "latency_median_ms": t["latency_median_ms"],
                "latency_p99_ms": t["latency_p99_ms"],
                "latency_max_ms": t["latency_max_ms"],
                "period_median_ms": t["period_median_ms"],
                "arrival_jitter_p99_ms": t["jitter_p99_ms"],
                "added_jitter_p99_ms": t["added_jitter_p99_ms"],
                "missed_steps": t["missed_steps"],
                "overruns": t["overruns"],
                "cpu_percent_main": s["cpu_percent_of_one_core"],
                "matcher_cpu_ms_per_scan": matcher["cpu_ms_per_scan"],
                "truth_precision": s["truth_precision"],
            }
    ours, base = out["variants"]["process"], out["variants"]["inline (baseline)"]
    out["ratio_process_over_inline"] = {
        k: ours[k] / base[k]
        for k in ("latency_median_ms", "latency_p99_ms", "added_jitter_p99_ms")
        if base[k]
    }
    return out


def format_table(result: dict[str, Any]) -> str:
    """The figures as a text table."""
    lines = [
        "Simulated flights (fly --hover --sim), "
        + ", ".join(f"{k} {v:g} s" for k, v in result["durations_s"].items())
        + ":",
        f"  {'variant':18s} {'lat med':>8s} {'lat p99':>8s} {'arr jit':>8s} {'add jit':>8s} "
        f"{'missed':>6s} {'CPU %':>6s} {'ICP ms':>7s} {'std x/y/z m':>22s}",
    ]
    for name, v in result["variants"].items():
        p = v["truth_precision"] or {}
        std = "/".join(f"{p.get(k, float('nan')):.4f}" for k in ("std_x_m", "std_y_m", "std_z_m"))
        lines.append(
            f"  {name:18s} {v['latency_median_ms']:8.3f} {v['latency_p99_ms']:8.3f} "
            f"{v['arrival_jitter_p99_ms']:8.2f} {v['added_jitter_p99_ms']:8.2f} "
            f"{v['missed_steps']:6d} {v['cpu_percent_main']:6.2f} "
            f"{v['matcher_cpu_ms_per_scan'] or float('nan'):7.2f} {std:>22s}"
        )
    r = result["ratio_process_over_inline"]
    lines.append(
        "  ratio process/inline: "
        + ", ".join(f"{k.removesuffix('_ms')} {v:.2f}" for k, v in r.items())
    )
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
    s = fly(duration_s, "scanmatch.worker=process", folder, extra)
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
