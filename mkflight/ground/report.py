"""The HTML flight report: one self-contained page of a flight folder (SPEC §6).

:func:`build_report` turns what :func:`mkflight.logs.load_flight` read into one HTML
document: the summary (how the flight ended, how long, the battery, the versions), a
timeline of the phases and failsafes (:mod:`.report_timeline`), the hover precision
beside TABLE IX (:mod:`.report_precision`), the step timing and CPU, the link counters
and the plots (:mod:`.report_plots`, PNG inline as ``data:`` URIs). It refers to no
other file and no network resource. What a folder lacks (no ``flight.json``: the
original system's two tables alone; no summary: a killed flight; no ``truth.txt``: a real
flight) is said in the section that needs it and listed at the top; nothing is
refused that :func:`~mkflight.logs.load_flight` reads.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import mkflight
from mkflight.errors import MkflightError
from mkflight.ground.report_html import (
    Cell,
    CellLike,
    bullet_list,
    fmt,
    kv_table,
    missing,
    num,
    page,
    para,
    png_figure,
    section,
    table,
)
from mkflight.ground.report_plots import PlotImages
from mkflight.ground.report_precision import hover_precision, precision_section
from mkflight.ground.report_timeline import PLANNED_CAUSE, timeline, timeline_svg
from mkflight.ground.report_timing import counters_section, finite, no_summary, timing_section
from mkflight.logs.flight import FlightData
from mkflight.logs.schema import (
    UNSET,
    FlightSummary,
    HoverSummary,
    Preflight,
    UnknownSummary,
)

FILE_NAME: Final = "report.html"
NOT_ANSWERED: Final = "not known (the FC did not answer)"
#: The events table stops here (a long laser stall logs one event every 0.3 s).
MAX_EVENT_ROWS: Final = 400
PLOT_CAPTIONS: Final = {
    "trajectory": "x-y path: the estimate (TABLE III), the truth when simulated, the set-point",
    "position": "x, y and height against time with their set-points",
    "velocity": "body velocity: the laser's B_Vel against the filter's B_esti_Vel (Fig 18/19)",
    "commands": "ControlPitch/Roll/Yaw, the sticks and the gas command (TABLE IV), MK counts",
    "battery": "battery voltage of the step events",
}


class ReportError(MkflightError):
    """The report cannot be written (exit 1)."""


def _battery(flight: FlightData) -> list[tuple[str, CellLike]]:
    """Battery voltage: the pre-flight check's, then start, end and minimum in flight."""
    rows: list[tuple[str, CellLike]] = []
    # The check's event: there in a killed flight's log too, which has no summary.
    checked = next((e for e in flight.events if isinstance(e, Preflight)), None)
    if checked is not None:
        rows.append(("battery at the pre-flight check", num(checked.battery_v, ".2f", "V")))
    for source, values in (("step events", flight.steps), ("DebugOut read", flight.samples)):
        volts = finite(values["battery_v"])
        if len(volts):
            rows.append(
                (
                    f"battery start / end / min ({source})",
                    Cell(f"{volts[0]:.2f} / {volts[-1]:.2f} / {volts.min():.2f} V", num=True),
                )
            )
            break
    return rows or [("battery", Cell("not recorded (no step events, no mk.raw)"))]


def _verdict(flight: FlightData) -> str:
    """The badge: landed and released, failed, or not known."""
    summary = flight.info.summary if flight.info is not None else None
    if isinstance(summary, FlightSummary):
        cls = "ok" if summary.exit_code == 0 else "bad"
        if cls == "ok" and _unplanned(summary.failsafes):
            cls = "warn"  # landed and released, after a failsafe nobody asked for
        text = f"exit {summary.exit_code}: {summary.end_reason} (phase {summary.final_phase})"
    elif isinstance(summary, HoverSummary):
        cls = "ok" if summary.landed and summary.released else "bad"
        text = f"sim hover: {summary.end}"
    else:
        cls, text = "unknown", no_summary(flight)
    return f'<span class="verdict {cls}">{Cell(text).html("span")}</span>'


def _unplanned(failsafes: list[str]) -> list[str]:
    """The failsafe decisions that were not a stop request (``stop_sigint``...)."""
    return [f for f in failsafes if PLANNED_CAUSE not in f]


def _flight_rows(s: FlightSummary) -> list[tuple[str, CellLike]]:
    unplanned = _unplanned(s.failsafes)
    rows: list[tuple[str, CellLike]] = [
        ("end reason", s.end_reason),
        ("exit code", Cell(str(s.exit_code), num=True, alarm=s.exit_code != 0)),
        ("final phase", s.final_phase),
        ("released (Config = 0 sent)", Cell(fmt(s.released), alarm=not s.released)),
        ("duration (wall)", num(s.duration_s, ".1f", "s")),
        ("flight (READY to the end)", num(s.flight_s, ".1f", "s")),
        ("failsafes", Cell("; ".join(s.failsafes) or "none", alarm=bool(unplanned))),
        ("estimator", f"{s.learned.filter}, hover gas {fmt(s.learned.hover_gas_counts, '.1f')}"),
    ]
    if s.log_error not in (UNSET, None):
        rows.append(("log error", Cell(str(s.log_error), alarm=True)))
    return rows


