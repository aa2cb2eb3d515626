"""``replay`` writes only its new folder (issue 10), and reads a log folder harmlessly.

Where a replay writes comes from the command line only (``--out``, or ``LOGDIR-replay``
beside the folder named): never from what the log holds, though ``flight.json`` names
ports and a log dir and each raw recording names its port. Its ptys live in a private
temporary folder, removed at the end. A folder whose files are symlinks is only read
through them; a FIFO or a device in place of a log file is refused unread (a FIFO would
block the replay forever, ``/dev/zero`` would fill the memory).
"""

from __future__ import annotations

import json
import os
import shutil
import struct
from pathlib import Path

import pytest

from mkflight.logs.raw import read_raw
from tests.flights import HOVER_SIM_1S
from tests.security.helpers import mkflight, one_error, tree

pytestmark = pytest.mark.background(HOVER_SIM_1S)  # recorded, flight

Tree = dict[str, tuple[str, bytes | str]]
_HEADER = struct.Struct("<8sHHqq")  # mk.raw: magic, version, label length, start times
FILES = ["flight.json", "events.jsonl", "mk.raw", "laser.raw", "imu_50ms.log", "laser_100ms.log"]


def _relabel(raw: Path, label: str) -> None:
    """Give a raw recording another port label, and every 'o' record that text."""
    blob = raw.read_bytes()
    magic, version, _, wall, start = _HEADER.unpack_from(blob)
    rec = read_raw(raw)
    body = b"".join(
        struct.pack("<qcI", r.t_ns, r.kind.encode(), len(data)) + data
        for r in rec.records
        for data in [label.encode() if r.kind == "o" else r.data]
    )
    label_b = label.encode()
    raw.write_bytes(_HEADER.pack(magic, version, len(label_b), wall, start) + label_b + body)


def _new_entries(before: Tree, after: Tree) -> set[str]:
    assert all(after.get(k) == v for k, v in before.items())  # nothing changed or removed
    return set(after) - set(before)


def test_paths_in_the_log_are_never_written(flight: Path, tmp_path: Path) -> None:
    victims = {name: tmp_path / f"victim-{name}" for name in ("dir", "mk", "laser", "label")}
    info = json.loads((flight / "flight.json").read_text())
    info["config"]["logging"]["dir"] = str(victims["dir"])
    info["config"]["mk"]["port"] = str(victims["mk"])
    info["config"]["laser"]["port"] = str(victims["laser"])
    (flight / "flight.json").write_text(json.dumps(info))
    _relabel(flight / "mk.raw", str(victims["label"] / "mk"))
    _relabel(flight / "laser.raw", str(victims["label"] / "laser"))
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    before = tree(tmp_path)
    done = mkflight("replay", str(flight), "--out", str(tmp_path / "out"), tmpdir=tmpdir)
    assert "Traceback" not in done.stderr
    assert done.returncode in (0, 1), done.stderr  # the matcher ran again (mk, laser changed)
    assert "ExternControl:" in done.stdout  # it replayed
    new = _new_entries(before, tree(tmp_path))
    assert new == {"out", *(f"out/{n}" for n in FILES)}
    assert not any(v.exists() for v in victims.values())
    assert list(tmpdir.iterdir()) == []  # the ptys' folder is gone


def test_the_default_output_folder_comes_from_the_argument(flight: Path, tmp_path: Path) -> None:
    info = json.loads((flight / "flight.json").read_text())
    info["config"]["logging"]["dir"] = str(tmp_path / "elsewhere")
    (flight / "flight.json").write_text(json.dumps(info))
    before = tree(tmp_path)
    done = mkflight("replay", str(flight))
    assert done.returncode == 0, done.stderr
    assert f"-> {tmp_path / 'flight-replay'}" in done.stdout
    new = _new_entries(before, tree(tmp_path))
    assert new == {"flight-replay", *(f"flight-replay/{n}" for n in FILES)}


def test_a_folder_of_symlinks_to_outside_files_is_only_read(flight: Path, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    outside.mkdir()
    for name in FILES:
        shutil.move(flight / name, outside / name)
        (flight / name).symlink_to(outside / name)
    before = tree(tmp_path)
    done = mkflight("replay", str(flight), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    assert "determinism check: passed" in done.stdout
    new = _new_entries(before, tree(tmp_path))
    assert new == {"out", *(f"out/{n}" for n in FILES)}
    assert all(not (tmp_path / "out" / n).is_symlink() for n in FILES)


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("flight.json", "fifo"),
        ("mk.raw", "fifo"),
        ("events.jsonl", "fifo"),
        ("laser.raw", "/dev/zero"),
        ("events.jsonl", "/dev/zero"),
        ("flight.json", "/dev/urandom"),
        ("mk.raw", "directory"),
    ],
)
def test_a_fifo_or_device_in_place_of_a_log_is_refused_unread(
    flight: Path, tmp_path: Path, name: str, kind: str
) -> None:
    (flight / name).unlink()
    if kind == "fifo":
        fifo = tmp_path / "fifo"  # never opened for writing: a reader would block for good
        os.mkfifo(fifo)
        (flight / name).symlink_to(fifo)
    elif kind == "directory":
        (flight / name).mkdir()
    else:
        (flight / name).symlink_to(kind)
    done = mkflight("replay", str(flight), "--out", str(tmp_path / "out"), timeout=60)
    line = one_error(done, 1)
    assert f"{flight / name}: cannot read" in line
    assert "not a regular file" in line


def test_a_dangling_symlink_as_out_is_not_followed(flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    target = tmp_path / "target"
    out.symlink_to(target)
    done = mkflight("replay", str(flight), "--out", str(out))
    assert "cannot be created" in one_error(done, 2)
    assert not target.exists()
