from __future__ import annotations

import json
import math
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

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

START = datetime(2024, 5, 1, 14, 0, 0, tzinfo=timezone(timedelta(hours=2)))


def test_round_trip_with_summary(tmp_path: Path) -> None:
    info = new_flight_info(START, Config(), fc_version="0.84a")
    assert info.start_utc == "2024-05-01T12:00:00.000000Z"
    assert info.mkflight_version == mkflight.__version__
    write_flight_json(tmp_path, info)
    assert read_flight_json(tmp_path) == info
    done = with_summary(info, {"duration_s": 12.5, "std_x_m": math.nan, "failsafes": []})
    write_flight_json(tmp_path, done)
    back = read_flight_json(tmp_path / FILE_NAME)
    assert back.summary == {"duration_s": 12.5, "std_x_m": None, "failsafes": []}
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
        write_flight_json(tmp_path, with_summary(info, {"bad": object()}))
    assert read_flight_json(tmp_path) == info


def test_reader_errors_name_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_text("{")
    with pytest.raises(ReplayError, match=f"{FILE_NAME}: cannot read"):
        read_flight_json(path)
    path.write_text('{"start_utc": "x"}')
    with pytest.raises(ReplayError, match="missing key 'mkflight_version'"):
        read_flight_json(path)