def _hover_rows(s: HoverSummary) -> list[tuple[str, CellLike]]:
    return [
        ("end (sim hover)", s.end),
        ("landed, released", f"{fmt(s.landed)}, {fmt(s.released)}"),
        ("simulated", num(s.sim_s, ".1f", "s")),
        ("in HOLD", num(s.hold_s, ".1f", "s")),
        ("hardest touchdown", num(s.touchdown_mps, ".3f", "m/s")),
        ("failsafes", "; ".join(s.failsafes) or "none"),
        ("airframe", f"{s.airframe_kind} (seed {s.airframe_seed})"),
    ]


def _summary_section(flight: FlightData, lacks: list[str]) -> str:
    """How it ended, how long, the versions, the battery; ``lacks`` gets a missing summary."""
    info = flight.info
    rows: list[tuple[str, CellLike]] = [("flight folder", str(flight.path.resolve()))]
    if info is not None:
        source = info.config_source  # None: a flight.json that does not record it
        rows += [
            ("start (UTC)", info.start_utc),
            ("mkflight version", info.mkflight_version),
            ("FC version", info.fc_version or NOT_ANSWERED),
            ("config source", source.describe() if source else "not recorded in flight.json"),
        ]
    summary = info.summary if info is not None else None
    body: list[str] = []
    if isinstance(summary, FlightSummary):
        rows += _flight_rows(summary)
    elif isinstance(summary, HoverSummary):
        rows += _hover_rows(summary)
    elif isinstance(summary, UnknownSummary):
        rows += [(str(k), str(v)) for k, v in summary.fields.items()]
        body.append(missing(f"summary of another version, shown as read: {summary.problem}"))
    else:
        body.append(missing(no_summary(flight)))
        lacks.append(no_summary(flight))
    rows += _battery(flight)
    rows.append(("steps, scans (events)", f"{len(flight.steps)}, {len(flight.scans)}"))
    return section("summary", "Summary", [kv_table(rows), *body])


def _timeline_section(flight: FlightData, lacks: list[str]) -> str:
    """The SVG timeline and its table of events; ``lacks`` gets a missing events log."""
    if not flight.events:
        text = "no timeline: the folder has no events.jsonl (phases and failsafes are in it)"
        lacks.append(text)
        return section("timeline", "Phases and failsafes", [missing(text)])
    tl = timeline(flight.events, flight.t0_ns)
    rows: list[list[CellLike]] = [
        [num(m.number), num(m.t_s, ".2f"), Cell(m.kind), Cell(m.text, alarm=m.alarm)]
        for m in tl.marks[:MAX_EVENT_ROWS]
    ]
    if len(tl.marks) > MAX_EVENT_ROWS:
        more = f"and {len(tl.marks) - MAX_EVENT_ROWS} more events (events.jsonl has them all)"
        rows.append([Cell(""), Cell(""), Cell("..."), Cell(more)])
    body = [
        timeline_svg(tl),
        para(
            f"The band: the phases. Below it the height estimate; dashed lines: the events "
            f"numbered as in the table (red: failsafes not asked for, crashes, the laser's "
            f"troubles). t = 0 s is {tl.zero}."
        ),
        table(("#", "t s", "event", "what"), rows),
    ]
    return section("timeline", "Phases and failsafes", body)


def _plots_section(plots: PlotImages, lacks: list[str]) -> str:
    if not plots.images:
        lacks.append(plots.missing)
        return section("plots", "Plots", [missing(plots.missing)])
    figures = [png_figure(name, png, PLOT_CAPTIONS.get(name, name)) for name, png in plots.images]
    return section("plots", "Plots", figures)


def _header(flight: FlightData) -> str:
    start = flight.info.start_utc if flight.info is not None else "start time not recorded"
    return (
        f"<header><h1>{Cell(f'Flight report: {flight.path.resolve().name}').html('span')}</h1>"
        f"{para(f'{flight.path.resolve()} · {start}', 'sub')}{_verdict(flight)}</header>"
    )


def _notes(lacks: Sequence[str], warnings: Sequence[str]) -> str:
    if not lacks and not warnings:
        return ""
    out = ['<div class="notes">']
    if lacks:
        out += [para("What this folder lacks:"), bullet_list(lacks)]
    if warnings:
        out += [para("The reader's warnings:"), bullet_list(warnings)]
    return "".join(out) + "</div>"


def build_report(flight: FlightData, plots: PlotImages) -> str:
    """The report of ``flight`` as one HTML document (module docstring)."""
    lacks: list[str] = []
    hp = hover_precision(flight)
    sections = [
        _summary_section(flight, lacks),
        _timeline_section(flight, lacks),
        precision_section(flight, hp),
        timing_section(flight, lacks),
        counters_section(flight),
        _plots_section(plots, lacks),
    ]
    lacks += [m for m in (hp.estimate_missing, hp.truth_missing) if m]
    footer = para(
        f"Made by mkflight {mkflight.__version__} from the flight folder alone; "
        "§, TABLE and Fig numbers are those of the 2011 QUT CyPhy MikroKopter documentation."
    )
    return page(
        f"Flight report: {flight.path.resolve().name}",
        [_header(flight), _notes(lacks, flight.warnings), *sections, f"<footer>{footer}</footer>"],
    )


def write_report(path: Path, html: str) -> Path:
    """Write ``html`` to ``path`` through a new temporary file renamed over it.

    A reader never sees half a page, and a symlink planted at ``path`` is replaced, not
    written through.

    Raises:
        ReportError: the folder cannot be written.
    """
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.unlink(missing_ok=True)
        with tmp.open("x", encoding="utf-8") as f:
            f.write(html)
        tmp.replace(path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)  # no half page left behind (a full disk, a folder)
        msg = f"{path}: cannot write the report: {err.strerror or err}"
        raise ReportError(msg) from err
    return path
