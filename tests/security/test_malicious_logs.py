"""Replay never executes what a log holds, and a hostile log ends in one line (issue 10).

A log folder is data from elsewhere. Nothing in ``mkflight/logs`` or ``mkflight/replay``
unpickles, evals, imports or runs anything named in it, nor loads YAML from it (JSON
only, decoded into builtins and then checked types); these runs hold the line: a YAML
python tag or a JSON "object hook" in ``flight.json`` is a string or an unknown key,
never a call (the marker file never appears). Absurd values (NaN, 1e400, numbers of
thousands of digits, times beyond what the lock-step loop runs on, nesting a hundred
thousand deep, a 100 MB ``flight.json``) end in one ``error:`` line naming the file, or
replay like any damaged input: never a traceback, never a hang.
"""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mkflight.replay.vloop import MAX_T_NS
from tests.flights import HOVER_SIM_1S
from tests.security.helpers import error_lines, mkflight, one_error

pytestmark = pytest.mark.background(HOVER_SIM_1S)  # recorded, flight

Event = dict[str, Any]


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    return tmp_path / "pwned"


def _replay(folder: Path, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    return mkflight("replay", str(folder), "--out", str(tmp_path / "out"), timeout=90)


def _ran_safely(done: subprocess.CompletedProcess[str]) -> None:
    """It replayed: a report, perhaps a failed determinism check; never a traceback."""
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode in (0, 1), done.stderr
    assert len(error_lines(done.stderr)) <= 1, done.stderr
    assert "ExternControl:" in done.stdout, done.stderr
    assert "\x1b" not in done.stdout + done.stderr


def _info(folder: Path) -> dict[str, Any]:
    info: dict[str, Any] = json.loads((folder / "flight.json").read_text())
    return info


def _tag(marker: Path) -> str:
    return f'!!python/object/apply:os.system ["touch {marker}"]'


# ----- flight.json ----------------------------------------------------------------------


def test_a_yaml_python_tag_as_the_whole_flight_json_is_not_json(
    flight: Path, tmp_path: Path, marker: Path
) -> None:
    (flight / "flight.json").write_text(_tag(marker) + "\n")
    line = one_error(_replay(flight, tmp_path), 1)
    assert f"{flight / 'flight.json'}: cannot read flight metadata" in line
    assert not marker.exists()


def test_yaml_python_tags_in_config_strings_stay_strings(
    flight: Path, tmp_path: Path, marker: Path
) -> None:
    info = _info(flight)
    info["config"]["logging"]["dir"] = _tag(marker)
    info["config"]["sim"]["fc"]["version"] = _tag(marker)
    info["mkflight_version"] = _tag(marker)
    (flight / "flight.json").write_text(json.dumps(info))
    done = _replay(flight, tmp_path)
    assert done.returncode == 0, done.stderr  # strings nothing reads as a path or as YAML
    assert "determinism check: passed" in done.stdout
    assert not marker.exists()


@pytest.mark.parametrize(
    ("where", "value", "says"),
    [
        ("config.mk", {"py/object": "os.system", "py/args": ["touch {m}"]}, "mk.py/object"),
        ("config.control", {"__class__": "os.system", "__reduce__": ["touch {m}"]}, "unknown"),
        ("config.safety", {"!!python/object/apply:os.system": ["touch {m}"]}, "unknown key"),
        ("config.control.kp_xy", "!!python/object/apply:os.system ['touch {m}']", "Expected"),
        ("config.mk.port", {"$type": "System.Diagnostics.Process", "cmd": "touch {m}"}, "mk.port"),
        ("config", "!!python/object/apply:os.system ['touch {m}']", "config: unexpected type"),
        ("summary", ["!!python/name:os.system", "touch {m}"], "summary: unexpected type"),
    ],
)
def test_json_object_hooks_are_unknown_keys_or_wrong_types(
    flight: Path, tmp_path: Path, marker: Path, where: str, value: Any, says: str
) -> None:
    info = _info(flight)
    *parents, key = where.split(".")
    node = info
    for p in parents:
        node = node[p]
    node[key] = json.loads(json.dumps(value).replace("{m}", str(marker)))
    (flight / "flight.json").write_text(json.dumps(info))
    line = one_error(_replay(flight, tmp_path), 1)
    assert str(flight / "flight.json") in line
    assert says in line
    assert not marker.exists()


def _escapes_in_a_key(text: str) -> str:
    """A config key with a newline and a terminal escape (the error line quotes keys)."""
    return text.replace('"mk": {', '"mk": {"k\\n\\u001b[2J": 1, ', 1)


def _set_kp(text: str) -> Callable[[str], str]:
    return lambda s: s.replace('"kp_xy": ', f'"kp_xy": {text}, "was": ', 1)


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (lambda s: "[" * 100_000 + "]" * 100_000, "cannot read flight metadata: maximum recursion"),
        (lambda s: s[:-2] + ', "x": ' + "[" * 100 + "]" * 100 + "}", "nested more than 32 deep"),
        (lambda s: s[:-2] + ', "x": ' + "9" * 5000 + "}", "cannot read flight metadata: Exceeds"),
        (_set_kp("NaN"), "control.kp_xy: Expected `float`, got `null`"),
        (_set_kp("Infinity"), "control.kp_xy: Expected `float`, got `null`"),
        (_set_kp("1e400"), "control.kp_xy: Expected `float`, got `null`"),
        (_set_kp("1" + "0" * 400), "control.kp_xy: Number out of range"),
        (_escapes_in_a_key, r"unknown field `k\n\x1b[2J`"),  # escaped: one inert line
    ],
    ids=["nested-1e5", "nested-100", "digits", "nan", "infinity", "1e400", "big-int", "escapes"],
)
def test_absurd_flight_json_is_one_error_line_naming_it(
    flight: Path, tmp_path: Path, edit: Callable[[str], str], says: str
) -> None:
    path = flight / "flight.json"
    path.write_text(edit(json.dumps(_info(flight), indent=2)))
    line = one_error(_replay(flight, tmp_path), 1)
    assert str(path) in line
    assert says in line


