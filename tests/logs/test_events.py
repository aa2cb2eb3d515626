from __future__ import annotations

import math
from pathlib import Path

import pytest

from mkflight.errors import ReplayError
from mkflight.logs.events import FILE_NAME, Event, EventsWriter, read_events


def test_round_trip_one_object_per_line(tmp_path: Path) -> None:
    with EventsWriter(tmp_path) as w:
        w.write(1_000, "failsafe", action="land", cause="laser stale")
        w.write(2_000, "battery", battery_v=10.9, height_m=math.nan)
    path = tmp_path / FILE_NAME
    assert len(path.read_text().splitlines()) == 2
    data = read_events(path)
    assert not data.truncated
    assert data.events == [
        Event(1_000, "failsafe", {"action": "land", "cause": "laser stale"}),
        Event(2_000, "battery", {"battery_v": 10.9, "height_m": None}),
    ]


def test_events_are_flushed_as_written(tmp_path: Path) -> None:
    w = EventsWriter(tmp_path)
    w.write(5, "start")
    assert read_events(tmp_path / FILE_NAME).events == [Event(5, "start", {})]
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.write(6, "late")


def test_reserved_field_names(tmp_path: Path) -> None:
    with EventsWriter(tmp_path) as w, pytest.raises(ValueError, match="reserved"):
        w.write(1, "x", t_ns=2)


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
    import numpy as np

    with EventsWriter(tmp_path) as w:
        w.write(5, "x", a=np.float64(0.25), b=np.int64(7), c=np.bool_(True), d=np.float64("nan"))
    (ev,) = read_events(tmp_path / FILE_NAME).events
    assert ev.fields == {"a": 0.25, "b": 7, "c": True, "d": None}
