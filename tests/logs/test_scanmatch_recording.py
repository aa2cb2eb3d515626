"""``mkflight scanmatch`` over our own recordings: a flight folder or its ``laser.raw``."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mkflight.commands.scanmatch import cmd_scanmatch
from mkflight.errors import ReplayError
from mkflight.logs import load_flight
from mkflight.logs.scans import read_scans
from mkflight.logs.schema import PhaseChange
from mkflight.scanmatch.log_tracking import poses_in_w, records_from_scans, track_records
from mkflight.scanmatch.trajectory import read_trajectory
from mkflight.sim.room import raycast
from mkflight.sim.world import default_room


def _scanmatch(log: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    assert cmd_scanmatch(log=str(log), odom=None, out=str(out), config_path=None, overrides=[]) == 0
    return read_trajectory(out)


def test_a_flight_folder_gives_the_flights_own_poses(
    sim_flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, poses = _scanmatch(sim_flight, tmp_path / "traj.txt")
    flight = load_flight(sim_flight)
    scans = flight.laser_scans
    assert scans is not None
    assert len(t) == len(scans)
    assert f"scanmatch: {len(scans)} scans" in capsys.readouterr().err
    assert (
        (tmp_path / "traj.txt").read_text().splitlines()[0].endswith(" 0.000000 0.000000 0.000000")
    )
    # one line per scan, at its front step's time on load_flight's time base
    assert flight.t0_ns is not None
    np.testing.assert_allclose(t, (scans.stamp_t_ns - flight.t0_ns) / 1e9, atol=1e-6)
    # at every scan event, the pose the flight's matcher gave that scan: the same matcher,
    # so on the ground the same pose; in the air it levelled the beams by the attitude
    # and took the estimator's velocity as its prior, which this does not
    events = flight.scans
    row = np.array([int(np.argmin(np.abs(t - te))) for te in events["t_s"]])
    np.testing.assert_allclose(t[row], events["t_s"], atol=1e-6)
    flown = np.stack((events["x_m"], events["y_m"], events["yaw_rad"]), axis=1)
    error = poses[row] - flown
    takeoff_s = next(
        (e.t_ns - flight.t0_ns) / 1e9
        for e in flight.events
        if isinstance(e, PhaseChange) and e.to == "TAKEOFF"
    )
    ground = events["t_s"] < takeoff_s
    assert 5 < ground.sum() < len(events)
    assert np.abs(error[ground]).max() < 1e-3
    assert np.sqrt(np.mean(error[:, :2] ** 2)) < 0.015
    assert np.abs(error[:, :2]).max() < 0.05
    assert np.abs(error[:, 2]).max() < 0.02
    # and the simulator's truth (W as well: y right)
    assert flight.truth is not None
    for k, key in enumerate(("x_m", "y_m")):
        truth = np.interp(t, flight.truth["t_s"], flight.truth[key])
        assert np.abs(poses[:, k] - truth).max() < 0.04


def test_its_laser_raw_alone_gives_the_same_lines(sim_flight: Path, tmp_path: Path) -> None:
    folder = (tmp_path / "a.txt").resolve()
    alone = tmp_path / "b.txt"
    _scanmatch(sim_flight, folder)
    proc = subprocess.run(
        [sys.executable, "-m", "mkflight", "scanmatch", str(sim_flight / "laser.raw")],
        capture_output=True,
        text=True,
        check=True,
    )
    alone.write_text(proc.stdout)
    assert proc.stdout == folder.read_text()


def test_the_output_is_in_w_moving_right_and_turning_clockwise(sim_flight: Path) -> None:
    """Scans ray-cast from poses moving +y (right) and turning +psi (clockwise) in W."""
    template = read_scans(sim_flight)
    room = default_room()  # math frame: y left, angles counter-clockwise
    n = 15
    truth_w = [(0.01 * i, 0.02 * i, 0.01 * i) for i in range(n)]
    body = template.angles_rad  # right positive
    ranges = np.array(
        [raycast(room, x, -y, -psi, -body, 5.6) for x, y, psi in truth_w], dtype=np.float64
    )
    stamp = template.t0_ns + np.arange(n, dtype=np.int64) * 100_000_000
    synthetic = dataclasses.replace(
        template,
        t_ns=stamp + 70_000_000,
        t_s=(stamp + 70_000_000 - template.t0_ns) / 1e9,
        stamp_t_ns=stamp,
        sensor_ms=template.sensor_ms[:n],
        seq=np.arange(1, n + 1),
        ranges_m=ranges,
    )
    records = records_from_scans(synthetic, min_range_m=0.02, max_range_m=5.6)
    tracked = poses_in_w(track_records(records, scan_steps=template.scan_steps))
    assert [s.t_s for s in tracked] == pytest.approx(0.1 * np.arange(n))
    for s, want in zip(tracked, truth_w, strict=True):
        assert s.pose == pytest.approx(want, abs=2e-3)
    assert math.copysign(1.0, tracked[-1].pose[1]) == 1.0  # right is +y


def test_a_folder_without_laser_raw_is_one_clear_error(sim_flight: Path, tmp_path: Path) -> None:
    empty = tmp_path / "no-flight"
    empty.mkdir()
    with pytest.raises(ReplayError, match=r"laser\.raw: no such file"):
        cmd_scanmatch(log=str(empty), odom=None, out=None, config_path=None, overrides=[])
