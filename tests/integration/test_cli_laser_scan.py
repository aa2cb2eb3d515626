"""``mkflight laser scan`` end to end: the real CLI process against URG emulators on ptys."""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import AsyncIterator

import numpy as np
import pytest

from mkflight.io.pty import PtyDevice
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg_scene import RoomScene, ScenePose
from mkflight.sim.urg_server import UrgEmulator

from .test_cli_mk_info import error_lines, run_cli

POSE = ScenePose(x_m=0.0, y_m=0.0, yaw_rad=0.0, height_m=0.45)
KEYS = {"t", "angle_min_rad", "angle_increment_rad", "ranges_m", "height_m"}


@pytest.fixture
async def emulator() -> AsyncIterator[UrgEmulator]:
    scene = RoomScene(room_caster(box_room(6.0, 4.0)), pose=POSE, seed=2)
    async with UrgEmulator(scene) as emu:
        yield emu


async def test_json_scans_match_the_room_and_the_height(emulator: UrgEmulator) -> None:
    code, out, err, _ = await run_cli(
        "laser", "scan", "--port", emulator.path, "--count", "5", "--json"
    )
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert len(rows) == 5
    for row in rows:
        assert set(row) == KEYS
        assert row["angle_min_rad"] == pytest.approx(-(725 - 384) * 2 * math.pi / 1024)
        assert row["angle_increment_rad"] == pytest.approx(2 * math.pi / 1024)
        ranges = row["ranges_m"]
        assert len(ranges) == 725 - 150 + 1
        angles = row["angle_min_rad"] + row["angle_increment_rad"] * np.arange(len(ranges))
        # The box is 6 x 4 m around the sensor: ahead 3 m, right (+pi/2) and left 2 m.
        for angle, wall_m in ((0.0, 3.0), (math.pi / 2, 2.0), (-math.pi / 2, 2.0)):
            i = int(np.argmin(np.abs(angles - angle)))
            if ranges[i] is not None:
                assert ranges[i] == pytest.approx(
                    wall_m / max(abs(math.cos(angle)), abs(math.sin(angle))), abs=0.05
                )
        assert sum(r is None for r in ranges) < 20  # the emulator's 0.5 % error codes
        assert row["height_m"] == pytest.approx(0.45, abs=0.01)
    gaps = [b["t"] - a["t"] for a, b in itertools.pairwise(rows)]
    assert all(g == pytest.approx(0.1, abs=0.01) for g in gaps)


async def test_sim_prints_the_sensor_and_scans() -> None:
    code, out, err, _ = await run_cli("laser", "scan", "--sim", "--count", "3")
    assert code == 0, err
    lines = out.splitlines()
    assert "URG-04LX" in lines[0]
    assert lines[1].split() == ["t_s", "valid", "min_m", "front_m", "height_m"]
    rows = [line.split() for line in lines[2:]]
    assert len(rows) == 3
    for r in rows:
        assert float(r[3]) == pytest.approx(3.0, abs=0.05)  # the 6 m room's front wall
        assert float(r[4]) == pytest.approx(0.0, abs=0.01)  # standing on the floor


async def test_missing_port_exits_2() -> None:
    code, _, err, _ = await run_cli("laser", "scan", "--port", "/dev/ttyACM_NOPE")
    assert code == 2
    assert error_lines(err) == ["error: serial port '/dev/ttyACM_NOPE' does not exist"]


async def test_silent_device_exits_1_with_a_clear_line() -> None:
    device = PtyDevice("silent")
    try:
        code, out, err, wall_s = await run_cli("laser", "scan", "--port", device.path)
    finally:
        await device.close()
    assert code == 1
    assert out == ""
    (line,) = error_lines(err)
    assert line.startswith(f"error: no answer to SCIP2.0 from the laser on {device.path}")
    assert "Traceback" not in err
    assert wall_s < 5.0
