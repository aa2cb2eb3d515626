from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from mkflight.errors import ReplayError
from mkflight.logs.events import FILE_NAME, EventsWriter, event_json, read_events
from mkflight.logs.schema import (
    KINDS,
    UNSET,
    Crash,
    Failsafe,
    PilotOverride,
    Preflight,
    PreflightFigures,
    Ready,
    Scan,
    Stop,
    UnknownEvent,
)
from tests.logs import format1, records


def test_round_trip_one_object_per_line(tmp_path: Path) -> None:
    with EventsWriter(tmp_path) as w:
        w.write(Failsafe(t_ns=1_000, action="LAND", cause="laser_stale"))
        w.write(records.step(2_000, math.nan, "HOLD", None))
    path = tmp_path / FILE_NAME
    assert path.read_text().splitlines() == [
        '{"t_ns":1000,"event":"failsafe","action":"LAND","cause":"laser_stale"}',
        '{"t_ns":2000,"event":"step","x_m":null,"y_m":0.0,"sp_x_m":null,"sp_y_m":null,'
        '"sp_height_m":null,"height_m":0.5,"vz_up_mps":0.0,"gas_counts":100,'
        '"battery_v":12.5,"phase":"HOLD","action":"NONE","latency_ms":1.25}',
    ]
    data = read_events(path)
    assert not data.truncated
    assert data.warnings == ()
    assert data.events == [
        Failsafe(t_ns=1_000, action="LAND", cause="laser_stale"),
        records.step(2_000, None, "HOLD", None),
    ]


def test_every_kind_round_trips_t_ns_first() -> None:
    """Each kind encodes as ``{"t_ns":..,"event":"<kind>",...}`` and decodes to itself."""
    samples = [
        records.step(5, 0.25, "HOLD", 0.0),
        records.scan(6, 1, 2, 3),
        records.scan(6, None, 2, 3, valid=False),
        Preflight.of(7, records.PREFLIGHT),
        Ready(t_ns=8),
        Stop(t_ns=9, request="sigint", reason="SIGINT", steps=None),
        PilotOverride(t_ns=10, moved={3: 120}),
        Crash(t_ns=11, task="laser", error="RuntimeError()"),
        Crash(t_ns=12, task="laser", error="RuntimeError()", exception="Traceback..."),
    ]
    for ev in samples:
        line = event_json(ev)
        obj = json.loads(line)
        assert list(obj)[:2] == ["t_ns", "event"]
        assert obj["event"] == ev.event
        assert msgspec.convert(obj, KINDS[ev.event], str_keys=True) == ev
    assert event_json(Ready(t_ns=-3)) == '{"t_ns":-3,"event":"ready"}'
    assert "exception" not in event_json(samples[-2])  # absent, not null
    assert json.loads(event_json(samples[6]))["moved"] == {"3": 120}


def test_every_known_kind_has_a_struct_named_in_the_union() -> None:
    assert set(KINDS) == {
        *("step", "scan", "failsafe", "phase", "preflight", "ready", "stop"),
        *("pilot_override", "stop_deadline", "crash", "laser_silent", "laser_lost"),
        *("laser_reopened", "end"),
    }
    for name, cls in KINDS.items():
        assert cls.__struct_fields__[0] == "t_ns", name
        assert cls.__struct_config__.tag == name


def test_preflight_event_and_summary_part_have_the_same_fields() -> None:
    assert Preflight.__struct_fields__[1:] == PreflightFigures.__struct_fields__
    ev = Preflight.of(1, records.PREFLIGHT)
    assert ev.fields == msgspec.structs.asdict(records.PREFLIGHT)


def test_format_1_lines_read_typed_and_write_back_byte_for_byte(tmp_path: Path) -> None:
    """A format-1 flight (mkflight 0.1.0's lines): every line a known kind, encoded
    again exactly as it was."""
    path = tmp_path / FILE_NAME
    path.write_text("".join(line + "\n" for line in format1.EVENT_LINES))
    data = read_events(path)
    assert data.warnings == ()
    assert [event_json(e) for e in data.events if not isinstance(e, UnknownEvent)] == list(
        format1.EVENT_LINES
    )
    kinds = [type(e).__name__ for e in data.events]
    assert kinds[:5] == ["Preflight", "Ready", "Scan", "Step", "Scan"]
    assert {"PhaseChange", "Stop", "Failsafe", "End"} <= set(kinds)


def test_older_shapes_of_known_kinds_read_typed(tmp_path: Path) -> None:
    """Format-1 lines of the shapes a reader still meets: a scan without its pose (a replay
    matches it again), a stop without steps (repeated at its time)."""
    path = tmp_path / FILE_NAME
    path.write_text(
        '{"t_ns":1,"event":"preflight","fc_version":"0.84a","debug_period_ms":53.5,'
        '"battery_v":12.6,"pitch_rad":-0.0017,"roll_rad":0.0035,"laser":"URG",'
        '"scan_period_ms":100.02,"ground_height_m":0.001}\n'
        '{"t_ns":2,"event":"ready"}\n'
        '{"t_ns":3,"event":"scan","index":1,"step":1,"seq":7,"valid":true,"height_m":0.3,'
        '"degenerate":false,"match_ms":1.5}\n'
        '{"t_ns":4,"event":"stop","request":"sigint","reason":"SIGINT"}\n'
        '{"t_ns":5,"event":"end","exit_reason":"SIGINT"}\n'
    )
    data = read_events(path)
    assert data.warnings == ()
    pre, ready, scan, stop, end = data.events
    assert isinstance(pre, Preflight)
    assert pre.ground_height_m == 0.001
    assert ready == Ready(t_ns=2)
    assert isinstance(scan, Scan)
    assert (scan.x_m, scan.got_ns, scan.seq) == (UNSET, None, 7)
    assert stop == Stop(t_ns=4, request="sigint", reason="SIGINT", steps=None)
    assert end.fields == {"exit_reason": "SIGINT"}


