"""mkflight.logs.flight: a flight folder, written by the real writers, read back as arrays."""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Callable
from dataclasses import astuple, dataclass
from datetime import UTC, datetime
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mkflight.clock import ManualClock
from mkflight.config import Config, MkConfig
from mkflight.errors import ReplayError
from mkflight.logs import (
    LOG_FORMAT,
    EventsWriter,
    Table3Row,
    Table3Writer,
    Table4Row,
    Table4Writer,
    extern_control_frames,
    load_flight,
    new_flight_info,
    read_flight_json,
    with_summary,
    write_flight_json,
)
from mkflight.logs.flight import COMMAND_DTYPE, SAMPLE_DTYPE, TRUTH_DTYPE, extern_controls
from mkflight.logs.raw import RawRecorder, read_raw
from mkflight.logs.schema import FlightSummary, PhaseChange, Preflight, Scan, Step, UnknownEvent
from mkflight.logs.table3 import COLUMNS as T3_COLUMNS
from mkflight.logs.table4 import COLUMNS as T4_COLUMNS
from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import (
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_GAS,
    ANALOG_GYRO_COMPASS,
    ANALOG_VOLTAGE,
    DebugOut,
    ExternControl,
    debug_request,
    ppm_request,
)
from mkflight.sim.truth import TruthLog
from mkflight.sim.vehicle import VehicleState
from tests.integration.recorded import commands_sent
from tests.logs import format1, records

T0_NS = 7_000_000_000  # the raw recorders' clock at the folder's creation
MS = 1_000_000
# A calibration unlike the defaults: the samples must use the flight's own.
MK = MkConfig(angle_unit_deg=0.2, voltage_unit_v=0.05, acc_z_counts_per_mps2=10.0)
COMMANDS = [
    ExternControl.neutral(frame=1),
    ExternControl(nick=-128, roll=127, yaw=-3, gas=200, config=1, frame=2),
    ExternControl(nick=5, roll=-6, yaw=7, gas=0, config=0),
]
T4_ROWS = [
    Table4Row(0.1, -0.2, 1.5, 0.25, -0.5, -9.81, -3, 4, 0, 1, 2, 3, 200, 1),
    Table4Row(-2.5e-05, 0.0, -3.1, 1.0, 2.0, -9.0, 127, -128, 5, 0, 0, 0, 0, 2),
    Table4Row(math.nan, 0.3, 0.0, 0.0, 0.0, -9.8, 0, 0, 0, 0, 0, 0, 10, 3),
]
T3_ROWS = [
    Table3Row(0.012, 0.011, 0.01, -0.003, -0.004, -0.002, 0.101, -0.02, 0.0031, 1),
    Table3Row(0.5, 0.4, 0.3, 0.2, 0.1, 0.0, 1.5, -1.5, math.nan, 2),
]


def _step(t_ns: int, x_m: float, phase: str, sp: float | None) -> Step:
    """A step event as FlightLogs.step writes it."""
    return Step(
        t_ns=t_ns,
        x_m=x_m,
        y_m=-x_m,
        sp_x_m=sp,
        sp_y_m=sp,
        sp_height_m=sp,
        height_m=0.6,
        vz_up_mps=0.01,
        gas_counts=120,
        battery_v=12.4,
        phase=phase,
        action="NONE",
        latency_ms=0.8,
    )


def _scan(t_ns: int, index: int | None, step: int, seq: int, height_m: float | None) -> Scan:
    """A scan event as the daemon writes it (no pose when ``height_m`` is None)."""
    valid = height_m is not None
    return Scan(
        t_ns=t_ns,
        index=index,
        step=step,
        seq=seq,
        valid=valid,
        got_ns=t_ns + 20 * MS,
        x_m=0.25 if valid else None,
        y_m=-0.5 if valid else None,
        yaw_rad=0.125 if valid else None,
        height_m=height_m,
        degenerate=not valid,
        match_ms=1.5,
    )


@dataclass(frozen=True)
class Written:
    """What _flight_folder wrote, to compare against."""

    debug: list[tuple[int, DebugOut]]  # (t_ns of the record that completed it, message)
    commands: list[tuple[int, ExternControl]]


def _debug(nick: int, voltage: int) -> DebugOut:
    return DebugOut.from_values(
        {
            ANALOG_ANGLE_NICK: nick,
            ANALOG_ANGLE_ROLL: -50,
            ANALOG_GYRO_COMPASS: 90,
            ANALOG_ACC_Z: 20,
            ANALOG_VOLTAGE: voltage,
            ANALOG_GAS: 400,
        }
    )


