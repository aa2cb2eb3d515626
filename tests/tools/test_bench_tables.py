"""tools/bench*.py's pure parts: ratios, CSM's table, pooled matcher runs, flight figures.

No flights and no timing here: the figures are made up, the arithmetic is checked.
"""

from __future__ import annotations

import math
from typing import Any

import bench_flight
import bench_scanmatch
import bench_trees
import pytest

README = """# data

## The anchor: CSM on these files

| dataset | prior | median ms | p95 ms | trans mean m | rot mean rad |
|---|---|---|---|---|---|
| synth_roomA_hover | zero | 1.51 | 2.20 | 0.0055 | 0.0037 |
| intel | odom | 0.31 | 0.46 | 0.0295 | 0.0079 |

| path | what | scans | size |
|---|---|---|---|
| `intel/intel.gt.txt` | poses | 910 | 0.45 |

## Sources

| not | this | table | 1 | 2 | 3 |
|---|---|---|---|---|---|
| x | y | 1 | 2 | 3 | 4 |
"""


def test_ratio_and_median_skip_missing_values() -> None:
    assert bench_trees.ratio(3.0, 2.0) == 1.5
    assert bench_trees.ratio(1.0, 0.0) is None
    assert bench_trees.ratio(None, 2.0) is None
    assert bench_trees.ratio(math.nan, 2.0) is None
    assert bench_trees.median_of([3.0, None, 1.0, math.nan, 2.0]) == 2.0
    assert bench_trees.median_of([None]) is None
    assert bench_trees.fmt(None, ".2f", 5) == "    -"
    assert bench_trees.fmt(1.234, ".2f", 5) == " 1.23"


def test_csm_rows_come_from_the_anchor_section_only() -> None:
    rows = bench_scanmatch.parse_csm_table(README)
    assert set(rows) == {"synth_roomA_hover", "intel"}
    assert rows["intel"] == {
        "median_ms": 0.31,
        "p95_ms": 0.46,
        "trans_m": 0.0295,
        "rot_rad": 0.0079,
    }
    assert bench_scanmatch.parse_csm_table("# no table here\n") == {}


