"""The report's timing, CPU and link counters: what the daemon measured of itself.

They are the end-of-flight summary's (``flight.json``, :class:`~mkflight.logs.schema.
FlightSummary`): step latency (DebugOut read to ExternControl written), jitter, missed
steps, CPU, the MK and laser links' counters and the raw recorders'. A killed flight has
no summary: its latency is then taken from the ``step`` events, and what the files hold
is counted from them in any case.
"""

from __future__ import annotations

from typing import Any, Final

import msgspec
import numpy as np

from mkflight.ground.report_html import Cell, CellLike, fmt, kv_table, missing, num, para, section
from mkflight.logs.flight import FlightData
from mkflight.logs.schema import FlightSummary, HoverSummary

#: Counters whose every non-zero value is a fault worth a look (shown red).
ALARM_COUNTERS: Final = frozenset(
    (
        *("crc_errors", "malformed_frames", "overflows", "stale_releases", "blind_commands"),
        *("confirms_lost", "parser_sum_errors", "parser_malformed", "parser_overflows"),
        *("stalls", "stream_errors", "dropped", "missed_steps", "overruns"),
    )
)


def no_summary(flight: FlightData) -> str:
    """Why the folder has no summary: no ``flight.json``, or a flight that did not end."""
    if flight.info is None:
        return "no flight.json: the folder holds the original system's tables only"
    return "flight.json has no summary: the flight did not end (killed, or still running)"


