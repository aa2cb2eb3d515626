"""mkflight.logs.scans: a real flight's ``laser.raw`` decoded as the driver decoded it."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from mkflight.errors import ReplayError
from mkflight.logs import load_flight, read_events, read_flight_json
from mkflight.logs.raw import RawRecorder, read_raw
from mkflight.logs.scans import ScanLog, decode_scans, read_scans
from mkflight.logs.schema import UNSET, FlightSummary, Scan
from mkflight.sim.room import raycast
from mkflight.sim.world import default_room
from tests.flights import HOVER_SIM_8S

pytestmark = pytest.mark.background(HOVER_SIM_8S)  # sim_flight


def _nan(value: float | None) -> float:
    return math.nan if value is None else value


def _scan_events(folder: Path) -> list[Scan]:
    return [e for e in read_events(folder / "events.jsonl").events if isinstance(e, Scan)]


def _summary(folder: Path) -> FlightSummary:
    summary = read_flight_json(folder / "flight.json").summary
    assert isinstance(summary, FlightSummary)
    return summary


def _assert_same_scans(a: ScanLog, b: ScanLog, n: int | None = None) -> None:
    n = len(b) if n is None else n
    np.testing.assert_array_equal(a.t_ns[:n], b.t_ns[:n])
    np.testing.assert_array_equal(a.seq[:n], b.seq[:n])
    np.testing.assert_array_equal(a.ranges_m[:n], b.ranges_m[:n])  # NaN == NaN here


def test_every_scan_the_driver_took_with_its_events_pose(sim_flight: Path) -> None:
    scans = read_scans(sim_flight)
    events = _scan_events(sim_flight)
    link = _summary(sim_flight).laser_link
    assert link is not UNSET
    # every scan the driver numbered, pre-flight ones included; the flight's scan events
    # are those the matcher got (a subset: the driver keeps only the newest scan)
    assert len(scans) == link.scans > len(events) > 50
    np.testing.assert_array_equal(scans.seq, np.arange(1, len(scans) + 1))
    assert scans.warnings == ()
    row = {int(s): i for i, s in enumerate(scans.seq)}
    for e in events:
        i = row[e.seq]
        assert scans.stamp_t_ns[i] == e.t_ns  # the driver's own stamp, recomputed
        assert e.x_m is not UNSET
        assert e.y_m is not UNSET
        assert e.yaw_rad is not UNSET
        want = [_nan(e.x_m), _nan(e.y_m), _nan(e.yaw_rad), _nan(e.height_m)]
        got = [scans.pose_x_m[i], scans.pose_y_m[i], scans.pose_psi_rad[i], scans.height_m[i]]
        np.testing.assert_array_equal(got, want)  # exactly; NaN where the event has null
    without = np.ones(len(scans), dtype=bool)
    without[[row[e.seq] for e in events]] = False
    assert np.isnan(scans.pose_x_m[without]).all()
    assert np.isnan(scans.height_m[without]).all()
    assert (np.diff(scans.t_ns) >= 0).all()  # one read may complete two replies (a busy host)
    assert (np.diff(scans.stamp_t_ns) > 0).all()  # the sensor's own times do not repeat
    assert (scans.t_ns > scans.stamp_t_ns).all()  # read after its front step was measured


def test_ranges_are_the_simulated_room_in_the_body_frame(sim_flight: Path) -> None:
    scans = read_scans(sim_flight)
    cfg = read_flight_json(sim_flight / "flight.json").config["laser"]
    assert scans.scan_steps == tuple(cfg["scan_steps"])
    assert scans.params.ares_steps == 1024
    assert scans.ranges_m.shape == (len(scans), 725 - 44 + 1)
    plane = scans.only_steps(*scans.scan_steps)
    assert plane.ranges_m.shape[1] == cfg["scan_steps"][1] - cfg["scan_steps"][0] + 1
    assert plane.beam_steps[0] == cfg["scan_steps"][1]  # increasing body angle: left first
    assert plane.angles_rad[0] == pytest.approx(-(725 - 384) * 2 * np.pi / 1024)
    assert plane.angle_increment_rad == pytest.approx(2 * np.pi / 1024)
    # the room's walls are 1.2-2.4 m away, its corners 3 m: every range within 4 m
    assert np.nanmax(plane.ranges_m) < 4.0
    assert np.nanmin(plane.ranges_m) > 0.2
    # the first scan, on the ground at the origin, is the room ray-cast from there
    # (sensor angles clockwise, the room's counter-clockwise)
    expected = raycast(default_room(), 0.0, 0.0, 0.0, -plane.angles_rad, 5.6)
    error = np.abs(plane.ranges_m[0] - expected)
    assert np.nanmedian(error) < 0.02
    assert np.isfinite(error).mean() > 0.95


def test_error_codes_are_nan_never_a_distance(sim_flight: Path) -> None:
    scans = read_scans(sim_flight)
    decoded = decode_scans(read_raw(sim_flight / "laser.raw"))
    values = np.array([d.reply.values for d in decoded.scans], dtype=np.float64)[:, ::-1]
    invalid = (values < scans.params.dmin_mm) | (values > scans.params.dmax_mm)
    assert invalid.any()  # the simulated URG sends error codes too
    assert np.isnan(scans.ranges_m[invalid]).all()
    np.testing.assert_array_equal(scans.ranges_m[~invalid], values[~invalid] / 1000.0)


def test_the_time_base_is_load_flights(sim_flight: Path) -> None:
    flight = load_flight(sim_flight)
    scans = flight.laser_scans
    assert scans is not None
    assert flight.t0_ns is not None
    assert scans.t0_ns == flight.t0_ns
    np.testing.assert_allclose(scans.t_s, (scans.t_ns - flight.t0_ns) / 1e9)
    # the TABLE III rows' times are their scan events' (the stamps)
    matched = {int(s): t for s, t in zip(scans.seq, scans.stamp_t_ns, strict=True)}
    stamp_s = [(matched[int(q)] - flight.t0_ns) / 1e9 for q in flight.scans["seq"]]
    np.testing.assert_allclose(stamp_s, flight.scans["t_s"])
    alone = read_scans(sim_flight / "laser.raw", t0_ns=flight.t0_ns)
    _assert_same_scans(alone, scans)
    np.testing.assert_array_equal(alone.t_s, scans.t_s)
    np.testing.assert_array_equal(alone.pose_x_m, scans.pose_x_m)
    # without t0_ns, the recording's own start
    own = read_scans(sim_flight)
    assert own.t0_ns == read_raw(sim_flight / "laser.raw").header.start_t_ns


def test_a_cut_recording_reads_up_to_the_cut_with_a_warning(
    sim_flight: Path, tmp_path: Path
) -> None:
    whole = read_scans(sim_flight)
    blob = (sim_flight / "laser.raw").read_bytes()
    cut = tmp_path / "laser.raw"
    cut.write_bytes(blob[: len(blob) // 2 + 7])
    scans = read_scans(cut)  # alone: no events, no flight.json beside it
    assert any("incomplete last record" in w for w in scans.warnings)
    assert len(whole) // 3 < len(scans) < len(whole)
    _assert_same_scans(scans, whole, len(scans))
    assert np.isnan(scans.pose_x_m).all()


def test_a_reply_with_a_bad_checksum_is_dropped_as_in_flight(
    sim_flight: Path, tmp_path: Path
) -> None:
    rec = read_raw(sim_flight / "laser.raw")
    reads = [i for i, r in enumerate(rec.records) if r.kind == "r" and len(r.data) > 1000]
    damaged = reads[len(reads) // 2]
    out = tmp_path / "laser.raw"
    with RawRecorder(out, rec.header.port_name, wall_clock_ns=lambda: 0) as writer:
        for i, r in enumerate(rec.records):
            data = r.data
            if i == damaged:  # one data character changed: the block's sum no longer fits
                k = next(j for j in range(500, len(data)) if 0x30 <= data[j] < 0x6F)
                data = data[:k] + bytes([data[k] + 1]) + data[k + 1 :]
            if r.kind in "rw":
                writer(r.kind, r.t_ns, data)
            else:
                writer.mark(r.kind, r.t_ns, r.text)
    whole = read_scans(sim_flight / "laser.raw")
    scans = read_scans(out)
    assert len(scans) == len(whole) - 1
    assert any("1 replies with a bad checksum" in w for w in scans.warnings)


def test_a_folder_without_laser_raw(sim_flight: Path, tmp_path: Path) -> None:
    folder = tmp_path / "no-laser"
    shutil.copytree(sim_flight, folder, ignore=shutil.ignore_patterns("laser.raw"))
    assert load_flight(folder).laser_scans is None
    with pytest.raises(ReplayError, match=r"laser\.raw: no such file"):
        read_scans(folder)


def test_a_recording_without_scans_is_an_empty_log(tmp_path: Path) -> None:
    path = tmp_path / "laser.raw"
    with RawRecorder(path, "/dev/ttyACM0") as writer:
        writer("w", 1, b"QT\n")
    scans = read_scans(path)
    assert len(scans) == 0
    assert scans.ranges_m.shape == (0, 0)
    assert scans.warnings == ()


def test_another_versions_laser_config_gives_the_defaults_and_a_warning(
    sim_flight: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "newer"
    shutil.copytree(sim_flight, folder)
    info = json.loads((folder / "flight.json").read_text())
    info["config"]["laser"]["a_newer_key"] = 1
    (folder / "flight.json").write_text(json.dumps(info))
    flight = load_flight(folder)
    assert flight.laser_scans is not None
    assert any("config.laser" in w and "defaults used" in w for w in flight.warnings)
    _assert_same_scans(flight.laser_scans, read_scans(sim_flight, t0_ns=flight.t0_ns))
    assert any("config.laser" in w for w in read_scans(folder).warnings)
