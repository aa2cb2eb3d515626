from __future__ import annotations

import json
import math
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import msgspec
import pytest

import mkflight
from mkflight.config import Config, config_to_dict
from mkflight.errors import ReplayError
from mkflight.logs.flight_json import (
    FILE_NAME,
    new_flight_info,
    read_flight_json,
    with_summary,
    write_flight_json,
)
from mkflight.logs.schema import UNSET, FlightSummary, HoverSummary, UnknownSummary
from tests.logs import format1, records

START = datetime(2024, 5, 1, 14, 0, 0, tzinfo=timezone(timedelta(hours=2)))


def test_round_trip_with_summary(tmp_path: Path) -> None:
    info = new_flight_info(START, Config(), fc_version="0.84a")
    assert info.start_utc == "2024-05-01T12:00:00.000000Z"
    assert info.mkflight_version == mkflight.__version__
    write_flight_json(tmp_path, info)
    assert read_flight_json(tmp_path) == info
    done = with_summary(info, records.summary(cpu_percent_of_one_core=math.nan, failsafes=[]))
    write_flight_json(tmp_path, done)
    back = read_flight_json(tmp_path / FILE_NAME)
    assert back.summary == records.summary(cpu_percent_of_one_core=None, failsafes=[])
    assert back.config == json.loads(json.dumps(config_to_dict(Config())))
    json.loads((tmp_path / FILE_NAME).read_text())  # strict JSON
    assert not (tmp_path / (FILE_NAME + ".tmp")).exists()


def test_naive_start_time_is_refused() -> None:
    with pytest.raises(ValueError, match="no time zone"):
        new_flight_info(datetime(2024, 5, 1), Config())


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path: Path) -> None:
    info = new_flight_info(datetime(2024, 1, 1, tzinfo=UTC), Config())
    write_flight_json(tmp_path, info)
    with pytest.raises(TypeError):
        write_flight_json(tmp_path, with_summary(info, records.summary(end_reason=object())))
    assert read_flight_json(tmp_path) == info


def test_reader_errors_name_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_text("{")
    with pytest.raises(ReplayError, match=f"{FILE_NAME}: cannot read"):
        read_flight_json(path)
    path.write_text('{"start_utc": "x"}')
    with pytest.raises(ReplayError, match="missing key 'mkflight_version'"):
        read_flight_json(path)


def test_a_format_1_flight_json_reads_typed_and_writes_back_byte_for_byte(
    tmp_path: Path,
) -> None:
    """A format-1 flight.json (mkflight 0.1.0's): the same bytes once read and written."""
    text = json.dumps(format1.FLIGHT_JSON, indent=2) + "\n"
    (tmp_path / FILE_NAME).write_text(text)
    info = read_flight_json(tmp_path)
    assert isinstance(info.summary, FlightSummary)
    assert info.summary.timing.steps == 1216
    assert info.summary.mk_raw is not UNSET
    assert info.summary.cpu_percent_in_hold is not None
    out = tmp_path / "again"
    out.mkdir()
    write_flight_json(out, info)
    assert (out / FILE_NAME).read_text() == text


def test_summaries_are_told_apart_by_their_keys(tmp_path: Path) -> None:
    info = new_flight_info(START, Config())
    hover = HoverSummary(
        std_x_m=0.01,
        std_y_m=None,
        std_z_m=0.005,
        rms_x_m=0.02,
        rms_y_m=0.02,
        rms_z_m=0.01,
        realtime_factor=math.inf,
        log_dir="f",
        sim_s=20.0,
        hold_s=12.0,
        end="landed",
        landed=True,
        released=True,
        touchdowns_mps=[0.3],
        touchdown_mps=0.3,
        failsafes=[],
        cpu_us_per_step=80.0,
        max_height_m=0.7,
        final_height_m=0.0,
        scans=False,
        airframe_kind="nominal",
        airframe_seed=0,
        airframe={"mass_kg": 1.2, "rotors": 4, "gear": True, "inertia": [0.1, 0.2]},
        learned=records.LEARNED,
    )
    write_flight_json(tmp_path, with_summary(info, hover))
    back = read_flight_json(tmp_path)
    assert back.summary == msgspec.structs.replace(hover, realtime_factor=None)
    data = json.loads((tmp_path / FILE_NAME).read_text())
    for summary, why in [
        ({"end_reason": "x"}, "Object missing required field `exit_code`"),
        ({"end": "landed", "std_x_m": "far"}, "Expected `float | null`, got `str`"),
        ({"duration_s": 3.0}, "neither an end_reason nor an end key"),
    ]:
        data["summary"] = summary
        (tmp_path / FILE_NAME).write_text(json.dumps(data))
        unknown = read_flight_json(tmp_path).summary
        assert isinstance(unknown, UnknownSummary)
        assert unknown.fields == summary
        assert why in unknown.problem
