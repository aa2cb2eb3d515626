"""The end-of-flight summary in ``flight.json`` (SPEC §6): why, timing, CPU, counters.

:func:`flight_summary` is a function of the figures the flight's collaborators hand
over at the end (the shell gathers them); it reads no clock and holds no reference.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, NamedTuple

from mkflight.control.phases import Phase
from mkflight.conversions import MS_PER_S
from mkflight.flight.preflight import PreflightReport
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
    RawCounters,
    Timing,
    from_plain,
)


class ProcessTimes(NamedTuple):
    """This process's CPU time and the wall clock, s: two readings give the CPU share."""

    cpu_s: float
    wall_s: float

    @classmethod
    def now(cls) -> ProcessTimes:
        """The two clocks now."""
        return cls(time.process_time(), time.perf_counter())


class MatcherFigures(NamedTuple):
    """The scan matcher's work over the flight: results got, their compute time (s)."""

    scans: int
    cpu_s: float


def end_reason(stop_reason: str, failsafes: Sequence[str], phase: Phase) -> str:
    """Why a flight without error ended: the stop request, else the failsafe that landed."""
    if stop_reason:
        return stop_reason
    return f"failsafe: {failsafes[0]}" if failsafes else f"phase {phase.name}"


def flight_summary(
    error: BaseException | None,
    *,
    stop_reason: str,
    phase: Phase,
    failsafes: Sequence[str],
    learned: dict[str, Any],
    released: bool,
    wall_s: float,
    cpu_s: float,
    flight_s: float,
    timing: dict[str, Any],
    hold_cpu: dict[str, float] | None,
    precision: dict[str, Any] | None,
    gc: dict[str, Any],
    matcher: MatcherFigures,
    preflight: PreflightReport | None,
    mk_link: dict[str, Any] | None,
    laser_link: object | None,
    raw: tuple[RawCounters, RawCounters] | None,
    log_error: OSError | None,
) -> FlightSummary:
    """The ``flight.json`` summary (:class:`~mkflight.logs.schema.FlightSummary`).

    Args:
        error: what ended the flight with exit 1 (None: it ended as asked).
        stop_reason: the first stop request's reason ("" if none came).
        phase: the phase machine's last phase.
        failsafes: the failsafe events, in order.
        learned: what the flight learned of its airframe.
        released: Config = 0 frames went out at the end.
        wall_s: wall time from the start of the flight's process work, s.
        cpu_s: this process's CPU time over ``wall_s``, s.
        flight_s: READY to the end, s (0 without READY).
        timing: the step timing figures.
        hold_cpu: CPU in HOLD, % of one core (None without a HOLD).
        precision: the HOLD precision estimate (None with too few samples).
        gc: the garbage collector's pauses.
        matcher: the scan matcher's counters.
        preflight: the pre-flight's report (None: it did not complete).
        mk_link: the MK link's counters (None: never opened).
        laser_link: the URG driver's stats (None: never opened).
        raw: the raw recorders' counters, ``mk.raw``'s and ``laser.raw``'s (None: no
            flight folder; then ``log_error`` is left out too).
        log_error: the write error that stopped the logs (None: none).
    """
    return FlightSummary(
        end_reason=str(error) if error is not None else end_reason(stop_reason, failsafes, phase),
        exit_code=0 if error is None and not log_error else 1,
        duration_s=round(wall_s, 3),
        flight_s=round(flight_s, 3),
        final_phase=phase.name,
        released=released,
        failsafes=list(failsafes),
        learned=from_plain(Learned, learned),
        timing=from_plain(Timing, timing),
        cpu_percent_of_one_core=round(100.0 * cpu_s / wall_s, 2) if wall_s > 0 else None,
        cpu_percent_in_hold=None if hold_cpu is None else from_plain(CpuInHold, hold_cpu),
        precision_estimate=None if precision is None else from_plain(PrecisionEstimate, precision),
        gc=from_plain(GcStats, gc),
        matcher=MatcherStats(
            scans=matcher.scans,
            cpu_ms_per_scan=round(MS_PER_S * matcher.cpu_s / matcher.scans, 3)
            if matcher.scans
            else None,
        ),
        preflight=UNSET if preflight is None else from_plain(PreflightFigures, preflight.as_dict()),
        mk_link=UNSET if mk_link is None else from_plain(MkLinkStats, mk_link),
        laser_link=UNSET if laser_link is None else from_plain(LaserLinkStats, _plain(laser_link)),
        mk_raw=UNSET if raw is None else raw[0],
        laser_raw=UNSET if raw is None else raw[1],
        log_error=UNSET if raw is None else None if log_error is None else str(log_error),
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
