"""flight_summary: a function of the figures, its keys and the rules for why and how it ended."""

from __future__ import annotations

from typing import Any

from mkflight.control.phases import Phase
from mkflight.flight.summary import MatcherFigures, end_reason, flight_summary

KEYS = [
    "end_reason",
    "exit_code",
    "duration_s",
    "flight_s",
    "final_phase",
    "released",
    "failsafes",
    "learned",
    "timing",
    "cpu_percent_of_one_core",
    "cpu_percent_in_hold",
    "precision_estimate",
    "gc",
    "matcher",
]


def _summary(**changes: Any) -> dict[str, Any]:
    figures: dict[str, Any] = {
        "stop_reason": "",
        "phase": Phase.RELEASED,
        "failsafes": [],
        "learned": {},
        "released": True,
        "wall_s": 20.0,
        "cpu_s": 5.0,
        "flight_s": 18.12345,
        "timing": {"steps": 3},
        "hold_cpu": None,
        "precision": None,
        "gc": {"collections": 0},
        "matcher": MatcherFigures(scans=4, cpu_s=0.01),
        "preflight": None,
        "mk_link": None,
        "laser_link": None,
        "raw": None,
        "log_error": None,
    }
    figures.update(changes)
    error = figures.pop("error", None)
    return flight_summary(error, **figures)


def test_the_keys_and_the_figures_derived_from_the_values() -> None:
    out = _summary()
    assert list(out) == KEYS  # nothing opened: no preflight, links or raw counters
    assert out["exit_code"] == 0
    assert out["flight_s"] == 18.123
    assert out["cpu_percent_of_one_core"] == 25.0
    assert out["matcher"] == {"scans": 4, "cpu_ms_per_scan": 2.5}
    assert _summary(matcher=MatcherFigures(0, 0.0))["matcher"]["cpu_ms_per_scan"] is None
    assert _summary(wall_s=0.0)["cpu_percent_of_one_core"] is None


def test_why_it_ended_stop_request_then_failsafe_then_phase() -> None:
    assert end_reason("SIGTERM", ["laser_stale"], Phase.RELEASED) == "SIGTERM"
    assert end_reason("", ["laser_stale"], Phase.RELEASED) == "failsafe: laser_stale"
    assert end_reason("", [], Phase.LANDED) == "phase LANDED"
    out = _summary(error=RuntimeError("boom"), stop_reason="SIGTERM")
    assert (out["end_reason"], out["exit_code"]) == ("boom", 1)


def test_lost_logs_exit_1_and_are_named_with_the_raw_counters() -> None:
    raw = {"mk_raw": {"records": 1}, "laser_raw": {"records": 2}}
    out = _summary(raw=raw, log_error=OSError(28, "No space left on device"))
    assert out["exit_code"] == 1
    assert out["mk_raw"] == {"records": 1}
    assert "No space left" in out["log_error"]
    assert _summary(raw=raw)["log_error"] is None