def _write_mk_raw(folder: Path) -> Written:
    """mk.raw as the link records it: reads split anywhere, garbage, writes frame by frame."""
    clock = ManualClock(T0_NS)
    d1, d2, foreign = _debug(100, 252), _debug(-30, 240), _debug(1, 1)
    foreign = DebugOut(foreign.status, foreign.analog, addr=2)  # the NC's: not the FC's
    b1, b2 = d1.encode(), d2.encode()
    with RawRecorder(folder / "mk.raw", "/dev/ttyUSB0", clock=clock) as rec:
        rec.mark("o", T0_NS + 1 * MS, "/dev/ttyUSB0")
        rec("w", T0_NS + 2 * MS, debug_request(5))
        rec("r", T0_NS + 10 * MS, b"\x00garbage" + b1[:30])
        rec("r", T0_NS + 11 * MS, b1[30:])  # completes d1
        rec("w", T0_NS + 12 * MS, COMMANDS[0].encode())
        rec("r", T0_NS + 13 * MS, foreign.encode() + b2[:-1] + b"X\r")  # d2 with a bad CRC
        rec("r", T0_NS + 14 * MS, b2)
        wire = COMMANDS[1].encode()
        rec("w", T0_NS + 15 * MS, wire[:7])
        rec("w", T0_NS + 16 * MS, wire[7:] + ppm_request())  # completes COMMANDS[1]
        rec("w", T0_NS + 20 * MS, COMMANDS[2].encode())
    return Written(
        debug=[(T0_NS + 11 * MS, d1), (T0_NS + 14 * MS, d2)],
        commands=[
            (T0_NS + 12 * MS, COMMANDS[0]),
            (T0_NS + 16 * MS, COMMANDS[1]),
            (T0_NS + 20 * MS, COMMANDS[2]),
        ],
    )


def _flight_folder(folder: Path, *, summary: bool = True) -> Written:
    """A folder as `mkflight fly` writes it (flight_logs.py), plus a simulator truth log."""
    folder.mkdir(exist_ok=True)
    info = new_flight_info(datetime(2024, 5, 1, 12, tzinfo=UTC), Config(mk=MK), "0.84a")
    write_flight_json(folder, info)
    with Table4Writer(folder) as t4:
        for row4 in T4_ROWS:
            t4.write_row(row4)
    with Table3Writer(folder) as t3:
        for row3 in T3_ROWS:
            t3.write_row(row3)
    with EventsWriter(folder) as ev:
        ev.write(Preflight.of(T0_NS + 5 * MS, records.PREFLIGHT))
        ev.write(_scan(T0_NS + 40 * MS, None, 1, 6, 0.0))
        ev.write(_step(T0_NS + 50 * MS, 0.5, "HANDSHAKE", None))
        ev.write(PhaseChange(t_ns=T0_NS + 50 * MS, to="TAKEOFF", reason="handshake done"))
        ev.write(_step(T0_NS + 100 * MS, -1.25, "TAKEOFF", 0.25))
        ev.write(_scan(T0_NS + 140 * MS, 1, 3, 7, 0.3))
        ev.write(_step(T0_NS + 150 * MS, 2.0, "HOLD", 0.5))
        ev.write(_scan(T0_NS + 240 * MS, 2, 5, 8, None))
    written = _write_mk_raw(folder)
    with RawRecorder(folder / "laser.raw", "/dev/ttyACM0", clock=ManualClock(T0_NS + 3)) as rec:
        rec("w", T0_NS + 4, b"SCIP2.0\n")
    truth = TruthLog(folder / "truth.txt", origin_ns=T0_NS - 1_000_000_000)
    truth.write(T0_NS, VehicleState(pos_w_m=(0.5, -0.25, -0.6)))
    truth.write(T0_NS + 50 * MS, VehicleState(pos_w_m=(0.75, 0.0, -0.5)))
    truth.close()
    if summary:
        write_flight_json(folder, with_summary(info, records.summary()))
    return written


def _same(got: list[tuple[object, ...]], want: list[tuple[object, ...]]) -> bool:
    """Equal row by row and value by value, NaN equal to NaN."""

    def eq(a: object, b: object) -> bool:
        nan = isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)
        return nan or a == b

    return len(got) == len(want) and all(
        len(g) == len(w) and all(eq(a, b) for a, b in zip(g, w, strict=True))
        for g, w in zip(got, want, strict=True)
    )


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    return tmp_path / "flight"


