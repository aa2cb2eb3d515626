"""The end-of-flight summary in ``flight.json`` (SPEC §6): why, timing, CPU, counters."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from mkflight.clock import NS_PER_S
from mkflight.logs.schema import (
    UNSET,
    CpuInHold,
    FlightSummary,
    GcStats,
    LaserLinkStats,
    Learned,
    MatcherStats,
    MkLinkStats,
    PrecisionEstimate,
    PreflightFigures,
    Timing,
    from_plain,
)

if TYPE_CHECKING:
    from mkflight.flight.app import FlightApp


def end_reason(app: FlightApp) -> str:
    """Why a flight without error ended: the stop request, else the failsafe that landed."""
    if app.stop_reason:
        return app.stop_reason
    events = app.core.counters.failsafe_events
    return f"failsafe: {events[0]}" if events else f"phase {app.core.phase.name}"


def flight_summary(app: FlightApp, error: BaseException | None, released: bool) -> FlightSummary:
    """The ``flight.json`` summary of ``app``'s flight (``released``: Config = 0 went out)."""
    wall_s = time.perf_counter() - app.wall0_s
    cpu_s = time.process_time() - app.cpu0_s
    cpu_in_hold = app.monitor.cpu_percent()
    precision = app.monitor.precision()
    logs = app.logs
    raw = logs.raw_counters() if logs is not None else (UNSET, UNSET)
    return FlightSummary(
        end_reason=str(error) if error is not None else end_reason(app),
        exit_code=0 if error is None and not (logs and logs.error) else 1,
        duration_s=round(wall_s, 3),
        flight_s=round((app.clock.now_ns() - app.start_ns) / NS_PER_S, 3) if app.start_ns else 0.0,
        final_phase=app.core.phase.name,
        released=released,
        failsafes=list(app.core.counters.failsafe_events),
        learned=from_plain(Learned, app.core.learned()),
        timing=from_plain(Timing, app.stats.summary()),
        cpu_percent_of_one_core=round(100.0 * cpu_s / wall_s, 2) if wall_s > 0 else None,
        cpu_percent_in_hold=None if cpu_in_hold is None else from_plain(CpuInHold, cpu_in_hold),
        precision_estimate=None if precision is None else from_plain(PrecisionEstimate, precision),
        gc=from_plain(GcStats, app.gc_watch.summary()),
        matcher=MatcherStats(
            scans=app.matches,
            cpu_ms_per_scan=round(1000 * app.monitor.matcher_cpu_s / app.matches, 3)
            if app.matches
            else None,
        ),
        preflight=UNSET
        if app.preflight is None
        else from_plain(PreflightFigures, app.preflight.as_dict()),
        mk_link=UNSET if app.link is None else from_plain(MkLinkStats, app.link.stats.summary()),
        laser_link=UNSET
        if app.driver is None
        else from_plain(LaserLinkStats, _plain(app.driver.stats)),
        mk_raw=raw[0],
        laser_raw=raw[1],
        log_error=UNSET if logs is None else None if logs.error is None else str(logs.error),
    )


def _plain(stats: object) -> dict[str, Any]:
    """A stats dataclass's plain counters (ints and floats, nested one level)."""
    result: dict[str, Any] = {}
    for name in getattr(stats, "__slots__", ()) or vars(stats):
        value = getattr(stats, name)
        if isinstance(value, int | float | str):
            result[name] = value
        elif hasattr(value, "__slots__") or hasattr(value, "__dict__"):
            for sub in getattr(value, "__slots__", ()) or vars(value):
                v = getattr(value, sub)
                if isinstance(v, int | float):
                    result[f"{name}_{sub}"] = v
    return result
