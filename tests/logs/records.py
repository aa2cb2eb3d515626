"""Typed records with plausible values, for tests that write flight folders."""

from __future__ import annotations

import msgspec

from mkflight.logs.schema import FlightSummary as _FlightSummary
from mkflight.logs.schema import (
    GcStats,
    Learned,
    MatcherStats,
    PreflightFigures,
    Scan,
    Step,
    Timing,
)

PREFLIGHT = PreflightFigures(
    fc_version="0.84a",
    debug_period_ms=50.0,
    battery_v=12.6,
    pitch_rad=0.001,
    roll_rad=-0.002,
    laser="SOKUIKI Sensor URG-04LX",
    scan_period_ms=100.0,
    ground_height_m=0.001,
)

LEARNED = Learned(
    bias_level_mps2=[0.01, 0.02, 0.03],
    hover_gas_counts=101.5,
    vibration_mps2=[0.2, 0.2, 0.3],
    steady_s=12.0,
    bias_used_mps2=[0.01, 0.02, 0.03],
    filter="kalman",
    acc_noise_used_mps2=[0.2, 0.3],
    descents=[],
    handed_in_air=False,
)

TIMING = Timing(
    steps=3,
    latency_median_ms=1.5,
    latency_p99_ms=4.0,
    latency_max_ms=9.0,
    period_median_ms=50.0,
    jitter_p99_ms=7.0,
    added_jitter_p99_ms=4.5,
    missed_steps=0,
    busy_median_ms=1.7,
    busy_p99_ms=5.9,
    restarted_periods=1,
    overruns=0,
    delayed_commands=0,
)


def summary(**changes: object) -> _FlightSummary:
    """A daemon summary (``changes``: fields to replace)."""
    base = _FlightSummary(
        end_reason="--duration 20 s",
        exit_code=0,
        duration_s=25.0,
        flight_s=21.0,
        final_phase="RELEASED",
        released=True,
        failsafes=["t+20.00s LAND stop_duration"],
        learned=LEARNED,
        timing=TIMING,
        cpu_percent_of_one_core=7.0,
        cpu_percent_in_hold=None,
        precision_estimate=None,
        gc=GcStats(collections=1, full_collections=0, max_pause_ms=0.1),
        matcher=MatcherStats(scans=2, cpu_ms_per_scan=4.9),
        preflight=PREFLIGHT,
    )
    return msgspec.structs.replace(base, **changes)


def step(t_ns: int, x_m: float | None, phase: str, sp_m: float | None) -> Step:
    """A step event at ``t_ns``: position ``x_m``, set-point ``sp_m`` (all three axes)."""
    return Step(
        t_ns=t_ns,
        x_m=x_m,
        y_m=0.0,
        sp_x_m=sp_m,
        sp_y_m=sp_m,
        sp_height_m=sp_m,
        height_m=0.5,
        vz_up_mps=0.0,
        gas_counts=100,
        battery_v=12.5,
        phase=phase,
        action="NONE",
        latency_ms=1.25,
    )


def scan(t_ns: int, index: int | None, step: int, seq: int, *, valid: bool = True) -> Scan:
    """A scan event at ``t_ns`` with TABLE III row ``index`` (None: no row)."""
    return Scan(
        t_ns=t_ns,
        index=index,
        step=step,
        seq=seq,
        valid=valid,
        got_ns=t_ns + 20_000_000,
        x_m=0.5 if valid else None,
        y_m=-0.25 if valid else None,
        yaw_rad=0.125 if valid else None,
        height_m=0.3 if valid else None,
        degenerate=not valid,
        match_ms=2.0,
    )