def test_tables_come_back_exactly_with_their_seed_column_names(folder: Path) -> None:
    _flight_folder(folder)
    f = load_flight(folder)
    assert f.imu.dtype.names == T4_COLUMNS
    assert f.laser.dtype.names == T3_COLUMNS
    assert _same(f.imu.tolist(), [astuple(r) for r in T4_ROWS])
    assert _same(f.laser.tolist(), [msgspec.structs.astuple(r) for r in T3_ROWS])
    assert f.imu["ControlPitch"].tolist() == [-3, 127, 0]
    assert f.laser["W_Vel.x"].tolist() == [0.012, 0.5]
    assert math.isnan(f.laser["CurrentPosition.theta"][1])
    assert f.path == folder
    assert f.warnings == ()


def test_time_base_is_the_mk_raw_start_for_every_array(folder: Path) -> None:
    written = _flight_folder(folder)
    f = load_flight(folder)
    assert f.t0_ns == T0_NS
    assert f.steps["t_s"].tolist() == [0.05, 0.1, 0.15]
    assert f.scans["t_s"].tolist() == [0.04, 0.14, 0.24]
    assert f.commands["t_s"].tolist() == [(t - T0_NS) / 1e9 for t, _ in written.commands]
    assert f.samples["t_s"].tolist() == [0.011, 0.014]
    # The truth log's t counts from its own origin, 1 s before T0_NS.
    assert f.truth is not None
    assert f.truth["t_s"].tolist() == pytest.approx([0.0, 0.05])
    assert f.truth.dtype == TRUTH_DTYPE
    assert f.truth[["x_m", "y_m", "height_m"]].tolist() == [(0.5, -0.25, 0.6), (0.75, 0.0, 0.5)]
    # A TABLE IV row's time is its step's (k-th step = index k); a TABLE III row's its scan's.
    assert f.imu_t_s.tolist() == [0.05, 0.1, 0.15]
    assert f.laser_t_s.tolist() == [0.14, 0.24]


def test_events_become_named_columns(folder: Path) -> None:
    _flight_folder(folder)
    f = load_flight(folder)
    assert f.steps.dtype.names == (
        *("t_s", "x_m", "y_m", "sp_x_m", "sp_y_m", "sp_height_m", "height_m", "vz_up_mps"),
        *("gas_counts", "battery_v", "phase", "action", "latency_ms"),
    )
    assert f.steps["x_m"].tolist() == [0.5, -1.25, 2.0]
    assert f.steps["phase"].tolist() == ["HANDSHAKE", "TAKEOFF", "HOLD"]
    assert f.steps.dtype["phase"] == np.dtype("U16")
    assert math.isnan(f.steps["sp_x_m"][0])  # null: no set-point yet
    assert f.steps["sp_height_m"][1:].tolist() == [0.25, 0.5]
    assert math.isnan(f.scans["index"][0])
    assert f.scans["index"][1:].tolist() == [1.0, 2.0]
    assert f.scans["valid"].tolist() == [1.0, 1.0, 0.0]
    assert math.isnan(f.scans["height_m"][2])
    phases = f.event_table("phase")
    assert phases["to"].tolist() == ["TAKEOFF"]
    assert phases["t_s"].tolist() == [0.05]
    assert [e.event for e in f.events] == [
        *("preflight", "scan", "step", "phase", "step", "scan", "step", "scan"),
    ]


def test_commands_are_every_extern_control_written(folder: Path) -> None:
    written = _flight_folder(folder)
    f = load_flight(folder)
    assert f.commands.dtype == COMMAND_DTYPE
    got = [tuple(r)[1:] for r in f.commands.tolist()]
    assert got == [(c.nick, c.roll, c.yaw, c.gas, c.config) for _, c in written.commands]
    assert commands_sent(folder) == [c for _, c in written.commands]  # the tests' wrapper


