"""``mkflight replay`` end to end: a recorded simulated flight played back.

One real flight (``fly --hover --sim``) is recorded per session (a background flight, as
are a killed one and one on a slow board: :mod:`tests.background`); the tests replay it,
and damaged copies of it, through the CLI and through :func:`replay_flight`.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mkflight.errors import ReplayError
from mkflight.logs.flight import extern_control_frames
from mkflight.logs.raw import read_raw
from mkflight.logs.table4 import read_table4
from mkflight.replay.run import replay_flight
from tests.background import Background, job

pytestmark = pytest.mark.background("replay-hover-10s")

MKFLIGHT = [sys.executable, "-m", "mkflight"]


def _mkflight(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*MKFLIGHT, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        check=False,
    )


@job("replay-hover-10s")
def _fly_10s(base: Path) -> Path:
    folder = base / "flight"
    done = _mkflight("fly", "--hover", "--sim", "--duration", "10", "--log-dir", str(folder))
    assert done.returncode == 0, done.stderr
    return folder


@pytest.fixture(scope="module")
def flight(background: Background) -> Path:
    folder: Path = background.result("replay-hover-10s")
    return folder


def _copy(flight: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(flight, dst)
    return dst


def test_a_replay_reproduces_every_command_byte_and_both_tables(
    flight: Path, tmp_path: Path
) -> None:
    out = tmp_path / "replayed"
    done = _mkflight("replay", str(flight), "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["deterministic"] is True
    c = report["commands"]
    assert c["original"] == c["replayed"] == c["identical"] > 150
    assert c["first_difference"] is None
    for name in ("imu_50ms.log", "laser_100ms.log"):
        assert (out / name).read_bytes() == (flight / name).read_bytes()
    assert report["matcher"]["recorded_poses"] > 50
    # the replay wrote a complete flight folder of its own
    assert read_table4(out / "imu_50ms.log").rows.shape[0] > 150
    assert read_raw(out / "mk.raw").records


def test_the_text_report_says_the_check_passed(flight: Path, tmp_path: Path) -> None:
    done = _mkflight("replay", str(flight), "--out", str(tmp_path / "r"))
    assert done.returncode == 0, done.stderr
    assert "determinism check: passed (byte-identical)" in done.stdout
    assert "imu_50ms.log" in done.stdout


def test_matching_the_scans_again_gives_the_same_commands(flight: Path, tmp_path: Path) -> None:
    """The scan matcher is deterministic too: run it on the replayed scans."""
    r = replay_flight(flight, tmp_path / "r", rematch=True)
    assert r.rematch
    assert r.matcher["recorded_poses"] == 0
    assert r.commands.identical, r.commands.first
    assert r.deterministic


def test_a_what_if_gain_changes_the_commands_and_says_how(flight: Path, tmp_path: Path) -> None:
    done = _mkflight(
        "replay", str(flight), "--out", str(tmp_path / "r"), "--set", "control.kp_xy=0.8", "--json"
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    c = report["commands"]
    assert c["first_difference"] is not None
    assert c["identical"] < c["original"]
    moved = c["channels"]["nick"]["frames_differing"] + c["channels"]["roll"]["frames_differing"]
    assert moved > 0
    assert c["channels"]["gas"]["frames_differing"] == 0  # kp_xy is not the height loop
    assert report["overrides"] == ["control.kp_xy=0.8"]
    text = _mkflight(
        "replay", str(flight), "--out", str(tmp_path / "t"), "--set", "control.kp_xy=0.8"
    )
    assert text.returncode == 0
    assert "first difference: frame" in text.stdout
    assert "nick" in text.stdout
    assert "counts" in text.stdout


def test_a_bad_set_key_is_a_usage_error(flight: Path, tmp_path: Path) -> None:
    done = _mkflight(
        "replay", str(flight), "--out", str(tmp_path / "r"), "--set", "control.kp_zz=1"
    )
    assert done.returncode == 2
    assert "control.kp_zz" in done.stderr
    assert "Traceback" not in done.stderr


def test_a_recording_cut_mid_record_is_replayed_as_far_as_it_goes(
    flight: Path, tmp_path: Path
) -> None:
    """A process killed mid-write: the tail record is incomplete."""
    src = _copy(flight, tmp_path)
    raw = src / "laser.raw"
    blob = raw.read_bytes()
    rec = read_raw(raw)
    cut = len(blob) * 2 // 3
    raw.write_bytes(blob[:cut])
    kept = read_raw(raw)
    assert kept.truncated_at is not None
    assert len(kept.records) < len(rec.records)
    done = _mkflight("replay", str(src), "--out", str(tmp_path / "r"), "--json")
    assert "Traceback" not in done.stderr
    assert f"laser.raw: incomplete last record at byte {kept.truncated_at}" in done.stderr
    assert "replaying what is readable" in done.stderr
    # The laser data ends early: the flight after the cut cannot be the same, so it is
    # played but checked only up to the cut, which the warning names.
    cut_s = (kept.records[-1].t_ns - rec.header.start_t_ns) / 1e9
    assert f"laser.raw: ends early, at {cut_s:.2f} s" in done.stderr
    assert done.returncode == 0, done.stderr
    commands = json.loads(done.stdout)["commands"]
    assert commands["first_difference"] is None  # every command up to the cut reproduced
    assert 0 < commands["original"] < len(extern_control_frames(read_raw(flight / "mk.raw")))


@pytest.mark.parametrize("name", ["mk.raw", "laser.raw", "flight.json"])
def test_a_missing_file_is_one_clear_line(flight: Path, tmp_path: Path, name: str) -> None:
    src = _copy(flight, tmp_path)
    (src / name).unlink()
    done = _mkflight("replay", str(src), "--out", str(tmp_path / "r"))
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1
    assert str(src / name) in lines[0]
    assert "missing" in lines[0]


def test_a_recording_of_another_format_version_names_file_and_offset(
    flight: Path, tmp_path: Path
) -> None:
    src = _copy(flight, tmp_path)
    raw = src / "mk.raw"
    blob = bytearray(raw.read_bytes())
    blob[8:10] = (7).to_bytes(2, "little")
    raw.write_bytes(bytes(blob))
    done = _mkflight("replay", str(src), "--out", str(tmp_path / "r"))
    assert done.returncode == 1
    assert f"{raw}: byte 8: unknown format version 7" in done.stderr
    assert "Traceback" not in done.stderr


def test_a_flight_json_of_a_newer_log_format_is_refused(flight: Path, tmp_path: Path) -> None:
    src = _copy(flight, tmp_path)
    info = json.loads((src / "flight.json").read_text())
    info["log_format"] = 2
    (src / "flight.json").write_text(json.dumps(info))
    with pytest.raises(ReplayError, match=r"flight\.json: log_format 2 .* newer"):
        replay_flight(src, tmp_path / "r")


def test_garbage_in_place_of_a_recording_is_an_error_naming_it(
    flight: Path, tmp_path: Path
) -> None:
    src = _copy(flight, tmp_path)
    (src / "laser.raw").write_bytes(b"this is not a recording\n" * 10)
    done = _mkflight("replay", str(src), "--out", str(tmp_path / "r"))
    assert done.returncode == 1
    assert f"{src / 'laser.raw'}: byte 0: not a raw recording" in done.stderr
    assert "Traceback" not in done.stderr


def test_an_existing_output_folder_is_never_overwritten(flight: Path, tmp_path: Path) -> None:
    out = tmp_path / "taken"
    out.mkdir()
    (out / "x").write_text("keep")
    done = _mkflight("replay", str(flight), "--out", str(out))
    assert done.returncode == 2
    assert "never overwritten" in done.stderr
    assert (out / "x").read_text() == "keep"


def test_the_seeds_two_tables_alone_replay_through_the_daemon(flight: Path, tmp_path: Path) -> None:
    """TABLE IV as DebugOut frames, TABLE III poses for the matcher: our estimator and
    controllers run on them; what went through losslessly comes back exactly."""
    seed = tmp_path / "seed"
    seed.mkdir()
    for name in ("imu_50ms.log", "laser_100ms.log"):
        shutil.copy(flight / name, seed / name)
    out = tmp_path / "r"
    done = _mkflight("replay", str(seed), "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["flight_exit_code"] == 0
    s = report["seed"]
    n_rows = len((seed / "imu_50ms.log").read_text().splitlines()) - 1
    assert s["imu_rows_played"] == s["imu_rows"] == n_rows  # every row, as a DebugOut
    cols = s["columns"]
    for name in ("AnglePitch", "AngleRoll", "AccX", "AccY", "AccZ"):
        assert cols[name]["rows"] == n_rows
        assert cols[name]["max_abs_diff"] == 0.0  # counts -> SI -> counts -> SI: lossless
    for name in ("CurrentPosition.x", "CurrentPosition.y", "CurrentPosition.theta"):
        assert cols[name]["rows"] > 50
        assert cols[name]["max_abs_diff"] == 0.0  # TABLE III's poses stood in for ICP
    assert cols["W_Vel.x"]["rms_diff"] < 0.01  # velocities from the same poses
    # our controller, similar commands: a sign error or noise would give <= 0; per axis
    # the correlation of two noisy command streams over an 8 s hold is 0.18-0.47
    mean_r = (cols["ControlPitch"]["correlation"] + cols["ControlRoll"]["correlation"]) / 2
    assert mean_r > 0.2
    # the replay wrote its own tables
    assert read_table4(out / "imu_50ms.log").rows.shape[0] > n_rows
    text = _mkflight("replay", str(seed), "--out", str(tmp_path / "t"))
    assert "TABLE III poses stood in for the scan matcher" in text.stdout
    assert "determinism check" not in text.stdout


def test_a_paced_replay_is_as_exact_and_not_faster_than_asked(flight: Path, tmp_path: Path) -> None:
    """--speed X paces the same lock-step clock: the same bytes, never ahead of X x real
    time (a lower bound only: a loaded machine may be slower, never faster)."""
    r = replay_flight(flight, tmp_path / "r", speed=40.0)
    assert r.deterministic, r.commands.first
    assert r.wall_s >= 0.95 * r.recorded_s / 40.0


@job("replay-killed")
def _fly_and_kill(base: Path) -> Path:
    """A 30 s flight SIGKILLed 10 s after its start (in its hold: the pre-flight takes ~2 s)."""
    folder = base / "killed"
    proc = subprocess.Popen(
        [*MKFLIGHT, "fly", "--hover", "--sim", "--duration", "30", "--log-dir", str(folder)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    with pytest.raises(subprocess.TimeoutExpired):
        proc.wait(timeout=10.0)  # into the flight
    proc.kill()
    proc.wait()
    return folder


@pytest.mark.background("replay-killed")
def test_a_killed_flight_replays_up_to_where_its_recording_ends(
    background: Background, tmp_path: Path
) -> None:
    """SIGKILL mid-flight: no summary, no release in the recording. The replay reproduces
    every recorded frame; what it sends after the recording ended is not held against it."""
    folder: Path = background.result("replay-killed")
    r = replay_flight(folder, tmp_path / "r")
    c = r.commands
    assert c.n_original > 50
    assert c.identical, c.first
    assert c.n_after_end > 0  # the replayed daemon handed back after the data ended
    assert any("the flight was killed" in w for w in r.warnings)
    assert r.deterministic


def test_ctrl_c_stops_the_replay_not_the_replayed_vehicle(flight: Path, tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [*MKFLIGHT, "replay", str(flight), "--speed", "1", "--out", str(tmp_path / "r")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    with pytest.raises(subprocess.TimeoutExpired):
        proc.wait(timeout=4.0)  # paced at real time: still replaying
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    assert "error: interrupted" in err
    assert "Traceback" not in err
    assert "determinism check" not in out  # no report of a landing it made up


def test_output_paths_that_cannot_be_a_folder_are_usage_errors(
    flight: Path, tmp_path: Path
) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    done = _mkflight("replay", str(flight), "--out", str(a_file))
    assert done.returncode == 2
    assert "is a file" in done.stderr
    assert "Traceback" not in done.stderr
    done = _mkflight("replay", str(flight), "--out", str(a_file / "sub"))
    assert done.returncode == 2
    assert "cannot be created" in done.stderr


def test_replaying_dot_writes_beside_the_flight(flight: Path, tmp_path: Path) -> None:
    src = _copy(flight, tmp_path)
    done = subprocess.run(
        [*MKFLIGHT, "replay", "."],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "copy-replay" / "mk.raw").exists()
    assert not any(p.name.endswith("-replay") for p in src.iterdir())


SLOW_BOARD = """
import gc, sys, time
_freeze = gc.freeze
def slow_freeze():  # a slow board: gc over a big heap stalls the loop 0.4 s at READY
    time.sleep(0.4)
    _freeze()
gc.freeze = slow_freeze
from mkflight.cli import main
sys.exit(main(sys.argv[1:]))
"""


@job("replay-slow-board")
def _fly_slow_board(base: Path) -> Path:
    folder = base / "slow"
    args = ["fly", "--hover", "--sim", "--duration", "10", "--log-dir", str(folder)]
    fly = subprocess.run(
        [sys.executable, "-c", SLOW_BOARD, *args],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert fly.returncode == 0, fly.stderr
    return folder


@pytest.mark.background("replay-slow-board")
def test_a_flight_whose_loop_stalled_at_ready_replays_byte_for_byte(
    background: Background, tmp_path: Path
) -> None:
    """The stall leaves the last scan 0.4 s old at READY; in flight the matcher's round
    trip let a new scan arrive before the laser task asked again. The replay gives each
    result at its recorded time, so it does not restart a 'stalled' stream the flight
    never restarted (found by review: 2 of 2 runs failed before)."""
    folder: Path = background.result("replay-slow-board")
    r = replay_flight(folder, tmp_path / "r")
    assert r.commands.identical, r.commands.first
    assert r.deterministic
