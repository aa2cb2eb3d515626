"""``mkflight laser scan``: the URG's identity, then N scans with the hat's height.

``--json`` lines carry ``t`` (seconds since the command started, when the scan's front
step was measured), ``angle_min_rad``, ``angle_increment_rad``, ``ranges_m`` and
``height_m`` (SPEC §7). The ranges are the scan steps (``laser.scan_steps``) in order of
increasing body angle: beam i points at ``angle_min_rad + i * angle_increment_rad``,
positive to the right like yaw; invalid ranges are ``null``. The height comes from the
hat steps by eq 26 assuming a level vehicle (no attitude here), ``null`` when the hat
gives none.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import math
import time
from collections.abc import AsyncIterator

import numpy as np

from mkflight.commands.interrupt import next_or_stop, stop_on_signals
from mkflight.config import Config, load_config
from mkflight.conversions import NS_PER_S
from mkflight.io.serial import open_serial
from mkflight.msgs import Scan
from mkflight.urg.driver import UrgDriver
from mkflight.urg.hat import HatSettings, hat_height
from mkflight.urg.units import SensorParams, step_body_angle_rad

URG_BAUDRATE = 115200  # USB CDC-ACM ignores it (scip2.md §1)
#: The simulated room of ``--sim``: 6 x 5 m with a box and a cabinet (x_min y_min x_max y_max).
DEMO_OBSTACLES = ((1.0, 0.8, 1.6, 1.4), (-2.4, -2.2, -1.6, -1.9))


def scan_row(
    scan: Scan, params: SensorParams, cfg: Config, t0_ns: int
) -> tuple[dict[str, object], list[float | None]]:
    """One scan as the ``--json`` object (see the module docstring), and its ranges."""
    laser = cfg.laser
    steps = np.arange(scan.first_step, scan.first_step + scan.ranges_m.size)
    lo, hi = laser.scan_steps
    ranges = scan.ranges_m[(steps >= lo) & (steps <= hi)][::-1]  # increasing body angle
    hat = scan.ranges_m[(steps >= laser.hat_steps[0]) & (steps <= laser.hat_steps[1])]
    height = hat_height(hat, 0.0, 0.0, HatSettings(offset_m=laser.hat_offset_m))
    values: list[float | None] = [None if math.isnan(r) else round(float(r), 3) for r in ranges]
    row: dict[str, object] = {
        "t": round((scan.t_ns - t0_ns) / NS_PER_S, 6),
        "angle_min_rad": round(step_body_angle_rad(hi, params), 9),
        "angle_increment_rad": round(params.step_angle_rad, 12),
        "ranges_m": values,
        "height_m": round(height.height_m, 4) if height.valid else None,
    }
    return row, values


def _summary_line(row: dict[str, object], ranges: list[float | None]) -> str:
    valid = [r for r in ranges if r is not None]
    angle_min, step = row["angle_min_rad"], row["angle_increment_rad"]
    assert isinstance(angle_min, float)
    assert isinstance(step, float)
    i_front = round(-angle_min / step)  # the beam straight ahead (step AFRT)
    front = ranges[i_front] if 0 <= i_front < len(ranges) else None
    height = row["height_m"]

    def m(v: object) -> str:
        return f"{v:8.3f}" if isinstance(v, float) else f"{'-':>8}"

    return (
        f"{row['t']:8.3f} {len(valid):5d}/{len(ranges):<5d} "
        f"{m(min(valid) if valid else None)} {m(front)} {m(height)}"
    )


@contextlib.asynccontextmanager
async def _port(port: str | None, sim: bool, cfg: Config) -> AsyncIterator[str]:
    """Yield the device path: ``port`` itself, or a running URG emulator's pty."""
    if not sim:
        assert port is not None
        yield port
        return
    from mkflight.sim.room import box_room, raycast
    from mkflight.sim.urg_scene import RoomScene, ScenePose
    from mkflight.sim.urg_server import UrgEmulator

    room = box_room(6.0, 5.0, obstacles=DEMO_OBSTACLES)
    scene = RoomScene(
        functools.partial(raycast, room),
        pose=ScenePose(x_m=0.0, y_m=0.0, yaw_rad=0.0, height_m=0.0),
        seed=cfg.sim.seed,
    )
    async with UrgEmulator(scene) as emulator:
        yield emulator.path


async def _laser_scan(port: str | None, sim: bool, count: int, as_json: bool, cfg: Config) -> int:
    stop = stop_on_signals()
    t0_ns = time.monotonic_ns()
    async with _port(port, sim, cfg) as path:
        stream = await open_serial(path, URG_BAUDRATE)
        async with UrgDriver(stream, cfg.laser) as driver:
            info = await driver.connect()
            if not as_json:
                print(f"{info.summary} on {path}")
                print(f"{'t_s':>8} {'valid':>11} {'min_m':>8} {'front_m':>8} {'height_m':>8}")
            await driver.start_stream()
            printed = 0
            while count == 0 or printed < count:
                scan = await next_or_stop(driver.next_scan(timeout_s=2.0), stop)
                if scan is None:
                    break
                row, ranges = scan_row(scan, driver.params, cfg, t0_ns)
                print(json.dumps(row) if as_json else _summary_line(row, ranges), flush=True)
                printed += 1
    return 0


def cmd_laser_scan(
    *,
    port: str | None,
    sim: bool,
    count: int,
    as_json: bool,
    config_path: str | None,
    overrides: list[str],
) -> int:
    """Print the sensor's identity and ``count`` scans (0: until interrupted)."""
    cfg = load_config(config_path, overrides)
    return asyncio.run(_laser_scan(port, sim, count, as_json, cfg))
