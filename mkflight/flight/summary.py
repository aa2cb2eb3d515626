"""The end-of-flight summary in ``flight.json`` (SPEC §6): why, timing, CPU, counters."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from mkflight.conversions import MS_PER_S, NS_PER_S

if TYPE_CHECKING:
    from mkflight.flight.app import FlightApp


def end_reason(app: FlightApp) -> str:
    """Why a flight without error ended: the stop request, else the failsafe that landed."""
    if app.stop_reason:
        return app.stop_reason
    events = app.core.counters.failsafe_events
    return f"failsafe: {events[0]}" if events else f"phase {app.core.phase.name}"


def flight_summary(app: FlightApp, error: BaseException | None, released: bool) -> dict[str, Any]:
    """The ``flight.json`` summary of ``app``'s flight (``released``: Config = 0 went out)."""
    wall_s = time.perf_counter() - app.wall0_s
    cpu_s = time.process_time() - app.cpu0_s
    counters = app.core.counters
    out: dict[str, Any] = {
        "end_reason": str(error) if error is not None else end_reason(app),
        "exit_code": 0 if error is None and not (app.logs and app.logs.error) else 1,
        "duration_s": round(wall_s, 3),
        "flight_s": round((app.clock.now_ns() - app.start_ns) / NS_PER_S, 3)
        if app.start_ns
        else 0.0,
        "final_phase": app.core.phase.name,
        "released": released,
        "failsafes": list(counters.failsafe_events),
        "learned": app.core.learned(),
        "timing": app.stats.summary(),
        "cpu_percent_of_one_core": round(100.0 * cpu_s / wall_s, 2) if wall_s > 0 else None,
        "cpu_percent_in_hold": app.monitor.cpu_percent(),
        "precision_estimate": app.monitor.precision(),
        "gc": app.gc_watch.summary(),
        "matcher": {
            "scans": app.matches,
            "cpu_ms_per_scan": round(MS_PER_S * app.monitor.matcher_cpu_s / app.matches, 3)
            if app.matches
            else None,
        },
    }
    if app.preflight is not None:
        out["preflight"] = app.preflight.as_dict()
    if app.link is not None:
        out["mk_link"] = app.link.stats.summary()
    if app.driver is not None:
        out["laser_link"] = _plain(app.driver.stats)
    if app.logs is not None:
        out.update(app.logs.raw_summary())
        out["log_error"] = app.logs.error and str(app.logs.error)
    return out


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
