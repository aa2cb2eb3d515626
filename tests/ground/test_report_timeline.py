"""The report's timeline (pure): spans and marks from events, and the SVG drawn of them."""

from __future__ import annotations

import re

import pytest

from mkflight.ground.report_timeline import (
    MAX_POINTS,
    PHASE_COLOURS,
    nice_ticks,
    timeline,
    timeline_svg,
)
from mkflight.logs.events import Event
from mkflight.logs.schema import Crash, End, Failsafe, PhaseChange, Ready, Step, Stop

T0 = 5_000_000_000  # the flight clock's ns at the first step


def _step(t_s: float, height_m: float | None = 0.5) -> Step:
    return Step(
        t_ns=T0 + round(t_s * 1e9),
        height_m=height_m,
        vz_up_mps=0.0,
        gas_counts=100,
        battery_v=12.0,
        phase="HOLD",
        action="NONE",
    )


def _at(t_s: float) -> int:
    return T0 + round(t_s * 1e9)


def _flight() -> list[Event]:
    return [
        Ready(t_ns=_at(-0.1)),
        _step(0.0, 0.0),
        PhaseChange(t_ns=_at(0.5), to="TAKEOFF", reason="handshake confirmed"),
        _step(1.0, 0.3),
        PhaseChange(t_ns=_at(2.0), to="HOLD", reason="take-off height reached"),
        _step(5.0, 0.6),
        Failsafe(t_ns=_at(6.0), action="LEVEL_HOLD", cause="laser_stale"),
        Stop(t_ns=_at(8.0), request="duration", reason="--duration 8 s", steps=150),
        Failsafe(t_ns=_at(8.0), action="LAND", cause="stop_duration"),
        PhaseChange(t_ns=_at(8.0), to="LAND", reason="failsafe land"),
        _step(10.0, None),
        End(t_ns=_at(10.5), exit_reason="--duration 8 s"),
    ]


def test_phase_changes_make_spans_and_other_events_numbered_marks() -> None:
    tl = timeline(_flight(), t0_ns=0)
    assert tl.zero == "the first step"
    assert [(s.phase, s.start_s, s.end_s) for s in tl.spans] == [
        ("PREFLIGHT", -0.1, 0.5),
        ("TAKEOFF", 0.5, 2.0),
        ("HOLD", 2.0, 8.0),
        ("LAND", 8.0, 10.5),
    ]
    kinds = [(m.number, m.kind, m.alarm, m.drawn) for m in tl.marks]
    assert kinds == [
        (1, "ready", False, True),
        (2, "phase", False, False),
        (3, "phase", False, False),
        (4, "failsafe", True, True),  # laser_stale: nobody asked for it
        (5, "stop", False, True),
        (6, "failsafe", False, True),  # stop_duration: asked for
        (7, "phase", False, False),
        (8, "end", False, True),
    ]
    assert tl.marks[3].text == "failsafe LEVEL_HOLD: laser_stale"
    assert tl.height_t_s == (0.0, 1.0, 5.0)  # the step without a height is left out
    assert tl.height_m == (0.0, 0.3, 0.6)


def test_the_svg_groups_marks_at_one_time_and_colours_the_phases() -> None:
    svg = timeline_svg(timeline(_flight(), t0_ns=0))
    labels = re.findall(r'fill="#[0-9a-f]{6}">([0-9,]+)</text>', svg)
    assert labels == ["1", "4", "5,6", "8"]  # stop and failsafe at 8.0 s share a line
    assert f'fill="{PHASE_COLOURS["HOLD"]}"' in svg
    assert svg.count("<polyline") == 1
    assert "http" not in svg


def test_text_in_the_svg_is_escaped() -> None:
    events: list[Event] = [_step(0.0), Crash(t_ns=_at(1.0), task="<x>", error="a & <b>")]
    svg = timeline_svg(timeline(events, t0_ns=None))
    assert "&lt;x&gt;" in svg
    assert "a &amp; &lt;b&gt;" in svg
    assert "<b>" not in svg


def test_a_long_flight_s_height_is_thinned_to_max_points() -> None:
    events: list[Event] = [_step(k * 0.05, 0.6) for k in range(3 * MAX_POINTS + 1)]
    tl = timeline(events, t0_ns=None)
    assert len(tl.height_m) == 3 * MAX_POINTS + 1
    (points,) = re.findall(r'<polyline points="([^"]*)"', timeline_svg(tl))
    assert MAX_POINTS // 2 < len(points.split()) <= MAX_POINTS


def test_without_steps_time_counts_from_the_recordings_start() -> None:
    events: list[Event] = [Ready(t_ns=_at(1.0)), End(t_ns=_at(3.0), exit_reason=None)]
    tl = timeline(events, t0_ns=T0)
    assert tl.zero == "the start of the recordings"
    assert [m.t_s for m in tl.marks] == [1.0, 3.0]
    assert "no height" in timeline_svg(tl)


@pytest.mark.parametrize(
    ("start", "end", "ticks"),
    [
        (0.0, 24.4, [0.0, 5.0, 10.0, 15.0, 20.0]),
        (-0.03, 7.5, [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]),
        (0.0, 0.126, [0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12]),
    ],
)
def test_ticks_are_round(start: float, end: float, ticks: list[float]) -> None:
    assert nice_ticks(start, end) == pytest.approx(ticks)
