"""Scan-matcher benchmark (SPEC §9): time per scan and relation error, two trees side by side.

Run: ``python tools/bench.py --only scanmatch`` (baseline revision against this tree, both in
subprocesses); or ``python tools/bench_scanmatch.py [--json] [--only NAME ...] [--repeat N]``
for the tree on ``PYTHONPATH`` alone (that is also what each subprocess of the comparison runs,
so both trees are timed by this one file's code).

For every dataset of ``../shared/data/laser/`` (skipped when absent) the log is matched with
the same prior as the data README's CSM table (own constant-velocity prediction for the
synthetic hover/traverse sets, ``--odom`` for the corridor, Intel and fr079), the
trajectory is scored with ``relpose_eval.py``'s own ``evaluate`` (imported from the
shared tools folder, not copied), and the median / p95 wall time per scan is reported
(time = beam selection, points, line model when a keyframe is taken, registration).
``random_rooms`` times URG-size scans (682 beams, hover motion, random rooms the matcher
has never seen). The code used from ``mkflight`` is the public API both trees have:
``KeyframeMatcher``, ``read_carmen``, ``scan_to_points``, ``log_tracking.track_records``,
``trajectory.read_trajectory`` and ``sim.room``.

The comparison (:func:`compare`) runs baseline and current alternated per dataset
(``repeat`` rounds: A B, B A, A B, ...), pools each tree's per-scan times, and reports both
medians and p95s, the CPU time a scan, the ratios current/baseline, both accuracies and
whether current's is no worse. CSM's figures are read from the data README's table (CSM
``sm_icp`` with laser_scan_matcher's defaults, measured on a 2-core VM, not in this run): a
labelled reference column, with the ratio to them. Timings on a shared VM vary by about
+-30 % run to run; the alternation makes the drift hit both trees alike.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from bench_trees import Tree, fmt, ratio  # tools/bench_trees.py, beside this file

from mkflight.conversions import MS_PER_S
from mkflight.scanmatch import KeyframeMatcher, read_carmen, scan_to_points
from mkflight.scanmatch.log_tracking import track_records
from mkflight.scanmatch.trajectory import read_trajectory
from mkflight.sim.room import random_room, raycast

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
LASER = SHARED / "data" / "laser"
CSM_SOURCE = (
    "../shared/data/laser/README.md: CSM sm_icp with all laser_scan_matcher defaults, "
    "single-threaded C, measured on a 2-core VM (not in this run)"
)
RANDOM_ROOMS = "random_rooms"

# name: (log, odom or None, relations)
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
# Accuracy counts as "no worse" within half the last digit the tables show (0.1 mm, 0.1 mrad).
ACCURACY_SLACK_M = 0.00005
ACCURACY_SLACK_RAD = 0.00005


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


def parse_csm_table(text: str) -> dict[str, dict[str, float]]:
    """CSM's rows of the data README's table (dataset, prior, median/p95 ms, trans m, rot rad).

    Only the table under the ``The anchor: CSM`` heading is read; rows that are not six
    cells with four numbers are skipped.
    """
    section = re.split(r"^## The anchor: CSM.*$", text, maxsplit=1, flags=re.MULTILINE)
    if len(section) < 2:
        return {}
    rows: dict[str, dict[str, float]] = {}
    for line in section[1].split("\n## ", 1)[0].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 6:
            continue
        try:
            median, p95, trans, rot = (float(c) for c in cells[2:])
        except ValueError:
            continue
        rows[cells[0]] = {"median_ms": median, "p95_ms": p95, "trans_m": trans, "rot_rad": rot}
    return rows


def csm_reference() -> dict[str, dict[str, float]]:
    """CSM's figures from ``../shared/data/laser/README.md`` (empty when it is absent)."""
    readme = LASER / "README.md"
    return parse_csm_table(readme.read_text()) if readme.exists() else {}