def _run(times: list[float], trans: float, rot: float) -> dict[str, Any]:
    return {
        "prior": "odom",
        "times_ms": times,
        "median_ms": sorted(times)[len(times) // 2],
        "cpu_ms_per_scan": sum(times) / len(times),
        "trans_mean_m": trans,
        "rot_mean_rad": rot,
        "invalid": 0,
    }


def test_a_row_pools_both_trees_and_checks_accuracy() -> None:
    base = [_run([2.0, 4.0, 6.0], 0.0280, 0.0077), _run([4.0, 4.0, 4.0], 0.0280, 0.0077)]
    cur = [_run([1.0, 2.0, 3.0], 0.0279, 0.0078), _run([2.0, 2.0, 2.0], 0.0279, 0.0078)]
    csm = {"median_ms": 0.5, "p95_ms": 1.0, "trans_m": 0.03, "rot_rad": 0.008}
    row = bench_scanmatch.compare_row("intel", base, cur, csm)
    assert row["baseline"]["median_ms"] == 4.0
    assert row["current"]["median_ms"] == 2.0
    assert row["current"]["run_medians_ms"] == [2.0, 2.0]
    assert row["ratio_median"] == 0.5
    assert row["current"]["cpu_ms_per_scan"] == 2.0  # the median of the runs' means
    assert row["ratio_cpu"] == 0.5
    assert row["ratio_current_over_csm"] == 4.0
    assert row["accuracy_no_worse"] is False  # rot 7.8 mrad against 7.7: beyond the slack
    within_slack = [_run([1.0], 0.0280, 0.0077 + 0.00004)]
    assert bench_scanmatch.compare_row("intel", base, within_slack, None)["accuracy_no_worse"]


def test_a_tree_that_fails_leaves_its_side_empty() -> None:
    row = bench_scanmatch.compare_row(
        "fr079", [{"error": "ImportError: x"}], [_run([1.0], 0, 0)], None
    )
    assert row["baseline"]["error"] == "ImportError: x"
    assert row["ratio_median"] is None
    assert row["accuracy_no_worse"] is None
    table = bench_scanmatch.format_compare_table(
        {"repeat": 1, "rows": [row], "skipped": ["intel"], "csm_source": None},
        ("baseline", "current"),
    )
    assert "baseline failed: ImportError: x" in table
    assert "skipped (data absent): intel" in table


def _events(hold_from: int, hold_to: int) -> list[dict[str, Any]]:
    """Steps every 50 ms with HOLD on [hold_from, hold_to), scans back every 100 ms."""
    events: list[dict[str, Any]] = [
        {"t_ns": 100, "event": "preflight"},
        {"t_ns": 200, "event": "ready"},
    ]
    for k in range(40):
        t = 1000 + k * 50
        phase = "HOLD" if hold_from <= k < hold_to else ("TAKEOFF" if k < hold_from else "LAND")
        events.append({"t_ns": t, "event": "step", "phase": phase})
        if k % 2 == 0:
            events.append({"t_ns": t - 10, "event": "scan", "got_ns": t + 5})
    return events


def test_hold_counts_steps_and_scans_in_the_window() -> None:
    counts = bench_flight.hold_counts(_events(10, 30))
    assert counts["steps_in_hold"] == 20
    assert counts["scans_in_hold"] == 10
    assert (counts["ready_ns"], counts["preflight_ns"]) == (200, 100)


def _summary(daemon: float, matcher: float) -> dict[str, Any]:
    return {
        "end_reason": "--duration 60 s",
        "timing": {
            "latency_median_ms": 1.0,
            "latency_p99_ms": 2.0,
            "latency_max_ms": 3.0,
            "missed_steps": 0,
            "steps": 40,
        },
        "cpu_percent_in_hold": {"daemon": daemon, "matcher": matcher, "hold_s": 1.0},
        "matcher": {"scans": 20, "cpu_ms_per_scan": 2.0},
        "truth_precision": {"std_x_m": 0.01, "std_y_m": 0.02, "std_z_m": 0.005},
    }


@pytest.mark.parametrize(
    ("worker", "own", "together"), [("process", 5.0, 7.0), ("inline", 3.0, 5.0)]
)
def test_flight_figures_take_the_matcher_out_of_the_daemon_when_inline(
    worker: str, own: float, together: float
) -> None:
    run = {
        "summary": _summary(5.0, 2.0),
        "exit_code": 0,
        "spawn_ns": 0,
        "wall_s": 10.0,
        "tree_cpu_s": 2.5,
    }
    f = bench_flight.flight_figures(run, {"scanmatch": {"worker": worker}}, _events(10, 30))
    assert f["daemon_percent"] == 5.0
    assert f["daemon_without_matcher_percent"] == own
    assert f["daemon_with_matcher_percent"] == together
    assert f["cpu_us_per_step"] == pytest.approx(own / 100 * 1.0 / 20 * 1e6)
    assert f["matcher_cpu_ms_per_scan"] == pytest.approx(2.0 / 100 * 1.0 / 10 * 1e3)
    assert f["truth_std_y_mm"] == pytest.approx(20.0)
    assert f["tree_cpu_percent"] == 25.0
    assert f["startup_s"] is None  # READY 200 ns after spawn: not a start-up, clocks differ
    run["spawn_ns"] = 200 - 2_500_000_000
    assert bench_flight.flight_figures(run, {}, _events(10, 30))["startup_s"] == 2.5


def test_a_flight_without_summary_is_an_error_not_figures() -> None:
    run = {"summary": None, "exit_code": 2, "stderr_tail": "error: bad option", "spawn_ns": 0}
    f = bench_flight.flight_figures(run, {}, [])
    assert f == {"error": "no summary (exit 2): error: bad option"}
    assert bench_flight.medians([f])["latency_p99_ms"] is None
