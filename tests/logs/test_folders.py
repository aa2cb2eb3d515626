"""mkflight.logs.folders: numbered flight folders, made atomically, and ``latest``."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from mkflight.commands.fly import _folder as fly_folder
from mkflight.config import load_config
from mkflight.errors import ConfigError
from mkflight.logs.folders import (
    LATEST,
    create_flight_folder,
    flight_folder_name,
    flight_number,
    next_flight_number,
    note_flight_folder,
)

MKFLIGHT = [sys.executable, "-m", "mkflight"]
WHEN = datetime(2026, 11, 26, 10, 57, 31)


def _at(when: datetime = WHEN) -> datetime:
    return when


def _numbers(base: Path) -> list[int]:
    return sorted(n for p in base.iterdir() if p.is_dir() and (n := flight_number(p.name)))


def test_names() -> None:
    assert flight_folder_name(42, WHEN) == "0042-20261126-1057"
    assert flight_folder_name(12345, WHEN) == "12345-20261126-1057"
    assert flight_number("0042-20261126-1057") == 42
    assert flight_number("0042-20261126-1057-replay") == 42
    assert flight_number("12345-20261126-1057") == 12345
    for foreign in ("flight-20261126-105700", "042-20261126-1057", "0042-2026112-1057", "latest"):
        assert flight_number(foreign) is None


def test_numbering_continues_after_gaps_and_foreign_folders(tmp_path: Path) -> None:
    base = tmp_path / "flights"
    first = create_flight_folder(base, now=_at)  # logging.dir is made
    assert first.path == base / "0001-20261126-1057"
    assert first.path.is_dir()
    assert not any(first.path.iterdir())
    (base / "0007-20200101-0000").mkdir()  # a gap
    (base / "flight-20261126-105700").mkdir()  # an older name
    (base / "9999 notes").mkdir()
    (base / "0050-20200101-0000").write_text("a file, not a flight")
    made = create_flight_folder(base, now=_at)
    assert made.path.name == "0008-20261126-1057"
    assert made.number == 8
    (base / "9999-20200101-0000").mkdir()
    assert create_flight_folder(base, now=_at).path.name == "10000-20261126-1057"
    assert next_flight_number(base) == 10001
    assert next_flight_number(tmp_path / "none") == 1


def test_a_name_taken_outside_the_lock_moves_on_to_the_next_number(tmp_path: Path) -> None:
    (tmp_path / "0003-20261126-1057").mkdir()
    # a file with the next name (not a flight folder, so not counted, but in the way)
    (tmp_path / "0004-20261126-1057").write_text("")
    assert create_flight_folder(tmp_path, now=_at).path.name == "0005-20261126-1057"


def test_latest_points_at_the_newest(tmp_path: Path) -> None:
    a = create_flight_folder(tmp_path, now=_at)
    assert a.latest_updated
    assert os.readlink(tmp_path / LATEST) == a.path.name  # relative: the tree can move
    b = create_flight_folder(tmp_path, now=lambda: WHEN + timedelta(minutes=3))
    assert (tmp_path / LATEST).resolve() == b.path.resolve()
    assert b.path.name == "0002-20261126-1100"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".latest")]  # no temp left


def test_a_dangling_or_foreign_latest(tmp_path: Path) -> None:
    (tmp_path / LATEST).symlink_to("0099-20000101-0000")  # dangling
    made = create_flight_folder(tmp_path, now=_at)
    assert made.latest_updated
    assert os.readlink(tmp_path / LATEST) == made.path.name
    (tmp_path / LATEST).unlink()
    (tmp_path / LATEST).write_text("the user's own file")
    made = create_flight_folder(tmp_path, now=_at)
    assert made.path.is_dir()  # the flight goes on
    assert not made.latest_updated
    assert made.latest_problem == f"{tmp_path / LATEST} is not a symlink: left alone"
    assert (tmp_path / LATEST).read_text() == "the user's own file"
    (tmp_path / LATEST).unlink()
    (tmp_path / LATEST).mkdir()
    made = create_flight_folder(tmp_path, now=_at)
    assert made.latest_problem is not None
    assert made.number == 3
    assert (tmp_path / LATEST).is_dir()
    assert not (tmp_path / LATEST).is_symlink()


def test_threads_starting_at_once_never_share_a_folder(tmp_path: Path) -> None:
    n = 12
    start = threading.Barrier(n)
    made: list[Path] = []
    errors: list[BaseException] = []

    def create(k: int) -> None:
        try:
            start.wait()
            # each sees another minute: the number, not the name, must be unique
            made.append(
                create_flight_folder(tmp_path, now=lambda: WHEN + timedelta(minutes=k)).path
            )
        except BaseException as err:  # pragma: no cover - reported below
            errors.append(err)

    threads = [threading.Thread(target=create, args=(k,)) for k in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(set(made)) == n
    assert _numbers(tmp_path) == list(range(1, n + 1))
    newest = max(made, key=lambda p: flight_number(p.name) or 0)
    assert os.readlink(tmp_path / LATEST) == newest.name


def test_processes_starting_at_once_never_share_a_folder(tmp_path: Path) -> None:
    code = (
        "import sys; from mkflight.logs.folders import create_flight_folder; "
        "sys.stdin.read(); print(create_flight_folder(sys.argv[1]).path)"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(tmp_path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(4)
    ]
    outs = [p.communicate("go", timeout=60)[0].strip() for p in procs]  # released together
    assert all(p.returncode == 0 for p in procs)
    assert len(set(outs)) == 4
    assert _numbers(tmp_path) == [1, 2, 3, 4]
    assert os.readlink(tmp_path / LATEST) == Path(max(outs, key=lambda s: Path(s).name)).name


def test_a_chosen_folder_moves_latest_only_when_it_is_the_newest_numbered_one(
    tmp_path: Path,
) -> None:
    base = tmp_path / "flights"
    first = create_flight_folder(base, now=_at)
    elsewhere = note_flight_folder(tmp_path / "mine", base)
    assert not elsewhere.latest_updated
    assert elsewhere.latest_problem is None
    assert os.readlink(base / LATEST) == first.path.name
    older = note_flight_folder(base / "0000-20261126-1057", base)
    assert not older.latest_updated
    chosen = note_flight_folder(base / "0002-20261126-1200", base)
    assert chosen.latest_updated
    assert os.readlink(base / LATEST) == "0002-20261126-1200"
    # a logging.dir not made yet is not made by noting a folder in it
    missing = tmp_path / "not-yet"
    noted = note_flight_folder(missing / "0001-20261126-1057", missing)
    assert not noted.latest_updated
    assert noted.latest_problem is None
    assert not missing.exists()


def test_a_planted_lock_symlink_is_refused(tmp_path: Path) -> None:
    (tmp_path / ".lock").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(ConfigError, match=r"logging\.dir .*cannot make a flight folder"):
        create_flight_folder(tmp_path)
    assert not (tmp_path / "elsewhere").exists()


def test_fly_and_sim_hover_make_numbered_folders(tmp_path: Path) -> None:
    base = tmp_path / "flights"
    cfg = load_config(None, [f"logging.dir={base}"])
    flown = fly_folder(cfg, None)
    assert flight_number(flown.name) == 1
    assert flown.is_dir()
    proc = subprocess.run(
        [*MKFLIGHT, "sim", "hover", "--duration", "6", "--json", "--set", f"logging.dir={base}"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    hovered = (base / LATEST).resolve()
    assert flight_number(hovered.name) == 2
    assert (hovered / "flight.json").is_file()
    assert str(hovered.name) in proc.stdout
    # the local wall time, to the minute
    stamp = datetime.strptime(hovered.name[5:], "%Y%m%d-%H%M")
    assert abs((datetime.now() - stamp).total_seconds()) < 180