def bench_dataset(name: str, repeat: int = 1, times: bool = False) -> dict[str, Any]:
    """Match one dataset (``repeat`` times for timing; accuracy from the first run).

    ``times``: also return every per-scan time (``times_ms``), for pooling across runs.
    """
    log, odom, rel = DATASETS[name]
    rv = load_relpose_eval()
    parsed = read_carmen(LASER / log)
    odom_data = read_trajectory(LASER / odom) if odom else None
    times_ms: list[float] = []
    # Start-up off the clock (imports, the first calls, a compiled kernel's load): each
    # tree's start-up is the start-up table's, not a per-scan cost.
    track_records(parsed.records[:3], odom=odom_data)
    cpu0 = time.process_time()
    tracked = track_records(parsed.records, odom=odom_data)
    for _ in range(repeat - 1):
        more = track_records(parsed.records, odom=odom_data)
        times_ms += [s.elapsed_s * MS_PER_S for s in more[1:]]
    cpu_s = time.process_time() - cpu0
    times_ms += [s.elapsed_s * MS_PER_S for s in tracked[1:]]
    traj = np.array([(s.t_s, *s.pose) for s in tracked])
    order = np.argsort(traj[:, 0], kind="stable")
    score = rv.evaluate(traj[order, 0], traj[order, 1:4], rv.load_relations(str(LASER / rel)))
    out = {
        "dataset": name,
        "prior": "odom" if odom else "own",
        "scans": len(tracked),
        "malformed": len(parsed.malformed),
        "invalid": sum(not s.result.valid for s in tracked[1:]),
        "degenerate": sum(s.result.degenerate for s in tracked),
        "median_ms": statistics.median(times_ms),
        "p95_ms": percentile(times_ms, 95),
        "cpu_ms_per_scan": cpu_s * MS_PER_S / (repeat * len(tracked)),
        "trans_mean_m": score["trans_mean_m"],
        "rot_mean_rad": score["rot_mean_rad"],
        "matched_relations": score["matched"],
    }
    if times:
        out["times_ms"] = times_ms
    return out


def bench_synthetic(
    n_rooms: int = 5, scans_per_room: int = 200, seed: int = 1, times: bool = False
) -> dict[str, Any]:
    """Time URG-size scans (682 beams, 1 cm noise) in random rooms during a slow hover."""
    rng = np.random.default_rng(seed)
    steps = np.arange(44, 726)
    angles = (steps - 384) * (2.0 * math.pi / 1024.0)
    use = steps >= 150  # laser.scan_steps: the hat and the mirror edge are not matched
    times_ms: list[float] = []
    errors_m: list[float] = []
    cpu_s = 0.0
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
            t0, c0 = time.perf_counter(), time.thread_time()
            pts = scan_to_points(r[use], angles[use], 0.02, 5.6)
            if i == 0:
                matcher = KeyframeMatcher(start_pose=(x, y, th))
            upd = matcher.update(pts, dt_s=0.1)
            if i > 0:
                times_ms.append((time.perf_counter() - t0) * MS_PER_S)
                cpu_s += time.thread_time() - c0
                errors_m.append(math.hypot(upd.pose[0] - x, upd.pose[1] - y))
    out = {
        "dataset": RANDOM_ROOMS,
        "description": "synthetic URG 682 beams (random rooms, hover)",
        "scans": len(times_ms),
        "median_ms": statistics.median(times_ms),
        "p95_ms": percentile(times_ms, 95),
        "cpu_ms_per_scan": cpu_s * MS_PER_S / len(times_ms),
        "abs_err_mean_m": float(np.mean(errors_m)),
    }
    if times:
        out["times_ms"] = times_ms
    return out


def available(only: list[str] | None = None) -> tuple[list[str], list[str]]:
    """The datasets to run (in table order, ``random_rooms`` last) and those absent."""
    names = [n for n in [*DATASETS, RANDOM_ROOMS] if not only or n in only]
    present = [n for n in names if n == RANDOM_ROOMS or (LASER / DATASETS[n][0]).exists()]
    return present, [n for n in names if n not in present]


def run(only: list[str] | None = None, repeat: int = 1, times: bool = False) -> dict[str, Any]:
    """This tree's figures: ``datasets`` (list of rows), ``synthetic`` (random rooms)."""
    present, skipped = available(only)
    rows = [bench_dataset(n, repeat, times) for n in present if n != RANDOM_ROOMS]
    synthetic = bench_synthetic(times=times) if RANDOM_ROOMS in present else None
    return {"datasets": rows, "skipped": skipped, "synthetic": synthetic}


def format_table(result: dict[str, Any]) -> str:
    """One tree's figures beside CSM's (the data README's table)."""
    csm = csm_reference()
    lines = [
        f"{'dataset':22s} {'prior':5s} {'med ms':>7s} {'p95 ms':>7s} {'trans m':>8s} "
        f"{'rot rad':>8s} | {'CSM med':>7s} {'trans':>7s} {'rot':>7s} | verdict"
    ]
    for r in result["datasets"]:
        c = csm.get(r["dataset"])
        if c is None:
            ref, verdict = f"{'-':>7s} {'-':>7s} {'-':>7s}", "no CSM figure"
        else:
            ref = f"{c['median_ms']:7.2f} {c['trans_m']:7.4f} {c['rot_rad']:7.4f}"
            acc_ok = r["trans_mean_m"] <= c["trans_m"] and r["rot_mean_rad"] <= c["rot_rad"]
            verdict = "acc ok" if acc_ok else "ACC WORSE"
        lines.append(
            f"{r['dataset']:22s} {r['prior']:5s} {r['median_ms']:7.2f} {r['p95_ms']:7.2f} "
            f"{r['trans_mean_m']:8.4f} {r['rot_mean_rad']:8.4f} | {ref} | "
            f"{verdict}, {r['invalid']} invalid"
        )
    s = result["synthetic"]
    if s is not None:
        lines.append(
            f"{s['description']}: median {s['median_ms']:.2f} ms, p95 {s['p95_ms']:.2f} ms, "
            f"mean abs error {s['abs_err_mean_m']:.4f} m"
        )
    if result["skipped"]:
        lines.append(f"skipped (data absent): {', '.join(result['skipped'])}")
    lines.append(f"CSM: {CSM_SOURCE}")
    return "\n".join(lines)


