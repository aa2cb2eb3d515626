"""``mkflight export``: a recorded flight as MCAP, read back and checked against its folder.

One real flight (``fly --hover --sim``, the background flight
:data:`tests.flights.HOVER_SIM_8S`) is exported. Its MCAP files are read with the ``mcap``
reader (JSON) and ``mcap-ros2-support``'s (``--ros2``); the topics, the counts, the times
and the values are compared with the folder's own files, read by the format readers, not by
the export's code.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from mkflight.errors import ConfigError
from mkflight.ground import export as export_module
from mkflight.ground import topics
from mkflight.ground.export import export_flight, write_mcap
from mkflight.ground.export_series import (
    NO_THROTTLE,
    flight_series,
    miko_cmd_from_table4,
    miko_imu_from_table4,
    pose2d_from_table3,
    row_gas,
    scan_series,
)
from mkflight.ground.frames import quaternion
from mkflight.ground.frames import sec_nsec as stamp
from mkflight.logs import table3, table4
from mkflight.logs.events import read_events
from mkflight.logs.flight import extern_controls, load_flight
from mkflight.logs.raw import read_raw
from mkflight.logs.scans import read_scans
from mkflight.logs.schema import Failsafe, PhaseChange, Scan, Step
from tests.background import Background
from tests.flights import HOVER_SIM_8S

pytestmark = pytest.mark.background(HOVER_SIM_8S)

MKFLIGHT = [sys.executable, "-m", "mkflight"]
NS = 1_000_000_000
ORIGINAL = {topics.POSE2D, topics.MIKO_IMU, topics.MIKO_CMD}


def _mkflight(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*MKFLIGHT, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        check=False,
    )


@dataclass(frozen=True)
class Msg:
    log_time: int
    publish_time: int
    schema: str
    value: Any


def _read_json(path: Path) -> dict[str, list[Msg]]:
    out: dict[str, list[Msg]] = {}
    with path.open("rb") as f:
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            assert channel.message_encoding == "json"
            assert schema is not None
            assert schema.encoding == "jsonschema"
            value = json.loads(m.data)
            out.setdefault(channel.topic, []).append(
                Msg(m.log_time, m.publish_time, schema.name, value)
            )
    return out


def _read_ros2(path: Path) -> dict[str, list[Msg]]:
    """Decoded by ``mcap-ros2-support`` (its DecoderFactory: ``read_ros2_messages`` is
    deprecated for it, and gives no publish_time)."""
    out: dict[str, list[Msg]] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, m, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert channel.message_encoding == "cdr"
            assert schema is not None
            assert schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append(
                Msg(m.log_time, m.publish_time, schema.name, decoded)
            )
    return out


@dataclass(frozen=True)
class Folder:
    """The recorded flight's own records, read with the format readers."""

    path: Path
    table3: npt.NDArray[Any]
    table4: npt.NDArray[Any]
    commands: list[tuple[int, Any]]
    steps: list[Step]
    scans: list[Scan]
    phases: list[PhaseChange]
    failsafes: list[Failsafe]
    truth_rows: int


@pytest.fixture(scope="session")
def flight(background: Background) -> Folder:
    path: Path = background.result(HOVER_SIM_8S)
    events = read_events(path / "events.jsonl").events
    truth = [line for line in (path / "truth.txt").read_text().splitlines() if line[:1].isdigit()]
    return Folder(
        path=path,
        table3=table3.read_table3(path / table3.FILE_NAME).rows,
        table4=table4.read_table4(path / table4.FILE_NAME).rows,
        commands=extern_controls(read_raw(path / "mk.raw")),
        steps=[e for e in events if isinstance(e, Step)],
        scans=[e for e in events if isinstance(e, Scan)],
        phases=[e for e in events if isinstance(e, PhaseChange)],
        failsafes=[e for e in events if isinstance(e, Failsafe)],
        truth_rows=len(truth),
    )