def finite(values: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    """The finite values of a column, as float64 (NaN: a null in the events)."""
    arr = np.asarray(values, dtype=np.float64)
    return arr[np.isfinite(arr)]


def _timing_rows(s: FlightSummary) -> list[tuple[str, CellLike]]:
    t = s.timing
    return [
        ("steps", num(t.steps)),
        ("command latency median", num(t.latency_median_ms, ".2f", "ms")),
        ("command latency p99", num(t.latency_p99_ms, ".2f", "ms")),
        ("command latency max", num(t.latency_max_ms, ".2f", "ms")),
        ("added jitter p99 (latency step to step)", num(t.added_jitter_p99_ms, ".2f", "ms")),
        ("DebugOut interval median", num(t.period_median_ms, ".1f", "ms")),
        ("DebugOut jitter p99", num(t.jitter_p99_ms, ".1f", "ms")),
        ("missed steps", num(t.missed_steps, alarm=t.missed_steps > 0)),
        (
            "step busy median / p99",
            Cell(f"{fmt(t.busy_median_ms, '.2f')} / {fmt(t.busy_p99_ms, '.2f')} ms", num=True),
        ),
        ("restarted periods, overruns", f"{t.restarted_periods}, {t.overruns}"),
        ("delayed commands", num(t.delayed_commands)),
    ]


def _cpu_rows(s: FlightSummary) -> list[tuple[str, CellLike]]:
    rows: list[tuple[str, CellLike]] = [
        ("daemon, whole flight", num(s.cpu_percent_of_one_core, ".2f", "% of one core")),
    ]
    if s.cpu_percent_in_hold is not None:
        h = s.cpu_percent_in_hold
        rows += [
            (f"daemon in HOLD ({h.hold_s:.1f} s)", num(h.daemon, ".2f", "% of one core")),
            ("scan matcher in HOLD", num(h.matcher, ".2f", "% of one core")),
        ]
    rows += [
        (
            "scan matcher",
            f"{s.matcher.scans} scans, {fmt(s.matcher.cpu_ms_per_scan, '.3f')} ms a scan",
        ),
        (
            "garbage collector",
            f"{s.gc.collections} runs ({s.gc.full_collections} full), "
            f"max pause {s.gc.max_pause_ms:.3f} ms",
        ),
    ]
    return rows


def _step_timing(flight: FlightData) -> list[tuple[str, CellLike]]:
    """What the step events say of the timing, for a flight without a summary."""
    lat = finite(flight.steps["latency_ms"])
    period = np.diff(flight.steps["t_s"]) * 1000.0
    rows: list[tuple[str, CellLike]] = [("steps", num(len(flight.steps)))]
    if len(lat):
        rows += [
            ("command latency median", num(float(np.median(lat)), ".2f", "ms")),
            ("command latency p99", num(float(np.percentile(lat, 99)), ".2f", "ms")),
        ]
    if len(period):
        rows.append(("step interval median", num(float(np.median(period)), ".1f", "ms")))
    return rows


def timing_section(flight: FlightData, lacks: list[str]) -> str:
    """Steps and CPU from the summary, else from the step events; ``lacks`` gets why not."""
    summary = flight.info.summary if flight.info is not None else None
    if isinstance(summary, FlightSummary):
        body = [
            para("Latency: DebugOut read to ExternControl written (SPEC §9)."),
            '<div class="grid">',
            kv_table(_timing_rows(summary), "Steps"),
            kv_table(_cpu_rows(summary), "CPU"),
            "</div>",
        ]
    elif isinstance(summary, HoverSummary):
        body = [
            kv_table(
                [
                    (
                        "CPU a step (lock-step simulation)",
                        num(summary.cpu_us_per_step, ".1f", "µs"),
                    ),
                    ("simulated s per wall s", num(summary.realtime_factor, ".1f")),
                ]
            )
        ]
    elif len(flight.steps):
        body = [
            missing(f"{no_summary(flight)}: timing from the step events instead"),
            kv_table(_step_timing(flight)),
        ]
    else:
        text = "no timing: no summary and no step events"
        lacks.append(text)
        body = [missing(text)]
    return section("timing", "Timing and CPU", body)


def _struct_rows(value: msgspec.Struct) -> list[tuple[str, CellLike]]:
    """A counters Struct's fields by name; a fault counter above zero, or an error, red."""
    rows: list[tuple[str, CellLike]] = []
    for key, v in msgspec.structs.asdict(value).items():
        if isinstance(v, str) or v is None:  # a recorder's error, or none
            rows.append((key, Cell(v or "none", alarm=v is not None)))
        else:
            rows.append(
                (
                    key,
                    num(
                        v,
                        ".3f" if isinstance(v, float) else "",
                        alarm=bool(v) and key in ALARM_COUNTERS,
                    ),
                )
            )
    return rows


def _recorded_rows(flight: FlightData) -> list[tuple[str, CellLike]]:
    """What the folder's files hold, counted by the reader (there for any folder)."""
    return [
        ("ExternControl written (mk.raw)", num(len(flight.commands))),
        ("DebugOut read (mk.raw)", num(len(flight.samples))),
        ("TABLE IV rows (imu_50ms.log)", num(len(flight.imu))),
        ("TABLE III rows (laser_100ms.log)", num(len(flight.laser))),
        ("events (events.jsonl)", num(len(flight.events))),
    ]


def counters_section(flight: FlightData) -> str:
    """What the files hold, then the links' and recorders' counters of the summary."""
    summary = flight.info.summary if flight.info is not None else None
    tables = [kv_table(_recorded_rows(flight), "Recorded")]
    if isinstance(summary, FlightSummary):
        for title, value in (
            ("MK link", summary.mk_link),
            ("Laser link", summary.laser_link),
            ("mk.raw recorder", summary.mk_raw),
            ("laser.raw recorder", summary.laser_raw),
        ):
            if isinstance(value, msgspec.Struct):
                tables.append(kv_table(_struct_rows(value), title))
    body = [
        para(
            "Counters of the links and raw recorders at the end (flight.json); red: a "
            "non-zero fault counter."
        ),
        '<div class="grid">',
        *tables,
        "</div>",
    ]
    if not isinstance(summary, FlightSummary):
        text = f"no link counters: {no_summary(flight)}"
        body.append(missing(text))
    return section("counters", "Link counters", body)