def test_events_are_flushed_as_written(tmp_path: Path) -> None:
    w = EventsWriter(tmp_path)
    w.write(Ready(t_ns=5))
    assert read_events(tmp_path / FILE_NAME).events == [Ready(t_ns=5)]
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.write(Ready(t_ns=6))


def test_t_ns_and_event_cannot_be_set_as_fields() -> None:
    """``event`` is the kind's tag, not a field; ``t_ns`` is every kind's first field."""
    with pytest.raises(TypeError, match="event"):
        Ready(t_ns=1, event="x")  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="t_ns"):
        Ready()  # type: ignore[call-arg]


def test_an_unknown_kind_is_kept_and_counted(tmp_path: Path) -> None:
    """A newer writer's kind: an UnknownEvent with its fields, one warning per kind."""
    path = tmp_path / FILE_NAME
    path.write_text(
        '{"t_ns": 1, "event": "ready"}\n'
        '{"t_ns": 2, "event": "thrust", "n": 4.5, "tags": ["a"]}\n'
        '{"t_ns": 3, "event": "thrust", "n": 5}\n'
    )
    data = read_events(path)
    assert data.events == [
        Ready(t_ns=1),
        UnknownEvent(2, "thrust", {"n": 4.5, "tags": ["a"]}),
        UnknownEvent(3, "thrust", {"n": 5}),
    ]
    assert data.warnings == (
        f"{path}:2: 2 'thrust' events of a kind not known here: kept as unknown events",
    )


def test_a_known_kind_that_does_not_fit_is_kept_as_unknown(tmp_path: Path) -> None:
    """Damaged fields are not a crash: the line is kept as read, with msgspec's reason."""
    path = tmp_path / FILE_NAME
    path.write_text(
        '{"t_ns": 1, "event": "scan", "index": 1, "seq": "7"}\n'
        '{"t_ns": 2, "event": "ready", "extra": [1]}\n'
    )
    data = read_events(path)
    bad, ready = data.events
    assert isinstance(bad, UnknownEvent)
    assert (bad.event, bad.fields["seq"]) == ("scan", "7")
    assert bad.problem == "Expected `int`, got `str` - at `$.seq`"
    assert ready == Ready(t_ns=2)  # a field it does not know is passed over
    (warning,) = data.warnings
    assert warning.startswith(f"{path}:1: 1 'scan' event not of the kind's shape: ")


def test_truncated_last_line_and_malformed_line(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_text('{"t_ns": 1, "event": "a"}\n{"t_ns": 2, "ev')
    data = read_events(path)
    assert data.truncated
    assert [e.t_ns for e in data.events] == [1]
    path.write_text('{"t_ns": 1, "event": "a"}\n[1, 2]\n')
    with pytest.raises(ReplayError, match=f"{FILE_NAME}:2: expected an object"):
        read_events(path)
    path.write_text('{"t_ns": 1.5, "event": "a"}\n')
    with pytest.raises(ReplayError, match=f"{FILE_NAME}:1: needs an integer t_ns"):
        read_events(path)


def test_a_line_nested_too_deep_is_a_replay_error_not_a_crash(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    path.write_text('{"t_ns": 1, "event": "x"}\n' + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ReplayError, match=r"events\.jsonl:2: nested too deeply"):
        read_events(path)


def test_numpy_scalars_are_written_as_the_numbers_they_hold(tmp_path: Path) -> None:
    with EventsWriter(tmp_path) as w:
        w.write(
            Scan(
                t_ns=5,
                index=np.int64(7),  # type: ignore[arg-type]
                step=1,
                seq=2,
                valid=np.bool_(True),  # type: ignore[arg-type]
                x_m=np.float64(0.25),
                height_m=np.float64("nan"),
                degenerate=False,
                match_ms=1.0,
            )
        )
    (ev,) = read_events(tmp_path / FILE_NAME).events
    assert isinstance(ev, Scan)
    assert (ev.index, ev.valid, ev.x_m, ev.height_m) == (7, True, 0.25, None)


def test_a_value_json_cannot_hold_is_a_type_error(tmp_path: Path) -> None:
    with EventsWriter(tmp_path) as w, pytest.raises(TypeError, match="'crash'"):
        w.write(Crash(t_ns=1, task="x", error=object()))  # type: ignore[arg-type]


def test_lines_in_blocks_reach_the_file_by_close_and_once_flushed(tmp_path: Path) -> None:
    w = EventsWriter(tmp_path)
    w.write(Ready(t_ns=1))
    path = tmp_path / FILE_NAME
    assert path.read_text() == '{"t_ns":1,"event":"ready"}\n'  # flushed as written
    w.flush_each_line = False  # a replay's: in blocks
    w.write(Ready(t_ns=2))
    assert path.read_text().count("\n") == 1
    w.flush_each_line = True  # what was held goes now
    assert path.read_text().count("\n") == 2
    w.flush_each_line = False
    w.write(Ready(t_ns=3))
    w.close()
    assert [e.t_ns for e in read_events(path).events] == [1, 2, 3]
