"""Damaged flight folders never hang a reader (issue 18): replay, analyze, plot, load_flight.

The folder is a real flight on real ptys (``mkflight sim`` and ``mkflight fly --mk-port
--laser-port``, ended by ``--duration``), the case a user replays. Each damage - a raw
file cut mid-record or mid-header or on a record boundary while the other goes on,
emptied, zero-filled, with garbage appended, its records out of time order or stamped
huge or negative; ``events.jsonl`` cut mid-line; ``flight.json`` missing or invalid; the
two raw files swapped - must end in one of two ways: a one-line ``error:`` naming the
file (exit 1), or a replay of the intact part with a ``warning:`` saying where it stops.
A hypothesis property applies random damage the same way. Every command runs in a
subprocess with a hard timeout (:data:`HARD_TIMEOUT_S`): a hang fails the test, no
wall-clock figure is asserted.
"""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mkflight.errors import ReplayError
from mkflight.logs import load_flight
from tests.background import Background, job

pytestmark = pytest.mark.background("damaged-hover-10s")

PY = sys.executable
#: Longer than any of these commands takes on a loaded CI machine; a hang is far beyond it.
HARD_TIMEOUT_S = 60.0
_HEADER = struct.Struct("<8sHHqq")
_RECORD = struct.Struct("<qcI")


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(
            [PY, *args],
            capture_output=True,
            text=True,
            timeout=HARD_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"hung: {' '.join(args)} did not end within {HARD_TIMEOUT_S:g} s")


