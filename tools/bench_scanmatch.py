"""Scan-matcher benchmark (SPEC §9): time per scan and relation error per dataset.

Run: ``python tools/bench_scanmatch.py [--json] [--only NAME ...] [--repeat N]``.

For every dataset of ``../shared/data/laser/`` (skipped when absent) the log is matched with
the same prior as the README's CSM table (own constant-velocity prediction for the
synthetic hover/traverse sets, ``--odom`` for the corridor, Intel and fr079), the
trajectory is scored with ``relpose_eval.py``'s own ``evaluate`` (imported from the
shared tools folder, not copied), and the median / p95 wall time per scan is reported
(time = beam selection, points, line model when a keyframe is taken, registration).
A synthetic case times URG-size scans (682 beams, hover motion, random rooms the matcher
has never seen). Timings on a shared VM vary by about +-30 % run to run.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import statistics
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from mkflight.conversions import MS_PER_S
from mkflight.scanmatch import KeyframeMatcher, read_carmen, scan_to_points
from mkflight.scanmatch.log_tracking import track_records
from mkflight.scanmatch.trajectory import read_trajectory
from mkflight.sim.room import random_room, raycast

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
LASER = SHARED / "data" / "laser"

# name: (log, odom or None, relations), CSM figures (median ms, p95 ms, trans m, rot rad)
DATASETS: dict[str, tuple[str, str | None, str]] = {
    "synth_roomA_hover": ("synth/synth_roomA_hover.clf", None, "synth/synth_roomA_hover.relations"),
    "synth_roomB_hover": ("synth/synth_roomB_hover.clf", None, "synth/synth_roomB_hover.relations"),
    "synth_roomA_traverse": (
        "synth/synth_roomA_traverse.clf",
        None,
        "synth/synth_roomA_traverse.relations",
    ),
    "synth_corridor_hover": (
        "synth/synth_corridor_hover.clf",
        "synth/synth_corridor_hover.odom.txt",
        "synth/synth_corridor_hover.relations",
    ),
    "intel": ("intel/intel-corrected.log.gz", "intel/intel.odom.txt", "intel/intel.relations"),
    "fr079": (
        "fr079/freiburg-079-corrected.log.gz",
        "fr079/fr079.odom.txt",
        "fr079/fr079.relations",
    ),
}
CSM: dict[str, tuple[float, float, float, float]] = {
    "synth_roomA_hover": (1.51, 2.20, 0.0055, 0.0037),
    "synth_roomB_hover": (2.00, 2.29, 0.0030, 0.0009),
    "synth_roomA_traverse": (1.60, 2.22, 0.0047, 0.0018),
    "synth_corridor_hover": (2.12, 2.34, 0.0350, 0.0005),
    "intel": (0.31, 0.46, 0.0295, 0.0079),
    "fr079": (0.92, 1.34, 0.0275, 0.0094),
}
TARGET_MEDIAN_MS = 2.0


def percentile(values: list[float], q: float) -> float:
    """The q-th percentile (0..100) by linear interpolation."""
    return float(np.percentile(np.asarray(values), q)) if values else math.nan


def load_relpose_eval() -> ModuleType:
    """Import ``relpose_eval.py`` from the shared tools folder."""
    path = SHARED / "tools" / "relpose_eval.py"
    spec = importlib.util.spec_from_file_location("relpose_eval", path)
    if spec is None or spec.loader is None:
        msg = f"cannot import {path}"
        raise ImportError(msg)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench_dataset(name: str, repeat: int = 1) -> dict[str, Any]:
    """Match one dataset (``repeat`` times for timing; accuracy from the first run)."""
    log, odom, rel = DATASETS[name]
    rv = load_relpose_eval()
    parsed = read_carmen(LASER / log)
    odom_data = read_trajectory(LASER / odom) if odom else None
    times_ms: list[float] = []
    tracked = track_records(parsed.records, odom=odom_data)
    for _ in range(repeat - 1):
        more = track_records(parsed.records, odom=odom_data)
        times_ms += [s.elapsed_s * MS_PER_S for s in more[1:]]
    times_ms += [s.elapsed_s * MS_PER_S for s in tracked[1:]]
    traj = np.array([(s.t_s, *s.pose) for s in tracked])
    order = np.argsort(traj[:, 0], kind="stable")
    score = rv.evaluate(traj[order, 0], traj[order, 1:4], rv.load_relations(str(LASER / rel)))
    return {
        "dataset": name,
        "prior": "odom" if odom else "own",
        "scans": len(tracked),
        "malformed": len(parsed.malformed),
        "invalid": sum(not s.result.valid for s in tracked[1:]),
        "degenerate": sum(s.result.degenerate for s in tracked),
        "median_ms": statistics.median(times_ms),
        "p95_ms": percentile(times_ms, 95),
        "trans_mean_m": score["trans_mean_m"],
        "rot_mean_rad": score["rot_mean_rad"],
        "matched_relations": score["matched"],
    }


def bench_synthetic(n_rooms: int = 5, scans_per_room: int = 200, seed: int = 1) -> dict[str, Any]:
    """Time URG-size scans (682 beams, 1 cm noise) in random rooms during a slow hover."""
    rng = np.random.default_rng(seed)
    steps = np.arange(44, 726)
    angles = (steps - 384) * (2.0 * math.pi / 1024.0)
    use = steps >= 150  # laser.scan_steps: the hat and the mirror edge are not matched
    times_ms: list[float] = []
    errors_m: list[float] = []
    for k in range(n_rooms):
        room = random_room(seed * 1000 + k)
        matcher = KeyframeMatcher()
        phase = rng.uniform(0, 2 * math.pi, 3)
        for i in range(scans_per_room):
            t = 0.1 * i
            x = 0.3 * math.sin(0.4 * t + phase[0])
            y = 0.3 * math.sin(0.3 * t + phase[1])
            th = 0.2 * math.sin(0.25 * t + phase[2])
            r = raycast(room, x, y, th, angles, 5.6)
            r = np.round(r + rng.normal(0.0, 0.01, r.shape), 3)
            t0 = time.perf_counter()
            pts = scan_to_points(r[use], angles[use], 0.02, 5.6)
            if i == 0:
                matcher = KeyframeMatcher(start_pose=(x, y, th))
            upd = matcher.update(pts, dt_s=0.1)
            if i > 0:
                times_ms.append((time.perf_counter() - t0) * MS_PER_S)
                errors_m.append(math.hypot(upd.pose[0] - x, upd.pose[1] - y))
    return {
        "dataset": "synthetic URG 682 beams (random rooms)",
        "scans": len(times_ms),
        "median_ms": statistics.median(times_ms),
        "p95_ms": percentile(times_ms, 95),
        "abs_err_mean_m": float(np.mean(errors_m)),
    }


def run(only: list[str] | None = None, repeat: int = 1) -> dict[str, Any]:
    """All benchmarks as one dict: ``datasets`` (list of rows) and ``synthetic``."""
    rows: list[dict[str, Any]] = []
    skipped: list[str] = []
    for name, (log, _odom, _rel) in DATASETS.items():
        if only and name not in only:
            continue
        if not (LASER / log).exists():
            skipped.append(name)
            continue
        rows.append(bench_dataset(name, repeat))
    return {"datasets": rows, "skipped": skipped, "synthetic": bench_synthetic()}


def format_table(result: dict[str, Any]) -> str:
    lines = [
        f"{'dataset':22s} {'prior':5s} {'med ms':>7s} {'p95 ms':>7s} {'trans m':>8s} "
        f"{'rot rad':>8s} | {'CSM med':>7s} {'p95':>5s} {'trans':>7s} {'rot':>7s} | verdict"
    ]
    for r in result["datasets"]:
        c = CSM[r["dataset"]]
        acc_ok = r["trans_mean_m"] <= c[2] and r["rot_mean_rad"] <= c[3]
        verdict = ("acc ok" if acc_ok else "ACC WORSE") + f", {r['invalid']} invalid"
        lines.append(
            f"{r['dataset']:22s} {r['prior']:5s} {r['median_ms']:7.2f} {r['p95_ms']:7.2f} "
            f"{r['trans_mean_m']:8.4f} {r['rot_mean_rad']:8.4f} | {c[0]:7.2f} {c[1]:5.2f} "
            f"{c[2]:7.4f} {c[3]:7.4f} | {verdict}"
        )
    s = result["synthetic"]
    ok = "ok" if s["median_ms"] <= TARGET_MEDIAN_MS else "OVER TARGET"
    lines.append(
        f"{s['dataset']}: median {s['median_ms']:.2f} ms, p95 {s['p95_ms']:.2f} ms "
        f"(target median <= {TARGET_MEDIAN_MS} ms: {ok}), "
        f"mean abs error {s['abs_err_mean_m']:.4f} m"
    )
    if result["skipped"]:
        lines.append(f"skipped (data absent): {', '.join(result['skipped'])}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--only", nargs="*", help="dataset names to run")
    ap.add_argument("--repeat", type=int, default=1, help="timing repetitions per dataset")
    a = ap.parse_args(argv)
    result = run(a.only, a.repeat)
    print(json.dumps(result) if a.json else format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