def test_a_100_mb_flight_json_is_refused_unread(flight: Path, tmp_path: Path) -> None:
    info = _info(flight)
    info["mkflight_version"] = "A" * 100_000_000
    path = flight / "flight.json"
    path.write_text(json.dumps(info))
    line = one_error(_replay(flight, tmp_path), 1)
    assert f"{path}: cannot read flight metadata: " in line
    assert "more than the 16777216 such a file holds" in line


# ----- events.jsonl ---------------------------------------------------------------------


def _events(folder: Path) -> list[Event]:
    lines = (folder / "events.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


def _write_events(folder: Path, events: list[Event], extra: str = "") -> None:
    text = "".join(json.dumps(e) + "\n" for e in events)  # NaN, Infinity as JS tokens
    (folder / "events.jsonl").write_text(text + extra)


def _edit_scans(**fields: Any) -> Callable[[list[Event]], list[Event]]:
    return lambda evs: [{**e, **fields} if e["event"] == "scan" else e for e in evs]


def _edit_stop(**fields: Any) -> Callable[[list[Event]], list[Event]]:
    return lambda evs: [{**e, **fields} if e["event"] == "stop" else e for e in evs]


SAFE_EVENT_EDITS: dict[str, Callable[[list[Event]], list[Event]]] = {
    "nan-pose": _edit_scans(x_m=float("nan"), height_m=float("nan"), yaw_rad=float("inf")),
    "huge-ints": _edit_scans(step=10**30, seq=10**30 + 1),
    "wrong-types": _edit_scans(x_m="1", y_m=[1], yaw_rad={"a": 1}, height_m=True, step="2"),
    "stop-at-step-1e30": _edit_stop(steps=10**30, request="sigterm"),
    "stop-reason": _edit_stop(reason="{0.__class__} %s %(x)s \x1b[2J\x1b]0;owned\x07\n"),
    "unknown-events": lambda evs: [
        *evs,
        {"t_ns": evs[-1]["t_ns"], "event": "__import__('os').system('true')", "x": [[{}]]},
        {"t_ns": evs[-1]["t_ns"], "event": "stop", "request": ["sigint"], "reason": None},
        {"t_ns": evs[-1]["t_ns"], "event": "ready", "step": -1},
    ],
}


@pytest.mark.parametrize("name", sorted(SAFE_EVENT_EDITS))
def test_odd_values_in_events_replay_safely(flight: Path, tmp_path: Path, name: str) -> None:
    _write_events(flight, SAFE_EVENT_EDITS[name](_events(flight)))
    _ran_safely(_replay(flight, tmp_path))


def _same(events: list[Event]) -> list[Event]:
    return events


NOT_INT = ":{line}: needs an integer t_ns"
BAD_EVENT_EDITS: dict[str, tuple[Callable[[list[Event]], list[Event]], str, str]] = {
    "ready-at-1e30": (
        lambda evs: [{**e, "t_ns": 10**30} if e["event"] == "ready" else e for e in evs],
        "('ready'): time 1000000000000000000000000000000 ns is outside",
        "",
    ),
    "got-beyond-the-loop": (
        _edit_scans(got_ns=MAX_T_NS + 1),
        "('scan') got_ns: time",
        "",
    ),
    "negative-time": (
        lambda evs: [{"t_ns": -1, "event": "stop", "request": "sigint"}, *evs],
        "event 1 ('stop'): time -1 ns is outside",
        "",
    ),
    "nested-1e5": (
        _same,
        ":{line}: nested too deeply to be an event",
        '{"t_ns": 1, "event": "x", "a": ' + "[" * 100_000 + "]" * 100_000 + "}\n",
    ),
    "nested-100": (
        _same,
        ":{line}: nested too deeply to be an event",
        '{"t_ns": 1, "event": "x", "a": ' + "[" * 100 + "]" * 100 + "}\n",
    ),
    "5000-digits": (
        _same,
        ":{line}: cannot decode: Exceeds",
        '{"t_ns": ' + "9" * 5000 + "}\n",
    ),
    "nan-time": (_same, NOT_INT, '{"t_ns": NaN, "event": "x"}\n'),
    "string-time": (_same, NOT_INT, '{"t_ns": "1", "event": 1}\n'),
    "a-list": (_same, ":{line}: expected an object, got list", "[1, 2]\n"),
    "1e400-time": (
        _same,
        NOT_INT,
        '{"t_ns": 1e400, "event": "x"}\n',
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_EVENT_EDITS))
def test_absurd_events_are_one_error_line_naming_the_file(
    flight: Path, tmp_path: Path, name: str
) -> None:
    edit, says, extra = BAD_EVENT_EDITS[name]
    events = _events(flight)
    _write_events(flight, edit(events), extra)
    line = one_error(_replay(flight, tmp_path), 1)
    assert str(flight / "events.jsonl") in line
    assert says.format(line=len(events) + 1) in line  # the odd line comes last


# ----- raw recordings -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("offset", "value", "says"),
    [
        (20, 2**62, "header: time 4611686018427387904 ns is outside"),  # start_t_ns
        (None, -1, "record 1: time -1 ns is outside"),  # the first record's t_ns
    ],
)
def test_raw_times_the_replay_cannot_run_at_are_refused(
    flight: Path, tmp_path: Path, offset: int | None, value: int, says: str
) -> None:
    path = flight / "mk.raw"
    blob = bytearray(path.read_bytes())
    if offset is None:
        (label_len,) = struct.unpack_from("<H", blob, 10)
        offset = 28 + label_len
    struct.pack_into("<q", blob, offset, value)
    path.write_bytes(bytes(blob))
    line = one_error(_replay(flight, tmp_path), 1)
    assert f"{path}: {says}" in line


