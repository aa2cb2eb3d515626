"""UrgDriver against the URG emulator over real pseudo-terminals."""

from __future__ import annotations

import asyncio
import itertools
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from mkflight.config import LaserConfig
from mkflight.errors import LinkError
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg_scene import RoomScene, ScenePose
from mkflight.sim.urg_server import UrgEmulator
from mkflight.urg.driver import UrgDriver
from mkflight.urg.hat import HatSettings, hat_height
from mkflight.urg.units import step_body_angle_rad

POSE = ScenePose(x_m=0.5, y_m=-0.3, yaw_rad=0.1, height_m=0.6)


@pytest.fixture
async def emulator(tmp_path: Path) -> AsyncIterator[UrgEmulator]:
    scene = RoomScene(room_caster(box_room(6.0, 4.0)), pose=POSE, seed=5)
    async with UrgEmulator(scene, link=tmp_path / "urg0") as emu:
        yield emu


async def open_driver(
    emulator: UrgEmulator, laser: LaserConfig | None = None, failed: asyncio.Event | None = None
) -> UrgDriver:
    async def opener() -> ByteStream:
        try:
            return await open_serial(emulator.path, 115200)
        except LinkError:
            if failed is not None:
                failed.set()
            raise

    driver = UrgDriver(await opener(), laser, reopen=opener)
    await driver.connect()
    await driver.start_stream()
    return driver


async def test_startup_reads_the_sensor_and_streams_at_10_hz(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator)
    assert driver.info is not None
    assert driver.params.amin_step == 44
    assert driver.params.amax_step == 725
    assert "URG-04LX" in driver.info.summary
    scans = [await driver.next_scan(timeout_s=1.0) for _ in range(8)]
    gaps_s = [(b.t_ns - a.t_ns) / 1e9 for a, b in itertools.pairwise(scans)]
    assert np.median(gaps_s) == pytest.approx(0.1, abs=0.01)
    scan = scans[-1]
    assert scan.first_step == 44
    assert scan.ranges_m.shape == (682,)
    await driver.close()
    assert emulator.model.rx_by_command["QT"] >= 2  # once at start-up, once on close


async def test_scans_are_stamped_when_taken_not_when_they_arrived(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator)
    for _ in range(3):
        await driver.next_scan(timeout_s=1.0)
    scan = await driver.next_scan(timeout_s=1.0)
    arrived_ns = time.monotonic_ns()
    age_ms = (arrived_ns - scan.t_ns) / 1e6
    # Front step 37.5 ms after step 0; the message leaves at step 725 (70.8 ms) + 30 ms USB.
    assert 50 <= age_ms <= 90
    await driver.close()


async def test_ranges_are_the_room_and_the_hat_gives_height(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator)
    scan = await driver.next_scan(timeout_s=1.0)
    steps = np.arange(scan.first_step, scan.first_step + scan.ranges_m.size)
    # Straight ahead (step 384) with yaw 0.1 rad to the right from (0.5, -0.3): the
    # front wall at x = 3 is (3 - 0.5) / cos(0.1) away.
    front = scan.ranges_m[steps == 384][0]
    assert front == pytest.approx(2.5 / math.cos(0.1), abs=0.05)
    assert step_body_angle_rad(384) == 0.0
    hat = scan.ranges_m[(steps >= 44) & (steps <= 127)]
    height = hat_height(hat, 0.0, 0.0, HatSettings.from_config(LaserConfig()))
    assert height.valid
    assert height.height_m == pytest.approx(0.6, abs=0.01)
    assert np.isnan(scan.ranges_m).sum() < 40  # error codes and mirror junk only
    assert np.nanmin(scan.ranges_m) >= 0.02  # never a "distance" below DMIN
    await driver.close()


async def test_checksum_errors_are_dropped_and_counted(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator)
    await driver.next_scan(timeout_s=1.0)
    emulator.corrupt_next(2)
    emulator.inject_garbage(b"garbage line\n\x00\xff\n\n")
    for _ in range(4):
        await driver.next_scan(timeout_s=2.0)
    assert driver.stats.parser.sum_errors >= 2
    assert driver.stats.parser.garbage_lines >= 1
    await driver.close()


async def test_a_stalled_stream_is_restarted(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator, LaserConfig(stall_s=0.3))
    await driver.next_scan(timeout_s=1.0)
    emulator.stall_for(0.6)
    scan = await driver.next_scan(timeout_s=3.0)
    assert scan.ranges_m.size == 682
    assert driver.stats.stalls >= 1
    assert driver.stats.restarts >= 1
    await driver.close()


async def test_a_stream_that_never_recovers_fails_clearly(emulator: UrgEmulator) -> None:
    driver = await open_driver(emulator, LaserConfig(stall_s=0.15, max_restarts=2))
    await driver.next_scan(timeout_s=1.0)
    emulator.stall_for(30.0)
    with pytest.raises(LinkError, match=r"sends no usable scans: 2 stream restarts in a row"):
        await driver.next_scan(timeout_s=10.0)
    await driver.close()


async def test_vanish_is_reported_and_reopen_recovers(emulator: UrgEmulator) -> None:
    failed = asyncio.Event()
    laser = LaserConfig(reopen_backoff_s=0.05, reopen_backoff_max_s=0.2)
    driver = await open_driver(emulator, laser, failed)
    await driver.next_scan(timeout_s=1.0)
    emulator.vanish()
    with pytest.raises(LinkError, match="vanished"):
        await driver.next_scan(timeout_s=1.0)
    reopening = asyncio.create_task(driver.reopen(max_wait_s=5.0))
    await asyncio.wait_for(failed.wait(), 2.0)
    emulator.replug()  # a UG01 powers up again: SCIP 1.1, timer at 0
    await reopening
    scan = await driver.next_scan(timeout_s=2.0)
    assert scan.ranges_m.size == 682
    assert driver.stats.reopens == 1
    await driver.close()


async def test_garbage_only_device_fails_with_a_clear_error(tmp_path: Path) -> None:
    from mkflight.io.pty import PtyDevice

    device = PtyDevice("junk")

    async def spew() -> None:
        while True:
            await device.read()
            device.write(b"\x00\xffnot scip\n")

    task = asyncio.create_task(spew())
    driver = UrgDriver(await open_serial(device.path, 115200), LaserConfig(request_timeout_s=0.3))
    with pytest.raises(LinkError, match=r"no answer to SCIP2\.0 from the laser on /dev/pts/"):
        await driver.connect()
    await driver.close()
    task.cancel()
    await device.close()
