"""flight_summary: a function of the figures, its keys, the rules for why and how it ended, and
the summary's parts: each producer's plain values fit its Struct, key for key, in order
(a key one adds or drops must show here, not as a TypeError in a shutdown)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgspec
import pytest

from mkflight.config import Config, load_config
from mkflight.control.phases import Phase
from mkflight.flight.monitor import GcWatch
from mkflight.flight.stats import StepStats
from mkflight.flight.step import FlightCore
from mkflight.flight.summary import MatcherFigures, _plain, end_reason, flight_summary
from mkflight.logs.flight_json import to_plain
from mkflight.logs.schema import (
    GcStats,
    LaserLinkStats,
    Learned,
    MkLinkStats,
    RawCounters,
    Timing,
    from_plain,
)
from mkflight.mk.link_types import LinkStats
from mkflight.urg.driver_types import UrgStats

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
        "learned": FlightCore(Config()).learned(),
        "released": True,
        "wall_s": 20.0,
        "cpu_s": 5.0,
        "flight_s": 18.12345,
        "timing": StepStats().summary(),
        "hold_cpu": None,
        "precision": None,
        "gc": GcWatch().summary(),
        "matcher": MatcherFigures(scans=4, cpu_s=0.01),
        "preflight": None,
        "mk_link": None,
        "laser_link": None,
        "raw": None,
        "log_error": None,
    }
    figures.update(changes)
    error = figures.pop("error", None)
    out: dict[str, Any] = to_plain(flight_summary(error, **figures))
    return out


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
    def counters(records: int) -> RawCounters:
        return RawCounters(records=records, bytes_read=0, bytes_written=0, dropped=0, error=None)

    raw = (counters(1), counters(2))
    out = _summary(raw=raw, log_error=OSError(28, "No space left on device"))
    assert out["exit_code"] == 1
    assert out["mk_raw"]["records"] == 1
    assert out["laser_raw"]["records"] == 2
    assert "No space left" in out["log_error"]
    assert _summary(raw=raw)["log_error"] is None


def _same_keys_in_order(cls: type[msgspec.Struct], values: Mapping[str, Any]) -> None:
    typed = from_plain(cls, values)
    assert list(msgspec.to_builtins(typed)) == list(values)
    assert msgspec.to_builtins(typed) == msgspec.to_builtins(dict(values))


@pytest.mark.parametrize(
    ("cls", "values"),
    [
        (Timing, lambda: StepStats().summary()),
        (GcStats, lambda: GcWatch().summary()),
        (MkLinkStats, lambda: LinkStats().summary()),
        (LaserLinkStats, lambda: _plain(UrgStats())),
        (Learned, lambda: FlightCore(Config()).learned()),
        (
            Learned,
            lambda: FlightCore(load_config(None, ["estimation.filter=complementary"])).learned(),
        ),
    ],
    ids=["timing", "gc", "mk_link", "laser_link", "learned-kalman", "learned-complementary"],
)
def test_each_part_fits_its_producer(cls: type[msgspec.Struct], values: Any) -> None:
    _same_keys_in_order(cls, values())


def test_a_key_the_struct_lacks_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        from_plain(GcStats, {**GcWatch().summary(), "young": 3})
