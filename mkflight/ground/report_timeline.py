"""A flight's phases and failsafes on one time axis, for the HTML report: data and SVG.

:func:`timeline` reads the events of a flight folder (``events.jsonl``, SPEC §6): every
``phase`` change makes a span, and every event that is neither a ``step`` nor a ``scan``
(pre-flight, READY, stop requests, failsafes, crashes, the laser's troubles, the end) a
numbered mark. :func:`timeline_svg` draws the spans as a coloured band, the height of the
``step`` events below it and the marks as numbered lines, so that the numbers point into
the report's table of events.

Time zero is the first ``step`` event, as in the plots (:mod:`mkflight.analysis.plots`);
a folder without steps counts from its first event. Pure: no I/O, text escaped here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape
from typing import Final

from mkflight.conversions import NS_PER_S
from mkflight.logs.events import Event
from mkflight.logs.schema import (
    Crash,
    End,
    Failsafe,
    LaserLost,
    LaserReopened,
    LaserSilent,
    PhaseChange,
    PilotOverride,
    Preflight,
    Ready,
    Scan,
    Step,
    Stop,
    StopDeadline,
    UnknownEvent,
)

#: The band's colour of each phase (SPEC §4's phases); another phase is grey.
PHASE_COLOURS: Final = {
    "PREFLIGHT": "#d9d9d9",
    "HANDSHAKE": "#c6dbef",
    "TAKEOFF": "#9ecae1",
    "HOLD": "#74c476",
    "LAND": "#fdae6b",
    "LANDED": "#bcbddc",
    "RELEASED": "#e7e7e7",
}
OTHER_PHASE_COLOUR: Final = "#bdbdbd"
ALARM_COLOUR: Final = "#d62728"
NOTE_COLOUR: Final = "#6b6b6b"
#: A failsafe with this cause prefix was asked for (a stop request), not an alarm.
PLANNED_CAUSE: Final = "stop_"

_W: Final = 1000.0  # the SVG's user units: width
_LEFT: Final = 70.0  # room for the height axis' labels
_RIGHT: Final = 20.0
_BAND_Y: Final = 26.0
_BAND_H: Final = 28.0
_PLOT_Y: Final = 66.0
_PLOT_H: Final = 90.0
_H: Final = _PLOT_Y + _PLOT_H + 46.0
MAX_POINTS: Final = 2000
_MIN_GAP: Final = 14.0  # marks closer than this share one line and label


@dataclass(frozen=True, slots=True)
class Span:
    """One phase from ``start_s`` to ``end_s`` (s from time zero)."""

    phase: str
    start_s: float
    end_s: float
    reason: str


@dataclass(frozen=True, slots=True)
class Mark:
    """One event of the table: its number, time (s), kind and what it says.

    ``alarm``: a failsafe not asked for, a crash, the laser lost or silent.
    ``drawn``: it is a line in the SVG (a phase change is the band's edge instead).
    """

    number: int
    t_s: float
    kind: str
    text: str
    alarm: bool
    drawn: bool


@dataclass(frozen=True, slots=True)
class Timeline:
    """The spans, the marks, the time axis' end and the height trace (s, m)."""

    spans: tuple[Span, ...]
    marks: tuple[Mark, ...]
    end_s: float
    height_t_s: tuple[float, ...]
    height_m: tuple[float, ...]
    zero: str


def _num(value: float | None, fmt: str, unit: str) -> str:
    return "?" if value is None or not math.isfinite(value) else f"{value:{fmt}} {unit}"


def _describe(e: Event) -> tuple[str, bool] | None:
    """An event's line in the table and whether it is an alarm; None for steps and scans."""
    match e:
        case Step() | Scan():
            return None
        case PhaseChange(to=to, reason=reason):
            return f"phase {to}: {reason}", False
        case Failsafe(action=action, cause=cause):
            return f"failsafe {action}: {cause}", not cause.startswith(PLANNED_CAUSE)
        case Preflight():
            return (
                f"pre-flight checks passed: FC {e.fc_version}, battery "
                f"{_num(e.battery_v, '.2f', 'V')}, {e.laser}, ground height "
                f"{_num(e.ground_height_m, '.3f', 'm')}"
            ), False
        case Ready():
            return "READY: the steps use DebugOut from here", False
        case Stop(request=request, reason=reason):
            return f"stop requested ({request}): {reason}", False
        case PilotOverride(moved=moved):
            sticks = ", ".join(f"channel {k} = {v}" for k, v in sorted(moved.items()))
            return f"pilot override: {sticks}", True
        case StopDeadline(error=error):
            return f"landing deadline passed: {error}", True
        case Crash(task=task, error=error):
            return f"crash in task {task}: {error}", True
        case LaserSilent(error=error):
            return f"laser silent: {error}", True
        case LaserLost(error=error):
            return f"laser lost: {error}", True
        case LaserReopened():
            return "laser port open again", False
        case End(exit_reason=reason):
            return f"flight folder closed: {reason or 'no reason given'}", False
        case UnknownEvent(event=event, problem=problem):
            why = f" ({problem})" if problem else " (a kind this version does not know)"
            return f"{event}{why}", False
    return None


def _zero_ns(events: Sequence[Event], t0_ns: int | None) -> tuple[int, str]:
    """Time zero: the first step, else the flight's t0, else the first event."""
    for e in events:
        if isinstance(e, Step):
            return e.t_ns, "the first step"
    if t0_ns is not None:
        return t0_ns, "the start of the recordings"
    return (events[0].t_ns if events else 0), "the first event"


def timeline(events: Sequence[Event], t0_ns: int | None) -> Timeline:
    """The phase spans, the numbered marks and the height trace of a flight's events."""
    zero_ns, zero = _zero_ns(events, t0_ns)
    marks: list[Mark] = []
    changes: list[tuple[float, str, str]] = []
    height_t: list[float] = []
    height: list[float] = []
    for e in events:
        t_s = (e.t_ns - zero_ns) / NS_PER_S
        if isinstance(e, Step) and e.height_m is not None and math.isfinite(e.height_m):
            height_t.append(t_s)
            height.append(e.height_m)
        if isinstance(e, PhaseChange):
            changes.append((t_s, e.to, e.reason))
        described = _describe(e)
        if described is not None:
            text, alarm = described
            drawn = not isinstance(e, PhaseChange)
            marks.append(Mark(len(marks) + 1, t_s, e.event, text, alarm, drawn))
    times = [m.t_s for m in marks] + height_t
    start_s = min([0.0, *times])
    end_s = max([start_s + 1.0, *times])
    spans: list[Span] = []
    phase, since, why = "PREFLIGHT", start_s, "start"
    for t_s, to, reason in changes:
        if t_s > since or spans:
            spans.append(Span(phase, since, t_s, why))
        phase, since, why = to, t_s, reason
    if events:
        spans.append(Span(phase, since, end_s, why))
    return Timeline(tuple(spans), tuple(marks), end_s, tuple(height_t), tuple(height), zero)


def _x(t_s: float, start_s: float, end_s: float) -> float:
    return _LEFT + (t_s - start_s) / (end_s - start_s) * (_W - _LEFT - _RIGHT)


def nice_ticks(start: float, end: float, count: float = 8.0) -> list[float]:
    """Round ticks (1, 2 or 5 times a power of ten apart), about ``count`` across."""
    raw = (end - start) / count
    step = 10 ** math.floor(math.log10(raw))
    for k in (1.0, 2.0, 5.0, 10.0):
        if raw <= k * step:
            step *= k
            break
    first = math.ceil(start / step) * step
    return [first + i * step for i in range(int((end - first) / step + 1e-9) + 1)]


def _band(tl: Timeline, start_s: float) -> list[str]:
    out: list[str] = []
    for s in tl.spans:
        x0, x1 = _x(s.start_s, start_s, tl.end_s), _x(s.end_s, start_s, tl.end_s)
        colour = PHASE_COLOURS.get(s.phase, OTHER_PHASE_COLOUR)
        tip = f"{s.phase} {s.start_s:.2f}-{s.end_s:.2f} s: {s.reason}"
        out.append(
            f'<rect x="{x0:.1f}" y="{_BAND_Y}" width="{max(x1 - x0, 0.5):.1f}" '
            f'height="{_BAND_H}" fill="{colour}" stroke="#ffffff">'
            f"<title>{escape(tip)}</title></rect>"
        )
        if x1 - x0 > 9.0 * len(s.phase) + 6.0:  # the name fits in its span
            out.append(
                f'<text x="{(x0 + x1) / 2:.1f}" y="{_BAND_Y + 18:.1f}" text-anchor="middle" '
                f'font-size="12">{escape(s.phase)}</text>'
            )
    return out


def _height(tl: Timeline, start_s: float) -> list[str]:
    out = [
        f'<rect x="{_LEFT}" y="{_PLOT_Y}" width="{_W - _LEFT - _RIGHT}" height="{_PLOT_H}" '
        'fill="none" stroke="#cccccc"/>'
    ]
    if not tl.height_m:
        out.append(
            f'<text x="{_W / 2}" y="{_PLOT_Y + _PLOT_H / 2}" text-anchor="middle" '
            f'font-size="12" fill="{NOTE_COLOUR}">no height: the folder has no step events</text>'
        )
        return out
    top_m = max(0.1, *tl.height_m)
    low_m = min(0.0, *tl.height_m)

    def y(h_m: float) -> float:
        return _PLOT_Y + _PLOT_H - (h_m - low_m) / (top_m - low_m) * _PLOT_H

    # At most MAX_POINTS vertices (a soak's 34 000 steps would not show more on 900 px).
    stride = max(1, math.ceil(len(tl.height_m) / MAX_POINTS))
    points = " ".join(
        f"{_x(t, start_s, tl.end_s):.1f},{y(h):.1f}"
        for t, h in zip(tl.height_t_s[::stride], tl.height_m[::stride], strict=True)
    )
    out.append(f'<polyline points="{points}" fill="none" stroke="#1f77b4" stroke-width="1.5"/>')
    for h_m in (low_m, top_m):
        out.append(
            f'<text x="{_LEFT - 6}" y="{y(h_m) + 4:.1f}" text-anchor="end" font-size="11">'
            f"{h_m:.2f} m</text>"
        )
    out.append(
        f'<text x="{_LEFT - 6}" y="{_PLOT_Y + _PLOT_H / 2 + 4:.1f}" text-anchor="end" '
        'font-size="11">height</text>'
    )
    return out


def _groups(tl: Timeline, start_s: float) -> list[list[Mark]]:
    """The drawn marks, those closer than :data:`_MIN_GAP` units merged into one line."""
    groups: list[list[Mark]] = []
    last_x = -math.inf
    for m in sorted((m for m in tl.marks if m.drawn), key=lambda m: m.t_s):
        x = _x(m.t_s, start_s, tl.end_s)
        if groups and x - last_x < _MIN_GAP:
            groups[-1].append(m)
        else:
            groups.append([m])
            last_x = x
    return groups


def _marks(tl: Timeline, start_s: float) -> list[str]:
    out: list[str] = []
    for group in _groups(tl, start_s):
        x = _x(group[0].t_s, start_s, tl.end_s)
        alarm = any(m.alarm for m in group)
        colour = ALARM_COLOUR if alarm else NOTE_COLOUR
        label = ",".join(str(m.number) for m in group)
        tip = "\n".join(f"{m.number}. {m.t_s:.2f} s {m.text}" for m in group)
        out.append(
            f"<g><title>{escape(tip)}</title>"
            f'<line x1="{x:.1f}" y1="{_BAND_Y - 4}" x2="{x:.1f}" y2="{_PLOT_Y + _PLOT_H}" '
            f'stroke="{colour}" stroke-width="{2 if alarm else 1}" stroke-dasharray="4 2"/>'
            f'<text x="{x:.1f}" y="{_BAND_Y - 8}" text-anchor="middle" font-size="11" '
            f'fill="{colour}">{escape(label)}</text></g>'
        )
    return out


def _legend(tl: Timeline) -> list[str]:
    """The colour of each phase the flight went through, in order, under the axis."""
    out: list[str] = []
    x = _LEFT
    seen: list[str] = []
    for s in tl.spans:
        if s.phase not in seen:
            seen.append(s.phase)
    for phase in seen:
        colour = PHASE_COLOURS.get(phase, OTHER_PHASE_COLOUR)
        out.append(
            f'<rect x="{x:.0f}" y="{_H - 14}" width="12" height="10" fill="{colour}" '
            f'stroke="#999999"/><text x="{x + 16:.0f}" y="{_H - 5}" font-size="11">'
            f"{escape(phase)}</text>"
        )
        x += 30.0 + 7.5 * len(phase)
    return out


def timeline_svg(tl: Timeline) -> str:
    """The timeline as an inline ``<svg>``: phase band, height, numbered marks, time axis."""
    start_s = min([0.0, *(s.start_s for s in tl.spans), *(m.t_s for m in tl.marks)])
    parts = [
        f'<svg viewBox="0 0 {_W:.0f} {_H:.0f}" '
        f'role="img" aria-label="phase and failsafe timeline" class="timeline" '
        f'font-family="sans-serif">',
        *_band(tl, start_s),
        *_height(tl, start_s),
        *_marks(tl, start_s),
        *_legend(tl),
    ]
    axis_y = _PLOT_Y + _PLOT_H
    for t in nice_ticks(start_s, tl.end_s):
        x = _x(t, start_s, tl.end_s)
        parts.append(
            f'<line x1="{x:.1f}" y1="{axis_y}" x2="{x:.1f}" y2="{axis_y + 5}" stroke="#333333"/>'
            f'<text x="{x:.1f}" y="{axis_y + 18}" text-anchor="middle" font-size="11">'
            f"{t:g}</text>"
        )
    parts.append(
        f'<text x="{_W - _RIGHT}" y="{_H - 5}" text-anchor="end" font-size="11">'
        f"{escape(f't (s) from {tl.zero}')}</text></svg>"
    )
    return "".join(parts)