def test_samples_are_debug_out_in_si_with_the_flights_calibration(folder: Path) -> None:
    _flight_folder(folder)
    f = load_flight(folder)
    assert f.samples.dtype == SAMPLE_DTYPE
    # Garbage, a bad-CRC frame and the NC's DebugOut are not samples.
    assert len(f.samples) == 2
    s = f.samples[0]
    assert s["pitch_rad"] == pytest.approx(-math.radians(100 * 0.2))  # MK + nick = nose down
    assert s["roll_rad"] == pytest.approx(math.radians(50 * 0.2))
    assert s["yaw_rad"] == pytest.approx(math.pi / 2)
    assert s["acc_z_mps2"] == pytest.approx(-(20 / 10.0 + 9.8))
    assert s["battery_v"] == pytest.approx(252 * 0.05)  # the default 0.1 would say 25.2
    assert s["gas_counts"] == 100
    assert f.samples["battery_v"][1] == pytest.approx(240 * 0.05)


def test_info_is_flight_json_with_its_log_format(folder: Path) -> None:
    _flight_folder(folder)
    f = load_flight(folder)
    assert f.info is not None
    assert f.info.log_format == LOG_FORMAT == 1
    assert f.info.summary == records.summary()
    assert f.info.config["mk"]["voltage_unit_v"] == 0.05
    assert json.loads((folder / "flight.json").read_text())["log_format"] == 1


def test_a_flight_without_summary_is_read_with_a_warning(folder: Path) -> None:
    _flight_folder(folder, summary=False)
    f = load_flight(folder)
    assert any("flight.json: no summary" in w for w in f.warnings)


def test_truncated_raw_keeps_the_complete_records_and_warns_with_the_offset(
    folder: Path,
) -> None:
    written = _flight_folder(folder)
    raw = folder / "mk.raw"
    blob = raw.read_bytes()
    last = len(blob) - (13 + len(COMMANDS[2].encode()))  # the last record's offset
    raw.write_bytes(blob[:-5])
    f = load_flight(folder)
    assert [tuple(r)[1:] for r in f.commands.tolist()] == [
        (c.nick, c.roll, c.yaw, c.gas, c.config) for _, c in written.commands[:2]
    ]
    assert len(f.samples) == 2
    kept = len(blob) - 5 - last  # of the last record, 5 bytes short
    assert f.warnings == (f"{raw}: incomplete last record at byte {last} ({kept} bytes) dropped",)


@pytest.mark.parametrize(
    ("name", "what"),
    [
        ("imu_50ms.log", "incomplete last row dropped"),
        ("laser_100ms.log", "incomplete last row dropped"),
        ("events.jsonl", "incomplete last event dropped"),
        ("truth.txt", "incomplete last row dropped"),
    ],
)
def test_a_cut_short_text_tail_is_dropped_with_file_and_line(
    folder: Path, name: str, what: str
) -> None:
    _flight_folder(folder)
    path = folder / name
    text = path.read_text()
    lines = text.count("\n")
    path.write_text(text + "0.5 0.")  # a killed writer's partial line
    f = load_flight(folder)
    assert f.warnings == (f"{path}:{lines + 1}: {what}",)
    assert len(f.imu) == 3
    assert len(f.laser) == 2
    assert len(f.steps) == 3
    assert f.truth is not None
    assert len(f.truth) == 2


def test_missing_optional_files_give_empty_arrays_of_the_same_dtype(folder: Path) -> None:
    _flight_folder(folder)
    full = load_flight(folder)
    for name in ("mk.raw", "laser.raw", "events.jsonl", "flight.json", "truth.txt"):
        (folder / name).unlink()
    f = load_flight(folder)
    assert f.t0_ns is None
    assert f.info is None
    assert f.truth is None
    assert f.events == []
    for key in ("steps", "scans", "commands", "samples", "imu", "laser"):
        assert getattr(f, key).dtype == getattr(full, key).dtype, key
    assert (len(f.steps), len(f.scans), len(f.commands), len(f.samples)) == (0, 0, 0, 0)
    assert len(f.imu) == 3
    assert f.warnings == ()


def test_only_flight_json_loads_with_empty_tables(folder: Path) -> None:
    _flight_folder(folder)
    for name in ("imu_50ms.log", "laser_100ms.log"):
        (folder / name).unlink()
    f = load_flight(folder)
    assert f.imu.dtype.names == T4_COLUMNS
    assert f.laser.dtype.names == T3_COLUMNS
    assert (len(f.imu), len(f.laser), len(f.imu_t_s)) == (0, 0, 0)
    assert len(f.commands) == 3