@job("damaged-hover-10s")
def _fly_on_ptys(base: Path) -> Path:
    """A 10 s hover flown on real ptys against ``mkflight sim`` (as on hardware)."""
    folder = base / "flight"
    sim = subprocess.Popen(
        [PY, "-m", "mkflight", "sim", "--truth", str(base / "truth.txt"), "--seed", "5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert sim.stdout is not None
        paths = dict(sim.stdout.readline().split(maxsplit=1) for _ in range(2))
        fly = subprocess.run(
            [
                *(PY, "-m", "mkflight", "fly", "--hover", "--log-dir", str(folder)),
                *("--mk-port", paths["mk"].strip(), "--laser-port", paths["laser"].strip()),
                *("--duration", "10"),
            ],
            capture_output=True,
            text=True,
            timeout=120,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    finally:
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=30)
    assert fly.returncode == 0, fly.stderr
    return folder


@pytest.fixture(scope="module")
def recorded(background: Background) -> Path:
    """The background flight ``damaged-hover-10s`` (read-only: each test damages a copy)."""
    folder: Path = background.result("damaged-hover-10s")
    return folder


def _records(path: Path) -> list[tuple[int, int]]:
    """(byte offset, t_ns) of each record of a raw file."""
    blob = path.read_bytes()
    offset = _HEADER.size + _HEADER.unpack_from(blob)[2]
    out = []
    while offset + _RECORD.size <= len(blob):
        t_ns, _, length = _RECORD.unpack_from(blob, offset)
        out.append((offset, t_ns))
        offset += _RECORD.size + length
    return out


# --------------------------------------------------------------------------- damage


def _cut_at(name: str, where: str) -> Callable[[Path], None]:
    def damage(folder: Path) -> None:
        path = folder / name
        blob = path.read_bytes()
        offset, _ = _records(path)[len(_records(path)) // 2]
        cut = {"mid-record": offset + 5, "boundary": offset, "mid-header": 17}[where]
        path.write_bytes(blob[:cut])

    return damage


def _rewrite(name: str, how: Callable[[bytes], bytes]) -> Callable[[Path], None]:
    def damage(folder: Path) -> None:
        path = folder / name
        path.write_bytes(how(path.read_bytes()))

    return damage


def _stamp(name: str, value: int, *, header: bool = False) -> Callable[[Path], None]:
    def damage(folder: Path) -> None:
        path = folder / name
        blob = bytearray(path.read_bytes())
        offset = 20 if header else _records(path)[len(_records(path)) // 2][0]
        struct.pack_into("<q", blob, offset, value)
        path.write_bytes(bytes(blob))

    return damage


def _disorder(name: str) -> Callable[[Path], None]:
    def damage(folder: Path) -> None:
        path = folder / name
        blob = bytearray(path.read_bytes())
        recs = _records(path)
        for offset, t_ns in recs[len(recs) // 2 : len(recs) // 2 + 20]:
            struct.pack_into("<q", blob, offset, t_ns - 3_000_000_000)
        path.write_bytes(bytes(blob))

    return damage


def _swap(folder: Path) -> None:
    a, b, tmp = folder / "mk.raw", folder / "laser.raw", folder / "swap.tmp"
    a.rename(tmp)
    b.rename(a)
    tmp.rename(b)


def _unlink(name: str) -> Callable[[Path], None]:
    return lambda folder: (folder / name).unlink()


_GARBAGE = bytes(range(256)) * 20

#: name -> (damage, what must end it: "error" names the file; "warning" replays a part)
CASES: dict[str, tuple[Callable[[Path], None], str, str]] = {}
for _raw in ("mk.raw", "laser.raw"):
    CASES |= {
        f"{_raw} cut mid-record": (_cut_at(_raw, "mid-record"), "warning", f"{_raw}: ends early"),
        f"{_raw} cut mid-header": (_cut_at(_raw, "mid-header"), "error", f"{_raw}: byte 17"),
        f"{_raw} ends early": (_cut_at(_raw, "boundary"), "warning", f"{_raw}: ends early"),
        f"{_raw} empty": (_rewrite(_raw, lambda b: b""), "error", f"{_raw}: byte 0"),
        f"{_raw} zero-filled": (
            _rewrite(_raw, lambda b: bytes(len(b))),
            "error",
            f"{_raw}: byte 0",
        ),
        f"{_raw} garbage appended": (
            _rewrite(_raw, lambda b: b + _GARBAGE),
            "error",
            f"{_raw}: byte",
        ),
        f"{_raw} out of time order": (_disorder(_raw), "error", f"{_raw}: byte"),
        f"{_raw} huge time": (_stamp(_raw, 2**62), "error", f"{_raw}"),
        f"{_raw} negative time": (_stamp(_raw, -5), "error", f"{_raw}"),
        f"{_raw} huge start": (_stamp(_raw, 2**62, header=True), "error", f"{_raw}: header"),
        f"{_raw} negative start": (_stamp(_raw, -(2**62), header=True), "error", f"{_raw}: header"),
    }
CASES |= {
    "events.jsonl cut mid-line": (
        _rewrite("events.jsonl", lambda b: b[: len(b) // 2 + 7]),
        "warning",
        "events.jsonl: last line cut short",
    ),
    "flight.json missing": (_unlink("flight.json"), "error", "flight.json: missing"),
    "flight.json invalid": (
        _rewrite("flight.json", lambda b: b[: len(b) // 2]),
        "error",
        "flight.json: cannot read",
    ),
    "raw files swapped": (_swap, "error", "look swapped"),
}


def _damaged(recorded: Path, tmp_path: Path, damage: Callable[[Path], None]) -> Path:
    folder = tmp_path / "damaged"
    shutil.copytree(recorded, folder)
    damage(folder)
    return folder


def _lines(proc: subprocess.CompletedProcess[str], prefix: str) -> list[str]:
    return [ln for ln in proc.stderr.splitlines() if ln.startswith(prefix)]


def _judge(proc: subprocess.CompletedProcess[str], folder: Path) -> None:
    """Ended with an error line naming a file of the folder, or ran (a warning if cut)."""
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode in (0, 1), (proc.returncode, proc.stderr[-3000:])
    if proc.returncode == 1:
        errors = _lines(proc, "error:")
        assert len(errors) == 1, proc.stderr[-3000:]
        named = str(folder) in errors[0] or "determinism check failed" in errors[0]
        assert named, errors[0]


@pytest.mark.parametrize("case", list(CASES))
def test_a_damaged_folder_replays_its_intact_part_or_names_the_damage(
    case: str, recorded: Path, tmp_path: Path
) -> None:
    damage, outcome, says = CASES[case]
    folder = _damaged(recorded, tmp_path, damage)
    proc = _run("-m", "mkflight", "replay", str(folder), "--fast", "--out", str(tmp_path / "o"))
    _judge(proc, folder)
    if outcome == "error":
        assert proc.returncode == 1
        (line,) = _lines(proc, "error:")
        assert says in line, line
        assert str(folder) in line, line
    else:
        assert any(says in w for w in _lines(proc, "warning:")), proc.stderr[-3000:]
        # the intact part is reproduced exactly: the check passes up to the cut
        assert proc.returncode == 0, proc.stderr[-3000:]
    if not case.startswith(("mk.raw", "laser.raw")):  # analyze reads the tables and events
        _judge(_run("-m", "mkflight", "analyze", "precision", str(folder)), folder)


def test_the_issue_case_truncated_mk_raw_ends_naming_mk_raw(recorded: Path, tmp_path: Path) -> None:
    """Issue 18: mk.raw cut at half its length less 3 bytes, replayed --fast."""
    size = (recorded / "mk.raw").stat().st_size
    folder = _damaged(recorded, tmp_path, _rewrite("mk.raw", lambda b: b[: size // 2 - 3]))
    proc = _run("-m", "mkflight", "replay", str(folder), "--fast", "--out", str(tmp_path / "o"))
    _judge(proc, folder)
    assert any("mk.raw: ends early, at" in w for w in _lines(proc, "warning:")), proc.stderr


@pytest.mark.parametrize("case", ["mk.raw garbage appended", "raw files swapped"])
def test_load_flight_and_plot_name_the_damage(case: str, recorded: Path, tmp_path: Path) -> None:
    folder = _damaged(recorded, tmp_path, CASES[case][0])
    pytest.importorskip("matplotlib")
    plot = _run("-m", "mkflight", "plot", str(folder), "--out-dir", str(tmp_path / "png"))
    _judge(plot, folder)
    with pytest.raises(ReplayError, match=str(folder)):
        load_flight(folder)


# --------------------------------------------------------------------------- random damage

_FILES = ("mk.raw", "laser.raw", "events.jsonl", "flight.json", "imu_50ms.log", "laser_100ms.log")


@st.composite
def _random_damage(draw: st.DrawFn) -> tuple[str, str, float, bytes]:
    name = draw(st.sampled_from(_FILES))
    how = draw(st.sampled_from(["cut", "zero", "garbage", "flip", "delete"]))
    where = draw(st.floats(0.0, 1.0))
    junk = draw(st.binary(min_size=1, max_size=64))
    return name, how, where, junk


def _apply(folder: Path, name: str, how: str, where: float, junk: bytes) -> None:
    path = folder / name
    blob = path.read_bytes()
    at = int(where * len(blob))
    if how == "cut":
        path.write_bytes(blob[:at])
    elif how == "zero":
        path.write_bytes(blob[:at] + bytes(min(4096, len(blob) - at)) + blob[at + 4096 :])
    elif how == "garbage":
        path.write_bytes(blob[:at] + junk + blob[at:])
    elif how == "flip":
        path.write_bytes(blob[:at] + junk + blob[at + len(junk) :])
    else:
        path.unlink()


@settings(
    max_examples=int(os.environ.get("MKFLIGHT_DAMAGE_EXAMPLES", "12")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(damage=_random_damage())
def test_random_damage_never_hangs_and_never_crashes(
    damage: tuple[str, str, float, bytes], recorded: Path, tmp_path: Path
) -> None:
    folder = tmp_path / f"random-{os.urandom(4).hex()}"
    shutil.copytree(recorded, folder)
    _apply(folder, *damage)
    out = folder.with_name(folder.name + "-out")
    _judge(_run("-m", "mkflight", "replay", str(folder), "--fast", "--out", str(out)), folder)
    _judge(_run("-m", "mkflight", "analyze", "precision", str(folder)), folder)


# --------------------------------------------------------------------------- scanmatch

CLF = Path(__file__).resolve().parents[1] / "data" / "laser" / "synth_roomA_hover_100.clf.gz"


def _clf_cases() -> dict[str, Callable[[bytes, bytes], bytes]]:
    """name -> (the .gz bytes, the text bytes) -> the damaged file's bytes."""
    return {
        "log.clf:cut mid-line": lambda gz, text: text[: len(text) * 2 // 3],
        "log.clf:garbage appended": lambda gz, text: text + _GARBAGE,
        "log.clf:zero-filled": lambda gz, text: bytes(len(text)),
        "log.clf:huge and NaN ranges": lambda gz, text: (
            text.replace(b" 1.", b" 1e308 ", 40)
            .replace(b" 2.", b" nan ", 40)
            .replace(b" 3.", b" -inf ", 40)
        ),
        "log.clf.gz:cut": lambda gz, text: gz[: len(gz) // 2],
        "log.clf.gz:garbage appended": lambda gz, text: gz + _GARBAGE,
    }


@pytest.mark.parametrize("case", list(_clf_cases()))
def test_scanmatch_on_a_damaged_log_ends_with_the_scans_it_could_read_or_an_error(
    case: str, tmp_path: Path
) -> None:
    import gzip

    name, _ = case.split(":")
    gz = CLF.read_bytes()
    log = tmp_path / name
    log.write_bytes(_clf_cases()[case](gz, gzip.decompress(gz)))
    proc = _run("-m", "mkflight", "scanmatch", str(log), "-o", str(tmp_path / "traj.txt"))
    _judge(proc, tmp_path)
    if proc.returncode == 0:
        rows = (tmp_path / "traj.txt").read_text(encoding="utf-8").splitlines()
        assert rows, "a trajectory row per scan that could be read"
        assert all(len(r.split()) == 4 for r in rows if not r.startswith("#"))
