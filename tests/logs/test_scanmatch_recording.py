"""``mkflight scanmatch`` over our own recordings: a flight folder or its ``laser.raw``."""

from __future__ import annotations

import dataclasses
import math
import shutil
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
from mkflight.scanmatch.log_tracking import (
    odom_in_math,
    poses_in_w,
    records_from_scans,
    track_records,
)
from mkflight.scanmatch.trajectory import read_trajectory
from mkflight.sim.room import raycast
from mkflight.sim.world import default_room
from tests.flights import HOVER_SIM_8S

pytestmark = pytest.mark.background(HOVER_SIM_8S)  # sim_flight


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
    # at every scan event with a pose, the pose the flight's matcher gave that scan: the
    # same matcher on the same levelled points, so on the ground the same pose. In the
    # air the flight also had the estimator's velocity as its prior and, on a loaded
    # machine, fewer scans (other keyframes): close, not equal. At touchdown the attitude
    # swings; without that prior one bad match can stay (the constant-velocity
    # prediction carries it on), so the close comparison ends at LAND.
    events = flight.scans[flight.scans["valid"] == 1.0]
    row = np.array([int(np.argmin(np.abs(t - te))) for te in events["t_s"]])
    np.testing.assert_allclose(t[row], events["t_s"], atol=1e-6)
    flown = np.stack((events["x_m"], events["y_m"], events["yaw_rad"]), axis=1)
    assert np.isfinite(flown).all()
    error = np.abs(poses[row] - flown)
    phase_s = {
        e.to: (e.t_ns - flight.t0_ns) / 1e9 for e in flight.events if isinstance(e, PhaseChange)
    }
    ground = events["t_s"] < phase_s["TAKEOFF"]
    assert 5 < ground.sum() < len(events)
    assert error[ground].max() < 1e-3
    flying = events["t_s"] < phase_s["LAND"]
    assert np.median(error[:, :2]) < 0.005
    assert np.sqrt(np.mean(error[flying, :2] ** 2)) < 0.02
    # and the simulator's truth (W as well: y right)
    assert flight.truth is not None
    for k, key in enumerate(("x_m", "y_m")):
        truth = np.interp(t, flight.truth["t_s"], flight.truth[key])
        off = np.abs(poses[:, k] - truth)
        assert np.median(off) < 0.005
        assert np.percentile(off[t < phase_s["LAND"]], 95) < 0.015


def test_its_laser_raw_gives_the_same_lines_and_alone_a_level_track(
    sim_flight: Path, tmp_path: Path
) -> None:
    folder = (tmp_path / "a.txt").resolve()
    _scanmatch(sim_flight, folder)
    proc = subprocess.run(
        [sys.executable, "-m", "mkflight", "scanmatch", str(sim_flight / "laser.raw")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert proc.stdout == folder.read_text()
    # outside its flight folder: no attitude, no flight's time base; still every scan
    alone = tmp_path / "laser.raw"
    shutil.copy(sim_flight / "laser.raw", alone)
    t, poses = _scanmatch(alone, tmp_path / "b.txt")
    assert len(t) == len(read_scans(sim_flight))
    read_s = read_scans(alone).t_s
    assert (t < read_s).all()  # the front step's time, before the reply was read
    assert (read_s - t < 0.5).all()
    # a hover about the origin (unlevelled: a touchdown's tilted scan may jump)
    assert np.median(np.abs(poses[:, :2])) < 0.02


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
    # odometry given in W is the prior once turned into the matcher's frame
    odom_t = np.arange(n, dtype=np.float64) * 0.1
    odom = odom_in_math((odom_t, np.array(truth_w, dtype=np.float64)))
    with_odom = poses_in_w(track_records(records, scan_steps=template.scan_steps, odom=odom))
    assert all(s.used_odom for s in with_odom[1:])
    for s, want in zip(with_odom, truth_w, strict=True):
        assert s.pose == pytest.approx(want, abs=2e-3)


def test_a_folder_without_laser_raw_is_one_clear_error(sim_flight: Path, tmp_path: Path) -> None:
    empty = tmp_path / "no-flight"
    empty.mkdir()
    with pytest.raises(ReplayError, match="not a flight folder"):
        cmd_scanmatch(log=str(empty), odom=None, out=None, config_path=None, overrides=[])
    tables_only = tmp_path / "tables-only"
    shutil.copytree(sim_flight, tables_only, ignore=shutil.ignore_patterns("laser.raw"))
    with pytest.raises(ReplayError, match=r"tables-only/laser\.raw: no such file"):
        cmd_scanmatch(log=str(tables_only), odom=None, out=None, config_path=None, overrides=[])
