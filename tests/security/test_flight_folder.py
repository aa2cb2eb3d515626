"""The flight folder (issue 10): made fresh, nothing written through a planted symlink.

``fly`` refuses a log dir that is not an empty folder before anything starts
(``commands.fly._folder``); :class:`FlightLogs` checks again as it creates the folder,
and every file in it is created, never opened if it exists: a symlink planted under one
of its names is not followed (O_EXCL), so a file elsewhere (``/etc/passwd``; here a
victim file in tmp_path) is never written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import pytest

from mkflight.clock import ManualClock
from mkflight.commands.fly import _folder
from mkflight.config import Config, load_config
from mkflight.errors import ConfigError, PreflightError
from mkflight.flight.flight_logs import TRUTH_FILE, FlightLogs
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import FILE_NAME, new_flight_info, write_flight_json
from mkflight.logs.raw import RawRecorder
from mkflight.logs.schema import Ready
from mkflight.logs.table3 import Table3Writer
from mkflight.logs.table4 import Table4Writer
from tests.logs import records
from tests.security.helpers import mkflight, one_error, tree

FOLDER_FILES = [
    "imu_50ms.log",
    "laser_100ms.log",
    "events.jsonl",
    "flight.json",
    "flight.json.tmp",
    "mk.raw",
    "laser.raw",
]
VICTIM_TEXT = b"root:x:0:0:root:/root:/bin/bash\n"


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file outside the flight folder that a planted symlink points at."""
    path = tmp_path / "victim"
    path.write_bytes(VICTIM_TEXT)
    return path


def _plant(folder: Path, name: str, target: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / name
    link.symlink_to(target)
    return link


def _logs(folder: Path) -> FlightLogs:
    return FlightLogs(
        folder,
        Config(),
        mk_port="/dev/ttyUSB0",
        laser_port="/dev/ttyACM0",
        clock=ManualClock(1_000),
        on_error=lambda err: None,
    )


def test_fly_refuses_a_log_dir_with_a_planted_symlink_before_starting(
    tmp_path: Path, victim: Path
) -> None:
    folder = tmp_path / "logs"
    _plant(folder, "imu_50ms.log", victim)
    before = tree(tmp_path)
    done = mkflight("fly", "--hover", "--sim", "--duration", "1", "--log-dir", str(folder))
    line = one_error(done, 2)
    assert f"log dir {str(folder)!r} is not empty" in line
    assert victim.read_bytes() == VICTIM_TEXT
    assert tree(tmp_path) == before  # nothing created, not even the simulator's truth


@pytest.mark.parametrize("kind", ["file", "dangling symlink", "symlink to a file"])
def test_fly_refuses_a_log_dir_that_is_not_a_folder(
    tmp_path: Path, victim: Path, kind: str
) -> None:
    path = tmp_path / "logs"
    if kind == "file":
        path.write_text("x")
    elif kind == "dangling symlink":
        path.symlink_to(tmp_path / "elsewhere" / "flight")
    else:
        path.symlink_to(victim)
    before = tree(tmp_path)
    done = mkflight("fly", "--hover", "--sim", "--log-dir", str(path))
    assert f"log dir {str(path)!r} is not a folder" in one_error(done, 2)
    assert tree(tmp_path) == before  # the symlink's target is not created either


def test_fly_refuses_a_log_dir_it_cannot_list(tmp_path: Path) -> None:
    folder = tmp_path / "logs"
    folder.mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Path, "iterdir", _denied)
        with pytest.raises(ConfigError, match="cannot be read: Permission denied"):
            _folder(Config(), str(folder))


def _denied(self: Path) -> None:
    raise PermissionError(13, "Permission denied", str(self))


def test_a_folder_made_under_logging_dir_stays_there(tmp_path: Path) -> None:
    cfg = load_config(None, [f"logging.dir={tmp_path / 'flights'}"])
    folder = _folder(cfg, None)
    assert folder.parent == Path(cfg.logging.dir)
    assert re.fullmatch(r"\d{4,}-\d{8}-\d{4}", folder.name)  # no '/', no '..'
    assert folder.is_dir()  # made new (mkdir), so empty: nothing planted in it
    assert not any(folder.iterdir())


@pytest.mark.parametrize("name", FOLDER_FILES)
def test_flight_logs_refuse_a_folder_with_a_planted_symlink(
    tmp_path: Path, victim: Path, name: str
) -> None:
    folder = tmp_path / "flight"
    _plant(folder, name, victim)
    with pytest.raises(PreflightError, match="is not empty: a flight folder is never"):
        _logs(folder)
    assert victim.read_bytes() == VICTIM_TEXT
    assert sorted(p.name for p in folder.iterdir()) == [name]


def test_a_truth_symlink_the_check_lets_through_is_never_written(
    tmp_path: Path, victim: Path
) -> None:
    """``truth.txt`` may be there (the simulator's); the daemon never writes it."""
    folder = tmp_path / "flight"
    _plant(folder, TRUTH_FILE, victim)
    logs = _logs(folder)
    logs.event(Ready(t_ns=2_000))
    logs.close(3_000, records.summary(end_reason="test"))
    assert victim.read_bytes() == VICTIM_TEXT
    kinds = {p.name: (p.is_file(), p.is_symlink()) for p in folder.iterdir()}
    assert kinds == {n: (True, False) for n in FOLDER_FILES if n != "flight.json.tmp"} | {
        TRUTH_FILE: (True, True)
    }


def test_a_fresh_folder_holds_only_new_regular_files(tmp_path: Path) -> None:
    folder = tmp_path / "a" / "flight"
    logs = _logs(folder)
    logs.close(2_000, records.summary())
    kinds = {p.name: (p.is_file(), p.is_symlink()) for p in folder.iterdir()}
    assert kinds == {n: (True, False) for n in FOLDER_FILES if n != "flight.json.tmp"}


# The second layer: each writer on its own creates its file, never opens one that exists.
WRITERS: dict[str, Callable[[Path], object]] = {
    "imu_50ms.log": Table4Writer,
    "laser_100ms.log": Table3Writer,
    "events.jsonl": EventsWriter,
    "mk.raw": lambda folder: RawRecorder(folder / "mk.raw", "/dev/ttyUSB0"),
}


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_no_writer_writes_through_a_symlink(tmp_path: Path, victim: Path, name: str) -> None:
    folder = tmp_path / "flight"
    _plant(folder, name, victim)
    with pytest.raises(FileExistsError):
        WRITERS[name](folder)
    assert victim.read_bytes() == VICTIM_TEXT
    dangling = tmp_path / "not-yet"
    (folder / name).unlink()
    (folder / name).symlink_to(dangling)  # O_CREAT alone would create the target
    with pytest.raises(FileExistsError):
        WRITERS[name](folder)
    assert not dangling.exists()


@pytest.mark.parametrize("name", ["flight.json.tmp", FILE_NAME])
def test_flight_json_is_not_written_through_a_symlink(
    tmp_path: Path, victim: Path, name: str
) -> None:
    """A link under the tmp name (or the final name) is replaced, its target untouched."""
    folder = tmp_path / "flight"
    _plant(folder, name, victim)
    info = new_flight_info(datetime.now(UTC), Config())
    path = write_flight_json(folder, info)
    assert victim.read_bytes() == VICTIM_TEXT
    assert path.is_file()
    assert not path.is_symlink()
    assert not os.path.lexists(folder / "flight.json.tmp")
