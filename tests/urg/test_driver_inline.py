"""UrgDriver.next_scan(inline=...): scans handled in the port's callback, recovery kept.

Over a real pseudo-terminal (the URG emulator), so that the driver parses in the serial
port's own callback as in flight.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mkflight.config import LaserConfig
from mkflight.io.serial import open_serial
from mkflight.msgs import Scan
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg_scene import RoomScene, ScenePose
from mkflight.sim.urg_server import UrgEmulator
from mkflight.urg.driver import UrgDriver


class Enough(Exception):
    """Ends a test's inline handling."""


@pytest.fixture
async def driver(tmp_path: Path) -> AsyncIterator[tuple[UrgDriver, UrgEmulator]]:
    scene = RoomScene(room_caster(box_room(6.0, 4.0)), pose=ScenePose(height_m=0.6), seed=5)
    async with UrgEmulator(scene, link=tmp_path / "urg0") as emu:
        drv = UrgDriver(await open_serial(emu.path, 115200), LaserConfig(stall_s=0.3))
        await drv.connect()
        await drv.start_stream()
        yield drv, emu
        await drv.close()


async def test_scans_go_to_inline_in_the_ports_callback_until_it_raises(
    driver: tuple[UrgDriver, UrgEmulator],
) -> None:
    drv, _ = driver
    seen: list[tuple[int, asyncio.Task[object] | None]] = []

    def inline(scan: Scan) -> None:
        seen.append((scan.seq, asyncio.current_task()))
        if len(seen) == 5:
            raise Enough

    with pytest.raises(Enough):
        await drv.next_scan(timeout_s=1.0, inline=inline)
    # five scans in a row, none dropped, each handled outside any task: in the callback
    seqs = [s for s, _ in seen]
    assert seqs == list(range(seqs[0], seqs[0] + 5))
    assert all(task is None for _, task in seen)
    assert drv.stats.scans_dropped == 0
    assert drv.stats.stalls == 0  # the stall timer moved with every scan


async def test_a_stall_while_serving_inline_is_restarted_and_scans_go_on(
    driver: tuple[UrgDriver, UrgEmulator],
) -> None:
    drv, emu = driver
    after: list[int] = []

    def inline(scan: Scan) -> None:
        if drv.stats.stalls:
            after.append(scan.seq)
            if len(after) == 2:
                raise Enough
        elif scan.seq == 2:
            emu.stall_for(0.6)

    with pytest.raises(Enough):
        await drv.next_scan(timeout_s=3.0, inline=inline)
    assert drv.stats.stalls >= 1
    assert drv.stats.restarts >= 1
    assert len(after) == 2