@pytest.fixture(scope="session")
def exported(flight: Folder, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("mcap") / "flight.mcap"
    done = _mkflight("export", str(flight.path), "-o", str(out), "--json")
    assert done.returncode == 0, done.stderr
    summary: dict[str, Any] = json.loads(done.stdout)
    assert summary["path"] == str(out)
    assert summary["size_bytes"] == out.stat().st_size
    return {"summary": summary, "messages": _read_json(out)}


@pytest.fixture(scope="session")
def exported_ros2(flight: Folder, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("mcap") / "flight-ros2.mcap"
    done = _mkflight("export", str(flight.path), "-o", str(out), "--ros2", "--json")
    assert done.returncode == 0, done.stderr
    return {"summary": json.loads(done.stdout), "messages": _read_ros2(out)}


def _table_times(flight: Folder) -> tuple[list[int], list[int]]:
    """The recorded t_ns of each TABLE IV row (its step) and TABLE III row (its scan)."""
    step_ns = {k: s.t_ns for k, s in enumerate(flight.steps, start=1)}
    scan_ns = {s.index: s.t_ns for s in flight.scans if s.index is not None}
    imu = [step_ns[int(i)] for i in flight.table4["index"]]
    laser = [scan_ns[int(i)] for i in flight.table3["index"]]
    return imu, laser


# ----- the default encoding: JSON with Foxglove's schemas ------------------------------------


def test_the_topics_and_counts_are_the_folders(flight: Folder, exported: dict[str, Any]) -> None:
    msgs = exported["messages"]
    assert flight.failsafes
    assert flight.phases
    assert set(msgs) == {
        *ORIGINAL,
        *(topics.POSE, topics.TF, topics.TF_STATIC, topics.SETPOINT, topics.HEIGHT),
        *(topics.VELOCITY, topics.ATTITUDE, topics.BATTERY, topics.COMMAND),
        *(topics.PHASE, topics.FAILSAFE, topics.TRUTH, topics.SCAN),
    }
    counts = {topic: len(m) for topic, m in msgs.items()}
    assert counts == exported["summary"]["counts"]
    assert counts[topics.POSE2D] == len(flight.table3) > 50
    assert counts[topics.MIKO_IMU] == len(flight.table4) > 100
    assert counts[topics.MIKO_CMD] == counts[topics.COMMAND] == len(flight.commands)
    assert counts[topics.PHASE] == len(flight.phases)
    assert counts[topics.FAILSAFE] == len(flight.failsafes)
    assert counts[topics.HEIGHT] == len(flight.steps)
    assert counts[topics.TRUTH] == flight.truth_rows > 100
    with_pose = [s for s in flight.steps if s.x_m is not None and s.y_m is not None]
    assert counts[topics.POSE] == counts[topics.TF] == len(with_pose)
    with_sp = [s for s in flight.steps if s.sp_x_m is not None and s.sp_y_m is not None]
    assert counts[topics.SETPOINT] == len(with_sp) > 50
    assert counts[topics.TF_STATIC] == 1
    assert exported["summary"]["left_out"] == {}


def test_the_schemas_are_foxgloves_and_table_v_to_vii(exported: dict[str, Any]) -> None:
    schema = {topic: m[0].schema for topic, m in exported["messages"].items()}
    assert schema[topics.POSE2D] == "geometry_msgs/Pose2D"
    assert schema[topics.MIKO_IMU] == "sensor_msgs/mikoImu"
    assert schema[topics.MIKO_CMD] == "sensor_msgs/mikoCmd"
    assert schema[topics.POSE] == schema[topics.SETPOINT] == "foxglove.PoseInFrame"
    assert schema[topics.TF] == schema[topics.TF_STATIC] == "foxglove.FrameTransform"
    first = {topic: m[0].value for topic, m in exported["messages"].items()}
    assert list(first[topics.POSE2D]) == ["x", "y", "theta"]  # TABLE V
    assert list(first[topics.MIKO_IMU]) == [
        *("pitchAngle", "rollAngle", "yawAngle", "AccX", "AccY", "AccZ")  # TABLE VI
    ]
    assert list(first[topics.MIKO_CMD]) == ["pitch", "roll", "yaw", "throttle"]  # TABLE VII


_JSON_TYPES: dict[str, tuple[type, ...]] = {
    "number": (int, float),
    "integer": (int,),
    "string": (str,),
    "null": (type(None),),
    "object": (dict,),
    "array": (list,),
}


def _conforms(value: Any, schema: dict[str, Any]) -> bool:
    """``value`` fits ``schema`` (the JSON Schema keywords the export uses)."""
    kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    if not any(
        isinstance(value, _JSON_TYPES[k]) and not (k != "null" and isinstance(value, bool))
        for k in kinds
    ):
        return False
    if isinstance(value, dict):
        props = schema.get("properties", {})
        return (
            set(value) == set(props)
            and set(schema.get("required", ())) <= set(value)
            and all(_conforms(v, props[k]) for k, v in value.items())
        )
    if isinstance(value, list):
        return all(_conforms(v, schema["items"]) for v in value)
    return True


def test_every_message_fits_its_channels_schema(exported: dict[str, Any]) -> None:
    with Path(exported["summary"]["path"]).open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {
            c.topic: json.loads(summary.schemas[c.schema_id].data)
            for c in summary.channels.values()
        }
        seen = 0
        for _, channel, m in reader.iter_messages():
            assert _conforms(json.loads(m.data), schemas[channel.topic]), channel.topic
            seen += 1
    assert seen == sum(exported["summary"]["counts"].values())
    assert schemas[topics.SCAN]["title"] == "foxglove.LaserScan"


def test_log_times_are_the_recorded_times(flight: Folder, exported: dict[str, Any]) -> None:
    msgs = exported["messages"]
    imu_ns, laser_ns = _table_times(flight)
    assert [m.log_time for m in msgs[topics.MIKO_IMU]] == imu_ns
    assert [m.log_time for m in msgs[topics.POSE2D]] == laser_ns
    assert [m.log_time for m in msgs[topics.MIKO_CMD]] == [t for t, _ in flight.commands]
    assert [m.log_time for m in msgs[topics.HEIGHT]] == [s.t_ns for s in flight.steps]
    assert [m.log_time for m in msgs[topics.PHASE]] == [p.t_ns for p in flight.phases]
    assert [m.log_time for m in msgs[topics.FAILSAFE]] == [f.t_ns for f in flight.failsafes]
    for topic, messages in msgs.items():
        assert all(m.publish_time == m.log_time for m in messages), topic
    for m in msgs[topics.POSE] + msgs[topics.TF]:  # the Foxglove stamp is the same time
        ts = m.value["timestamp"]
        assert ts["sec"] * NS + ts["nsec"] == m.log_time


def test_values_are_the_folders(flight: Folder, exported: dict[str, Any]) -> None:
    msgs = exported["messages"]
    pose2d = msgs[topics.POSE2D]
    for i in (0, len(pose2d) // 2, len(pose2d) - 1):
        row = flight.table3[i]
        assert pose2d[i].value == {
            "x": float(row["CurrentPosition.x"]),
            "y": float(row["CurrentPosition.y"]),
            "theta": float(row["CurrentPosition.theta"]),
        }
    imu = msgs[topics.MIKO_IMU]
    for i in (0, len(imu) // 2, len(imu) - 1):
        row = flight.table4[i]
        assert imu[i].value["pitchAngle"] == float(row["AnglePitch"])
        assert imu[i].value["AccZ"] == float(row["AccZ"])
    cmd = msgs[topics.MIKO_CMD]
    assert max(m.value["throttle"] for m in cmd) > 0  # the flight flew
    for (_, c), m in zip(flight.commands, cmd, strict=True):
        assert m.value == {"pitch": c.nick, "roll": c.roll, "yaw": c.yaw, "throttle": c.gas}
    assert [m.value["phase"] for m in msgs[topics.PHASE]] == [p.to for p in flight.phases]
    assert [m.value["cause"] for m in msgs[topics.FAILSAFE]] == [f.cause for f in flight.failsafes]
    heights = [m.value["height_m"] for m in msgs[topics.HEIGHT]]
    assert heights == [s.height_m for s in flight.steps]
    hold = [s for s in flight.steps if s.phase == "HOLD" and s.x_m is not None]
    by_time = {m.log_time: m.value for m in msgs[topics.POSE]}
    assert hold
    for s in hold[:: max(1, len(hold) // 10)]:
        position = by_time[s.t_ns]["pose"]["position"]
        assert (position["x"], position["y"]) == (s.x_m, s.y_m)
        assert s.height_m is not None
        assert position["z"] == -s.height_m


def test_the_truth_is_exported_on_the_flight_clock(
    flight: Folder, exported: dict[str, Any]
) -> None:
    data = load_flight(flight.path)
    assert data.truth is not None
    assert data.t0_ns is not None
    truth = exported["messages"][topics.TRUTH]
    want = [data.t0_ns + round(t * NS) for t in data.truth["t_s"].tolist()]
    assert [m.log_time for m in truth] == want
    assert [m.value["height_m"] for m in truth] == data.truth["height_m"].tolist()


# ----- --ros2 ----------------------------------------------------------------------------------


def test_ros2_decodes_with_the_same_topics_counts_times_and_values(
    flight: Folder, exported: dict[str, Any], exported_ros2: dict[str, Any]
) -> None:
    msgs = exported_ros2["messages"]
    json_msgs = exported["messages"]
    assert {t: len(m) for t, m in msgs.items()} == {t: len(m) for t, m in json_msgs.items()}
    for topic, messages in msgs.items():
        assert [m.log_time for m in messages] == [m.log_time for m in json_msgs[topic]], topic
    schema = {topic: m[0].schema for topic, m in msgs.items()}
    assert schema[topics.POSE2D] == "geometry_msgs/msg/Pose2D"
    assert schema[topics.POSE] == "geometry_msgs/msg/PoseStamped"
    assert schema[topics.TF] == "tf2_msgs/msg/TFMessage"
    assert schema[topics.PHASE] == "std_msgs/msg/String"
    assert schema[topics.MIKO_IMU] == "mkflight_msgs/msg/MikoImu"
    row = flight.table3[-1]
    last = msgs[topics.POSE2D][-1].value
    assert (last.x, last.y, last.theta) == (
        row["CurrentPosition.x"],
        row["CurrentPosition.y"],
        row["CurrentPosition.theta"],
    )
    imu = msgs[topics.MIKO_IMU][len(flight.table4) // 2].value
    assert imu.pitch_angle == flight.table4[len(flight.table4) // 2]["AnglePitch"]
    for (_, c), m in zip(flight.commands, msgs[topics.MIKO_CMD], strict=True):
        assert (m.value.pitch, m.value.roll, m.value.yaw, m.value.throttle) == (
            c.nick,
            c.roll,
            c.yaw,
            c.gas,
        )
    for m in msgs[topics.POSE] + msgs[topics.HEIGHT]:  # headers carry the recorded stamp
        assert m.value.header.stamp.sec * NS + m.value.header.stamp.nanosec == m.log_time
    for m in msgs[topics.TF][:: max(1, len(msgs[topics.TF]) // 10)]:  # both frames, each time
        frames = [(t.header.frame_id, t.child_frame_id) for t in m.value.transforms]
        assert frames == [("map", "world"), ("world", "vehicle")]
        assert m.value.transforms[0].transform.rotation.x == pytest.approx(1.0)
    phases = [json.loads(m.value.data)["phase"] for m in msgs[topics.PHASE]]
    assert phases == [p.to for p in flight.phases]


# ----- the original system's tables alone ------------------------------------------------------


def _tables_only(flight: Folder, tmp_path: Path) -> Path:
    folder = tmp_path / "tables"
    folder.mkdir()
    for name in (table3.FILE_NAME, table4.FILE_NAME):
        shutil.copy(flight.path / name, folder / name)
    return folder


@pytest.mark.parametrize("ros2", [False, True], ids=["json", "ros2"])
def test_a_folder_of_the_two_tables_alone_exports_at_nominal_times(
    flight: Folder, tmp_path: Path, ros2: bool
) -> None:
    folder = _tables_only(flight, tmp_path)
    out = tmp_path / "tables.mcap"
    done = _mkflight("export", str(folder), "-o", str(out), *(["--ros2"] if ros2 else []))
    assert done.returncode == 0, done.stderr
    msgs = _read_ros2(out) if ros2 else _read_json(out)
    assert set(msgs) == {*ORIGINAL, topics.VELOCITY}  # TABLE III's velocities too
    assert len(msgs[topics.VELOCITY]) == len(flight.table3)
    assert [m.log_time for m in msgs[topics.MIKO_IMU]] == [
        int(i) * 50_000_000 for i in flight.table4["index"]
    ]
    assert [m.log_time for m in msgs[topics.POSE2D]] == [
        int(i) * 100_000_000 for i in flight.table3["index"]
    ]
    cmd = msgs[topics.MIKO_CMD]
    assert len(cmd) == len(flight.table4)
    for m, row in zip(cmd, flight.table4, strict=True):
        v = m.value
        got = (v["pitch"], v["throttle"]) if not ros2 else (v.pitch, v.throttle)
        assert got == (row["ControlPitch"], NO_THROTTLE)


def test_without_mk_raw_the_commands_come_from_table_iv_and_the_steps(
    flight: Folder, tmp_path: Path
) -> None:
    """A ``sim hover`` folder has no ``mk.raw``: the steps still say the gas sent."""
    folder = _tables_only(flight, tmp_path)
    shutil.copy(flight.path / "events.jsonl", folder / "events.jsonl")
    out = tmp_path / "no-raw.mcap"
    done = _mkflight("export", str(folder), "-o", str(out))
    assert done.returncode == 0, done.stderr
    cmd = _read_json(out)[topics.MIKO_CMD]
    imu_ns, _ = _table_times(flight)
    assert [m.log_time for m in cmd] == imu_ns
    gas = {s.t_ns: s.gas_counts for s in flight.steps}
    assert [m.value["throttle"] for m in cmd] == [gas[t] for t in imu_ns]
    assert max(m.value["throttle"] for m in cmd) > 0
    assert [m.value["pitch"] for m in cmd] == flight.table4["ControlPitch"].tolist()


def test_tables_exports_only_the_original_topics_of_a_whole_flight(
    flight: Folder, tmp_path: Path
) -> None:
    out = tmp_path / "t.mcap"
    done = _mkflight("export", str(flight.path), "-o", str(out), "--tables")
    assert done.returncode == 0, done.stderr
    msgs = _read_json(out)
    assert set(msgs) == ORIGINAL
    assert len(msgs[topics.MIKO_CMD]) == len(flight.commands)  # the commands, with gas
    assert "/mikoCmd" in done.stdout


# ----- the scan ---------------------------------------------------------------------------------


def test_the_scans_of_laser_raw_are_on_scan(
    flight: Folder, exported: dict[str, Any], exported_ros2: dict[str, Any]
) -> None:
    scans = read_scans(flight.path)
    plane = scans.only_steps(*scans.scan_steps)  # the hat's beams give /height instead
    beams = plane.ranges_m.shape[1]
    assert 400 < beams < scans.ranges_m.shape[1]
    fox = exported["messages"][topics.SCAN]
    ros = exported_ros2["messages"][topics.SCAN]
    assert len(fox) == len(ros) == len(scans) > 50
    assert [m.log_time for m in fox] == [m.log_time for m in ros] == scans.t_ns.tolist()
    stamps = [m.value["timestamp"]["sec"] * NS + m.value["timestamp"]["nsec"] for m in fox]
    assert stamps == scans.stamp_t_ns.tolist()
    assert {s.t_ns for s in flight.scans} <= set(stamps)  # each scan event's scan is there
    for i in (0, len(fox) // 2, len(fox) - 1):
        v, r = fox[i].value, ros[i].value
        assert v["start_angle"] == plane.angle_min_rad
        assert r.angle_min == pytest.approx(plane.angle_min_rad, abs=1e-6)  # float32
        want = plane.ranges_m[i]
        got = np.array([math.nan if x is None else x for x in v["ranges"]])
        np.testing.assert_array_equal(got, want)
        np.testing.assert_allclose(np.array(r.ranges), want, rtol=1e-6)
        assert r.header.stamp.sec * NS + r.header.stamp.nanosec == stamps[i]
    assert np.isfinite(plane.ranges_m).mean() > 0.5  # the walls are seen


@dataclass(frozen=True)
class FakeScans:
    """A ScanLog's fields that ``/scan`` reads."""

    t_ns: npt.NDArray[np.int64]
    stamp_t_ns: npt.NDArray[np.int64]
    angle_min_rad: float
    angle_increment_rad: float
    ranges_m: npt.NDArray[np.float64]


def _scans(n: int, beams: int, t0_ns: int) -> FakeScans:
    rng = np.random.default_rng(7)
    ranges = rng.uniform(0.02, 5.6, (n, beams))
    ranges[:, 3] = np.nan  # an error code
    t = t0_ns + np.arange(n, dtype=np.int64) * 100_000_000 + 12_345
    return FakeScans(t, t - 30_000_000, -2.08, 0.0061359, ranges)


@pytest.mark.parametrize("ros2", [False, True], ids=["json", "ros2"])
def test_scans_are_laser_scans_in_the_vehicle_frame(
    flight: Folder, tmp_path: Path, ros2: bool
) -> None:
    data = load_flight(flight.path)
    assert data.t0_ns is not None
    scans = _scans(20, 682, data.t0_ns)
    out = tmp_path / "scan.mcap"
    write_mcap(out, flight_series(data, scans), ros2=ros2, force=False)
    msgs = (_read_ros2 if ros2 else _read_json)(out)[topics.SCAN]
    assert [m.log_time for m in msgs] == scans.t_ns.tolist()
    for i in (0, 19):
        v = msgs[i].value
        want = scans.ranges_m[i]
        if ros2:
            assert v.header.frame_id == topics.VEHICLE_FRAME
            assert v.header.stamp.sec * NS + v.header.stamp.nanosec == scans.stamp_t_ns[i]
            assert v.angle_min == pytest.approx(-2.08, abs=1e-6)
            assert v.angle_max == pytest.approx(-2.08 + 681 * 0.0061359, abs=1e-6)
            got = np.array(v.ranges)
            np.testing.assert_allclose(got, want, rtol=1e-6)  # float32, NaN where NaN
        else:
            assert msgs[i].schema == "foxglove.LaserScan"
            assert v["frame_id"] == topics.VEHICLE_FRAME
            ts = v["timestamp"]
            assert ts["sec"] * NS + ts["nsec"] == scans.stamp_t_ns[i]
            assert v["start_angle"] == -2.08
            assert v["end_angle"] == pytest.approx(-2.08 + 681 * 0.0061359)
            assert len(v["ranges"]) == 682
            assert v["ranges"][3] is None
            got = np.array([math.nan if r is None else r for r in v["ranges"]])
            np.testing.assert_array_equal(got, want)


# ----- bad input, and never a half file ----------------------------------------------------------


def _one_error_line(done: subprocess.CompletedProcess[str]) -> str:
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("error: ")
    assert "Traceback" not in done.stderr
    return lines[0]


def test_not_a_flight_folder_is_one_error_line_and_no_file(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    done = _mkflight("export", str(tmp_path / "missing"), "-o", str(out))
    assert done.returncode == 1
    assert "not a flight folder" in _one_error_line(done)
    (tmp_path / "empty").mkdir()
    done = _mkflight("export", str(tmp_path / "empty"), "-o", str(out))
    assert done.returncode == 1
    assert "not a flight folder" in _one_error_line(done)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"]


def test_a_malformed_table_names_the_file_and_leaves_nothing(
    flight: Folder, tmp_path: Path
) -> None:
    folder = _tables_only(flight, tmp_path)
    with (folder / table3.FILE_NAME).open("a") as f:
        f.write("1 2 three\n")
    out = tmp_path / "out" / "x.mcap"
    out.parent.mkdir()
    done = _mkflight("export", str(folder), "-o", str(out))
    assert done.returncode == 1
    assert table3.FILE_NAME in _one_error_line(done)
    assert list(out.parent.iterdir()) == []


def test_an_existing_file_is_kept_unless_forced(flight: Folder, tmp_path: Path) -> None:
    folder = _tables_only(flight, tmp_path)
    out = tmp_path / "x.mcap"
    out.write_bytes(b"precious")
    done = _mkflight("export", str(folder), "-o", str(out))
    assert done.returncode == 2
    assert "--force" in _one_error_line(done)
    assert out.read_bytes() == b"precious"
    done = _mkflight("export", str(folder), "-o", str(out), "--force")
    assert done.returncode == 0, done.stderr
    assert set(_read_json(out)) == {*ORIGINAL, topics.VELOCITY}
    done = _mkflight("export", str(folder), "-o", str(tmp_path / "no" / "x.mcap"))
    assert done.returncode == 2
    assert "no such directory" in _one_error_line(done)
    assert _mkflight("export", str(folder)).returncode == 2  # -o is required


def test_table_rows_without_a_time_are_left_out_and_counted(flight: Folder, tmp_path: Path) -> None:
    folder = tmp_path / "cut"
    shutil.copytree(flight.path, folder)
    lines = (folder / "events.jsonl").read_text().splitlines(keepends=True)
    steps = [i for i, line in enumerate(lines) if '"event":"step"' in line.replace(" ", "")]
    assert len(steps) == len(flight.steps)
    dropped = set(steps[-5:])  # as if the last steps' events were never written
    (folder / "events.jsonl").write_text(
        "".join(x for i, x in enumerate(lines) if i not in dropped)
    )
    out = tmp_path / "cut.mcap"
    done = _mkflight("export", str(folder), "-o", str(out), "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["left_out"] == {table4.FILE_NAME: 5}
    assert summary["counts"][topics.MIKO_IMU] == len(flight.table4) - 5
    done = _mkflight("export", str(folder), "-o", str(tmp_path / "cut2.mcap"))
    assert f"not exported: 5 rows of {table4.FILE_NAME} without a time" in done.stdout


def test_a_failure_while_writing_leaves_no_half_file(
    flight: Folder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = _tables_only(flight, tmp_path)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "old.mcap").write_bytes(b"old")

    def broken(kind: str, row: dict[str, Any], t_ns: int) -> bytes:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("mkflight.ground.export_json.json_message", broken)
    with pytest.raises(export_module.ExportError, match="No space left"):
        export_flight(folder, out_dir / "old.mcap", force=True)
    with pytest.raises(ConfigError, match="exists"):
        export_flight(folder, out_dir / "old.mcap")
    assert [p.name for p in out_dir.iterdir()] == ["old.mcap"]
    assert (out_dir / "old.mcap").read_bytes() == b"old"


def test_a_file_system_without_hard_links_still_gets_the_file(
    flight: Folder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_links(src: object, dst: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    folder = _tables_only(flight, tmp_path)
    out = tmp_path / "out" / "x.mcap"
    out.parent.mkdir()
    r = export_flight(folder, out)
    assert set(_read_json(out)) == {*ORIGINAL, topics.VELOCITY}
    assert [p.name for p in out.parent.iterdir()] == ["x.mcap"]
    assert r.size_bytes == out.stat().st_size
    assert out.stat().st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@pytest.mark.parametrize(("ros2", "module"), [(False, "mcap.writer"), (True, "mcap_ros2.writer")])
def test_a_missing_writer_names_the_extra(
    flight: Folder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ros2: bool, module: str
) -> None:
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    with pytest.raises(export_module.ExportError, match=r"mkflight\[export\]"):
        export_flight(_tables_only(flight, tmp_path), tmp_path / "x.mcap", ros2=ros2)
    assert not (tmp_path / "x.mcap").exists()


# ----- the pure conversions --------------------------------------------------------------------

_finite = st.floats(-1e3, 1e3, allow_nan=False)


def _rows(n: int, fmt: Any, draw_values: list[float]) -> npt.NDArray[Any]:
    rows = np.zeros(n, fmt.dtype)
    for k, name in enumerate(fmt.columns):
        if name == "index":
            rows[name] = np.arange(1, n + 1)
        else:
            rows[name] = [draw_values[(k * 7 + i) % len(draw_values)] for i in range(n)]
    return rows


@given(
    values=st.lists(st.integers(-128, 128).map(float), min_size=1, max_size=30),
    times=st.lists(
        st.one_of(st.floats(0, 1e5, allow_nan=False), st.just(math.nan)), min_size=1, max_size=30
    ),
    t0_ns=st.integers(0, 2**50),
)
def test_tables_to_messages_keep_every_timed_row_in_time_order(
    values: list[float], times: list[float], t0_ns: int
) -> None:
    n = len(times)
    t_s = np.array(times)
    imu = _rows(n, table4.FORMAT, values)
    laser = _rows(n, table3.FORMAT, values)
    timed = [i for i in range(n) if math.isfinite(times[i])]
    order = sorted(timed, key=lambda i: (round(times[i] * NS), timed.index(i)))
    for series, table, mapping in (
        (pose2d_from_table3(laser, t_s, t0_ns), laser, {"x": "CurrentPosition.x"}),
        (miko_imu_from_table4(imu, t_s, t0_ns), imu, {"AccY": "AccY", "rollAngle": "AngleRoll"}),
        (miko_cmd_from_table4(imu, t_s, t0_ns), imu, {"yaw": "ControlYaw"}),
    ):
        assert series.t_ns.tolist() == [t0_ns + round(times[i] * NS) for i in order]
        for name, column in mapping.items():
            assert series.columns[name].tolist() == [table[column][i] for i in order]
    cmd = miko_cmd_from_table4(imu, t_s, t0_ns)
    assert set(cmd.columns["throttle"].tolist()) <= {NO_THROTTLE}


@given(st.lists(st.integers(0, 40), max_size=20, unique=True), st.integers(0, 30))
def test_row_gas_is_the_rows_step_or_not_recorded(indexes: list[int], steps: int) -> None:
    imu = np.zeros(len(indexes), table4.FORMAT.dtype)
    imu["index"] = sorted(indexes)
    step_table = np.zeros(steps, [("t_s", float), ("gas_counts", float)])
    step_table["gas_counts"] = np.arange(steps) * 3.0 + 100
    step_table["gas_counts"][::4] = math.nan  # a step whose gas is null
    got = row_gas(imu, step_table).tolist()
    for i, g in zip(imu["index"].tolist(), got, strict=True):
        known = 1 <= i <= steps and (i - 1) % 4 != 0
        assert g == ((i - 1) * 3 + 100 if known else NO_THROTTLE)


@given(st.integers(0, 2**62), st.integers(0, 2**40))
def test_seconds_since_t0_come_back_to_the_same_nanosecond(t0_ns: int, dt_ns: int) -> None:
    """load_flight's t_s = (t_ns - t0_ns) / 1e9; the export's t_ns is exact again."""
    laser = _rows(1, table3.FORMAT, [0.0])
    series = pose2d_from_table3(laser, np.array([dt_ns / NS]), t0_ns)
    assert series.t_ns.tolist() == [t0_ns + dt_ns]
    sec, nsec = stamp(t0_ns + dt_ns)
    assert sec * NS + nsec == t0_ns + dt_ns
    assert 0 <= nsec < NS


@given(st.floats(-math.pi, math.pi), st.sampled_from([0.0, math.pi]))
def test_quaternions_are_unit_and_turn_by_the_angle(yaw: float, roll: float) -> None:
    x, y, z, w = quaternion(roll_rad=roll, yaw_rad=yaw)
    assert x * x + y * y + z * z + w * w == pytest.approx(1.0)
    if roll == 0.0:
        assert math.atan2(2 * w * z, 1 - 2 * z * z) == pytest.approx(yaw, abs=1e-9)


def test_scan_series_sorts_by_time_and_keeps_each_beam() -> None:
    scans = _scans(5, 10, 1000)
    shuffled = FakeScans(
        scans.t_ns[::-1].copy(),
        scans.stamp_t_ns[::-1].copy(),
        scans.angle_min_rad,
        scans.angle_increment_rad,
        scans.ranges_m[::-1],
    )
    s = scan_series(shuffled)
    assert s.t_ns.tolist() == scans.t_ns.tolist()
    assert s.columns["stamp_ns"].tolist() == scans.stamp_t_ns.tolist()
    np.testing.assert_array_equal(s.columns["ranges_m"], scans.ranges_m)
    assert s.row(0)["angle_min_rad"] == -2.08
