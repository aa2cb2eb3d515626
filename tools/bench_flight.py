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
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

VARIANTS = {"process": "scanmatch.worker=process", "inline (baseline)": "scanmatch.worker=inline"}


def fly(duration_s: float, setting: str, folder: Path) -> dict[str, Any]:
    """One simulated flight; its ``--json`` summary."""
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