def test_time_base_falls_back_to_laser_raw_then_to_the_first_event(folder: Path) -> None:
    _flight_folder(folder)
    (folder / "mk.raw").unlink()
    f = load_flight(folder)
    assert f.t0_ns == T0_NS + 3
    assert len(f.commands) == 0
    (folder / "laser.raw").unlink()
    f = load_flight(folder)
    assert f.t0_ns == T0_NS + 5 * MS  # the preflight event
    assert f.steps["t_s"].tolist() == pytest.approx([0.045, 0.095, 0.145])


def test_a_folder_of_the_seed_system_loads_with_nominal_times(folder: Path) -> None:
    """The original system wrote only the two tables (here via numpy, not our writers)."""
    folder.mkdir()
    imu = np.array([[0.01 * i] * 6 + [i, -i, 0, 0, 0, 0, 100, i] for i in (1, 2, 3, 4)])
    laser = np.array([[0.1 * i] * 9 + [i] for i in (1, 2)])
    np.savetxt(folder / "imu_50ms.log", imu, header=" ".join(T4_COLUMNS), comments="")
    np.savetxt(folder / "laser_100ms.log", laser, header=" ".join(T3_COLUMNS), comments="")
    f = load_flight(folder)
    assert f.t0_ns is None
    assert f.imu["ControlRoll"].tolist() == [-1, -2, -3, -4]
    assert f.imu["AccZ"].tolist() == [0.01, 0.02, 0.03, 0.04]
    assert f.imu_t_s.tolist() == pytest.approx([0.05, 0.1, 0.15, 0.2])
    assert f.laser_t_s.tolist() == pytest.approx([0.1, 0.2])
    assert f.info is None
    assert f.warnings == ()


def test_rows_without_their_event_have_nan_time(folder: Path) -> None:
    _flight_folder(folder)
    with (folder / "imu_50ms.log").open("a") as fh:
        fh.write("0.0 0.0 0.0 0.0 0.0 -9.8 0 0 0 0 0 0 0 4\n")  # killed before its step event
    f = load_flight(folder)
    assert f.imu_t_s[:3].tolist() == [0.05, 0.1, 0.15]
    assert math.isnan(f.imu_t_s[3])


def test_not_a_flight_folder_is_a_replay_error_naming_it(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match=f"{tmp_path / 'nope'}: not a flight folder"):
        load_flight(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "mk.raw").write_bytes(b"")
    with pytest.raises(ReplayError, match=f"{tmp_path / 'empty'}: not a flight folder"):
        load_flight(tmp_path / "empty")


def test_a_newer_log_format_is_refused_naming_flight_json(folder: Path) -> None:
    _flight_folder(folder)
    path = folder / "flight.json"
    data = json.loads(path.read_text())
    data["log_format"] = LOG_FORMAT + 1
    del data["summary"]  # a newer format may lay out its keys differently
    path.write_text(json.dumps(data))
    with pytest.raises(ReplayError, match=r"flight\.json: log_format 2 .* newer .* reads \(1\)"):
        load_flight(folder)


def test_flight_json_without_log_format_is_format_1(folder: Path) -> None:
    _flight_folder(folder)
    path = folder / "flight.json"
    data = json.loads(path.read_text())
    del data["log_format"]  # as written before the key existed
    path.write_text(json.dumps(data))
    assert read_flight_json(path).log_format == 1
    info = load_flight(folder).info
    assert info is not None
    assert info.log_format == 1
    data["log_format"] = "1"
    path.write_text(json.dumps(data))
    with pytest.raises(ReplayError, match=r"flight\.json: log_format: expected a positive integer"):
        load_flight(folder)