# ----- the seed's two tables ------------------------------------------------------------


def _seed(flight: Path, tmp_path: Path, column: int, table: str, value: str) -> Path:
    seed = tmp_path / "seed"
    seed.mkdir()
    for name in ("imu_50ms.log", "laser_100ms.log"):
        shutil.copy(flight / name, seed / name)
    lines = (seed / table).read_text().splitlines()
    rows = [r.split() for r in lines[1:]]
    for row in rows:
        row[column] = value
    (seed / table).write_text("\n".join([lines[0], *(" ".join(r) for r in rows)]) + "\n")
    return seed


@pytest.mark.parametrize("value", ["nan", "1e300"])
def test_seed_poses_that_never_allow_a_take_off_end_the_replay(
    flight: Path, tmp_path: Path, value: str
) -> None:
    """TABLE III's pose unusable from row 0: the daemon stays on the ground, the replay
    ends (it ran on for good, writing logs, before)."""
    seed = _seed(flight, tmp_path, 6, "laser_100ms.log", value)  # CurrentPosition.x
    done = _replay(seed, tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert "did not take off within 30 s" in done.stderr
    assert "flight: no take-off in 30 s" in done.stdout


@pytest.mark.parametrize("value", ["1e300", "9" * 30, "9" * 5000])
def test_a_seed_count_beyond_int64_is_one_error_line(
    flight: Path, tmp_path: Path, value: str
) -> None:
    seed = _seed(flight, tmp_path, 6, "imu_50ms.log", value)  # ControlPitch, MK counts
    line = one_error(_replay(seed, tmp_path), 1)
    assert f"{seed / 'imu_50ms.log'}:2: column ControlPitch: cannot parse" in line
    assert len(line) < 300  # the 5000 digits are not all quoted