# ----- two trees: the comparison ---------------------------------------------------------


def measure_in_tree(tree: Tree, name: str) -> dict[str, Any]:
    """One run of one dataset by this file in a subprocess on ``tree``'s ``mkflight``.

    Returns the dataset's row with its per-scan times, or ``{"error": ...}`` when the tree
    could not run it (a tree without some API fails alone; the other's figures stand).
    """
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--json", "--times", "--only", name],
        capture_output=True,
        text=True,
        check=False,
        env=tree.env(),
        cwd=tree.path,
        stdin=subprocess.DEVNULL,
    )
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    result = json.loads(proc.stdout)
    rows = result["datasets"] or [result["synthetic"]]
    row: dict[str, Any] = rows[0]
    return row


def pool_runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One tree's runs of one dataset as one row: pooled median/p95, per-run medians, accuracy.

    Accuracy comes from the first run (matching is deterministic); a failed run's error is
    kept and the tree's figures are None when no run succeeded.
    """
    ok = [r for r in runs if "error" not in r]
    errors = [r["error"] for r in runs if "error" in r]
    if not ok:
        return {
            "error": errors[0] if errors else "not run",
            "median_ms": None,
            "p95_ms": None,
            "cpu_ms_per_scan": None,
        }
    pooled = [t for r in ok for t in r["times_ms"]]
    first = ok[0]
    return {
        "median_ms": statistics.median(pooled),
        "p95_ms": percentile(pooled, 95),
        "run_medians_ms": [r["median_ms"] for r in ok],
        "best_run_median_ms": min(r["median_ms"] for r in ok),
        "cpu_ms_per_scan": statistics.median(r["cpu_ms_per_scan"] for r in ok),
        "run_cpu_ms_per_scan": [r["cpu_ms_per_scan"] for r in ok],
        "scans_timed": len(pooled),
        "trans_mean_m": first.get("trans_mean_m"),
        "rot_mean_rad": first.get("rot_mean_rad"),
        "abs_err_mean_m": first.get("abs_err_mean_m"),
        "invalid": first.get("invalid"),
        "prior": first.get("prior"),
        "error": errors[0] if errors else None,
    }


def accuracy_no_worse(current: dict[str, Any], baseline: dict[str, Any]) -> bool | None:
    """Current's error <= baseline's (within :data:`ACCURACY_SLACK_M`/``_RAD``); None: unknown."""
    pairs = [
        ("trans_mean_m", ACCURACY_SLACK_M),
        ("rot_mean_rad", ACCURACY_SLACK_RAD),
        ("abs_err_mean_m", ACCURACY_SLACK_M),
    ]
    checked = [
        current[k] <= baseline[k] + slack
        for k, slack in pairs
        if current.get(k) is not None and baseline.get(k) is not None
    ]
    return all(checked) if checked else None


def compare_row(
    name: str,
    baseline_runs: list[dict[str, Any]],
    current_runs: list[dict[str, Any]],
    csm: dict[str, float] | None,
) -> dict[str, Any]:
    """One dataset's table row: both trees pooled, ratios current/baseline, CSM's reference."""
    base, cur = pool_runs(baseline_runs), pool_runs(current_runs)
    row: dict[str, Any] = {
        "dataset": name,
        "prior": cur.get("prior") or base.get("prior"),
        "baseline": base,
        "current": cur,
        "ratio_median": ratio(cur["median_ms"], base["median_ms"]),
        "ratio_p95": ratio(cur["p95_ms"], base["p95_ms"]),
        "ratio_cpu": ratio(cur["cpu_ms_per_scan"], base["cpu_ms_per_scan"]),
        "ratio_best_run": ratio(cur.get("best_run_median_ms"), base.get("best_run_median_ms")),
        "accuracy_no_worse": accuracy_no_worse(cur, base)
        if base["error"] is None and cur["error"] is None
        else None,
        "csm": csm,
    }
    if csm is not None:
        row["ratio_current_over_csm"] = ratio(cur["median_ms"], csm["median_ms"])
        row["ratio_baseline_over_csm"] = ratio(base["median_ms"], csm["median_ms"])
    return row


def compare(
    trees: tuple[Tree, Tree], only: list[str] | None = None, repeat: int = 3
) -> dict[str, Any]:
    """Every present dataset, ``repeat`` rounds of both trees alternated (module docstring)."""
    present, skipped = available(only)
    csm = csm_reference()
    rows = []
    for name in present:
        runs: dict[str, list[dict[str, Any]]] = {t.label: [] for t in trees}
        for k in range(repeat):  # A B, B A, A B, ...: neither tree always goes first
            for tree in trees if k % 2 == 0 else trees[::-1]:
                runs[tree.label].append(measure_in_tree(tree, name))
        base, cur = (runs[t.label] for t in trees)
        rows.append(compare_row(name, base, cur, csm.get(name)))
        for r in (*base, *cur):
            r.pop("times_ms", None)
    return {
        "repeat": repeat,
        "rows": rows,
        "skipped": skipped,
        "csm_source": CSM_SOURCE if csm else None,
        "accuracy_slack": {"m": ACCURACY_SLACK_M, "rad": ACCURACY_SLACK_RAD},
    }


def _accuracy(side: dict[str, Any]) -> str:
    if side.get("trans_mean_m") is not None:
        return f"{1000 * side['trans_mean_m']:6.1f}/{1000 * side['rot_mean_rad']:5.1f}"
    if side.get("abs_err_mean_m") is not None:
        return f"{1000 * side['abs_err_mean_m']:6.1f} abs  "
    return f"{'-':>12s}"


def format_compare_table(result: dict[str, Any], labels: tuple[str, str]) -> str:
    """The comparison as text: ms a scan, ratios, accuracy (mm / mrad), CSM's reference."""
    lines = [
        f"Scan matcher, {labels[1]} against {labels[0]}, {result['repeat']} alternated runs "
        "per tree: wall ms a scan (median of all scans, and p95's ratio), CPU ms a scan "
        "(mean; blind to the other processes' share of the cores), accuracy = relation "
        "error mean mm / mrad (random rooms: mean absolute error mm):",
        f"  {'':27s} {'wall median ms':^22s}   {'CPU ms a scan':^22s}  {'p95':>5s} | "
        f"{'accuracy':^33s} | {'CSM, reference':^15s}",
        f"  {'dataset':21s} {'prior':5s} {'base':>7s} {'cur':>7s} {'ratio':>6s}   "
        f"{'base':>7s} {'cur':>7s} {'ratio':>6s}  {'ratio':>5s} | {'base':>12s} {'cur':>12s} "
        f"{'no worse':>7s} | {'med ms':>6s} {'cur/CSM':>8s}",
    ]
    for r in result["rows"]:
        b, c, csm = r["baseline"], r["current"], r["csm"] or {}
        verdict = {True: "yes", False: "NO", None: "-"}[r["accuracy_no_worse"]]
        lines.append(
            f"  {r['dataset']:21s} {r['prior'] or '-':5s} {fmt(b['median_ms'], '.2f', 7)} "
            f"{fmt(c['median_ms'], '.2f', 7)} {fmt(r['ratio_median'], '.2f', 6)}   "
            f"{fmt(b['cpu_ms_per_scan'], '.2f', 7)} {fmt(c['cpu_ms_per_scan'], '.2f', 7)} "
            f"{fmt(r['ratio_cpu'], '.2f', 6)}  {fmt(r['ratio_p95'], '.2f', 5)} | "
            f"{_accuracy(b):>12s} {_accuracy(c):>12s} {verdict:>8s} | "
            f"{fmt(csm.get('median_ms'), '.2f', 6)} "
            f"{fmt(r.get('ratio_current_over_csm'), '.2f', 8)}"
        )
        for side, label in ((b, labels[0]), (c, labels[1])):
            if side.get("error"):
                lines.append(f"    {label} failed: {side['error']}")
    if result["skipped"]:
        lines.append(f"  skipped (data absent): {', '.join(result['skipped'])}")
    if result["csm_source"]:
        lines.append(f"  CSM columns: reference only, from {result['csm_source']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--only", nargs="*", help="dataset names to run")
    ap.add_argument("--repeat", type=int, default=1, help="timing repetitions per dataset")
    ap.add_argument("--times", action="store_true", help="--json: every per-scan time too")
    a = ap.parse_args(argv)
    result = run(a.only, a.repeat, a.times)
    print(json.dumps(result) if a.json else format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