@pytest.mark.parametrize(
    ("name", "damage", "match"),
    [
        ("mk.raw", lambda b: b"MKRAW\r\n\x1a\x02" + b[9:], r"mk\.raw: byte 8: unknown format"),
        ("laser.raw", lambda b: b"GARBAGE!" + b[8:], r"laser\.raw: byte 0: not a raw"),
        ("mk.raw", lambda b: b + b"\x00" * 8 + b"z" + b"\x00" * 4, r"mk\.raw: byte \d+: unknown"),
        ("events.jsonl", lambda b: b.replace(b'"scan"', b"scan", 1), r"events\.jsonl:2: not JSON"),
        ("imu_50ms.log", lambda b: b.replace(b" 2\n", b" x\n"), r"imu_50ms\.log:3: column index"),
        ("laser_100ms.log", lambda b: b"\xff\xfe" + b, r"laser_100ms\.log: cannot read"),
        ("flight.json", lambda b: b[:-20], r"flight\.json: cannot read flight metadata"),
        ("truth.txt", lambda b: b + b"1.0 2.0 x 4.0\n", r"truth\.txt:5: expected 't x y z'"),
        ("truth.txt", lambda b: b.replace(b"t0_ns 6", b"t0_ns x"), r"truth\.txt:2: t0_ns"),
    ],
)
def test_corrupt_input_is_a_replay_error_naming_file_and_place(
    folder: Path, name: str, damage: Callable[[bytes], bytes], match: str
) -> None:
    _flight_folder(folder)
    path = folder / name
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(ReplayError, match=match):
        load_flight(folder)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"x_m": "far"}, r"step event at t_ns 1: x_m = 'far' is not a number"),
        ({"phase": 3}, r"step event at t_ns 1: phase = 3 is not a string"),
        ({"x_m": 10**400}, r"step event at t_ns 1: x_m = \d+ is not a number"),
    ],
)
def test_a_step_field_of_the_wrong_type_is_a_replay_error(
    folder: Path, fields: dict[str, object], match: str
) -> None:
    folder.mkdir()
    with Table4Writer(folder):
        pass
    line = json.dumps({"t_ns": 1, "event": "step", **fields})  # 10**400: not via a writer
    (folder / "events.jsonl").write_text(line + "\n")
    with pytest.raises(ReplayError, match=match):
        load_flight(folder)


def test_events_times_beyond_any_clock_are_a_replay_error(folder: Path) -> None:
    folder.mkdir()
    with Table4Writer(folder):
        pass
    (folder / "events.jsonl").write_text(
        f'{{"t_ns": 0, "event": "x"}}\n{{"t_ns": {10**400}, "event": "step"}}\n'
    )
    with pytest.raises(ReplayError, match="out of range"):
        load_flight(folder)


def test_an_unknown_kinds_fields_become_columns_and_mixed_ones_do_not(folder: Path) -> None:
    """A kind this version does not know (a newer writer's): its scalar keys are columns."""
    folder.mkdir()
    with Table4Writer(folder):
        pass
    lines = [
        {"t_ns": 0, "event": "note", "index": 1, "yaw_rad": 0.5, "text": "a", "mixed": 1},
        {"t_ns": 1, "event": "note", "index": 2, "yaw_rad": None, "mixed": "x", "nested": [1]},
        {"t_ns": 2, "event": "note", "text": "a very long note, longer than 16"},
    ]
    (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))
    f = load_flight(folder)
    notes = f.event_table("note")
    assert notes.dtype.names == ("t_s", "index", "yaw_rad", "text")
    assert notes["text"].tolist() == ["a", "", "a very long note, longer than 16"]
    assert np.isnan(notes["yaw_rad"][1])
    fields = {k: v for k, v in lines[1].items() if k not in ("t_ns", "event")}
    assert f.events[1] == UnknownEvent(1, "note", fields)
    assert f.warnings == (
        f"{folder / 'events.jsonl'}:1: 3 'note' events of a kind not known here: "
        "kept as unknown events",
    )


def test_a_known_kinds_columns_are_its_struct_fields(folder: Path) -> None:
    """Keys a known kind does not have are passed over; a field it lacks is null."""
    folder.mkdir()
    with Table4Writer(folder):
        pass
    scan = msgspec.to_builtins(_scan(5, 1, 1, 7, 0.5))
    del scan["got_ns"]
    (folder / "events.jsonl").write_text(json.dumps({**scan, "note": "a"}) + "\n")
    f = load_flight(folder)
    assert f.scans.dtype.names == (
        *("t_s", "index", "step", "seq", "valid", "got_ns", "x_m", "y_m", "yaw_rad"),
        *("height_m", "degenerate", "match_ms"),
    )
    assert np.isnan(f.scans["got_ns"][0])
    assert f.scans["x_m"].tolist() == [0.25]
    assert f.warnings == ()


def test_a_format_1_folder_loads(folder: Path) -> None:
    """A format-1 folder (mkflight 0.1.0's lines) loads, typed, without warnings."""
    folder.mkdir()
    (folder / "events.jsonl").write_text("".join(e + "\n" for e in format1.EVENT_LINES))
    (folder / "flight.json").write_text(json.dumps(format1.FLIGHT_JSON, indent=2))
    f = load_flight(folder)
    assert f.warnings == ()
    assert f.info is not None
    assert isinstance(f.info.summary, FlightSummary)
    assert f.info.summary.end_reason == "--duration 60 s"
    assert len(f.steps) == 3
    assert f.steps["phase"].tolist() == ["PREFLIGHT", "HANDSHAKE", "HANDSHAKE"]
    assert f.scans["index"][1:3].tolist() == [1.0, 2.0]
    assert np.isnan(f.scans["index"][[0, 3]]).all()
    assert sum(isinstance(e, Step) for e in f.events) == 3
    assert f.t0_ns == 35014413562503  # no raw recordings: the first event's time


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(
        ["mk.raw", "laser.raw", "events.jsonl", "flight.json", "imu_50ms.log", "truth.txt"]
    ),
    garbage=st.binary(max_size=300),
    keep=st.integers(min_value=0, max_value=400),
)
def test_garbage_in_any_file_loads_or_is_a_replay_error(
    name: str, garbage: bytes, keep: int
) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "f"
        _flight_folder(folder)
        path = folder / name
        path.write_bytes(path.read_bytes()[:keep] + garbage)
        try:
            f = load_flight(folder)
        except ReplayError as err:
            error = str(err)
        else:
            error = ""
        if error:
            assert name in error
        else:  # what the garbage did not touch is all there
            if name != "imu_50ms.log":
                assert len(f.imu) == 3
            if name != "events.jsonl":
                assert len(f.steps) == 3
            if name != "mk.raw":
                assert len(f.commands) == 3


# ----- extern_control_frames ----------------------------------------------------------------

_s8 = st.integers(min_value=-128, max_value=127)
_u8 = st.integers(min_value=0, max_value=255)
_extern = st.builds(
    ExternControl,
    nick=_s8,
    roll=_s8,
    yaw=_s8,
    gas=_u8,
    height=_s8,
    frame=_u8,
    config=_u8,
    digital=st.tuples(_u8, _u8),
    remote_buttons=_u8,
    free=_u8,
)
_to_nc = ExternControl(nick=1, gas=9, addr=2).encode()  # a 'b' frame, not to the FC
_other = st.sampled_from([debug_request(5), ppm_request(), _to_nc, b"\r\n", b"#xx"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    items=st.lists(st.one_of(_extern, _other), max_size=12),
    cuts=st.lists(st.integers(min_value=0, max_value=2000), max_size=20),
    reads=st.lists(st.binary(max_size=20), max_size=5),
)
def test_extern_control_frames_round_trip_through_any_split_of_the_writes(
    items: list[ExternControl | bytes], cuts: list[int], reads: list[bytes]
) -> None:
    stream = b"".join(i.encode() if isinstance(i, ExternControl) else i for i in items)
    bounds = sorted({0, len(stream), *(c for c in cuts if c < len(stream))})
    chunks = [(bounds[k], stream[bounds[k] : bounds[k + 1]]) for k in range(len(bounds) - 1)]
    expected: list[tuple[int, bytes]] = []
    end = 0
    for item in items:  # each frame is complete in the chunk holding its last byte
        wire = item.encode() if isinstance(item, ExternControl) else item
        end += len(wire)
        if isinstance(item, ExternControl):
            expected.append((max(b for b in bounds if b < end), wire))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mk.raw"
        with RawRecorder(path, "pty", clock=ManualClock(0)) as rec:
            for k, (start, chunk) in enumerate(chunks):
                rec("w", start, chunk)
                if k < len(reads):
                    rec("r", start, b"#bb" + reads[k])  # reads never count
        recording = read_raw(path)
    got = extern_control_frames(recording)
    assert got == expected  # re-encoding gives the very bytes on the wire
    assert [f.cmd for f in FrameParser().feed(b"".join(w for _, w in got))] == ["b"] * len(got)
    decoded = [c for _, c in extern_controls(recording)]
    assert [c.encode() for c in decoded] == [frame for _, frame in got]


def test_a_frame_cut_by_a_lost_port_is_dropped_and_the_next_one_kept(tmp_path: Path) -> None:
    a, b = COMMANDS[1].encode(), COMMANDS[2].encode()
    path = tmp_path / "mk.raw"
    with RawRecorder(path, "pty", clock=ManualClock(0)) as rec:
        rec("w", 1, a[:10])
        rec.mark("c", 2, "lost")
        rec.mark("o", 3, "pty")
        rec("w", 4, a[10:])  # the tail alone is no frame
        rec("w", 5, b)
    assert extern_control_frames(read_raw(path)) == [(5, b)]
