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

import json
import math
from typing import TYPE_CHECKING

from mkflight.commands.args import (
    Command,
    Subparsers,
    add_count,
    add_json,
    add_port_or_sim,
    config_options,
    subcommands,
)
from mkflight.conversions import NS_PER_S

if TYPE_CHECKING:
    from mkflight.config import Config
    from mkflight.msgs import Scan
    from mkflight.sim.urg_server import UrgEmulator
    from mkflight.urg.units import SensorParams

URG_BAUDRATE = 115200  # USB CDC-ACM ignores it (scip2.md §1)
#: The simulated room of ``--sim``: 6 x 5 m with a box and a cabinet (x_min y_min x_max y_max).
DEMO_OBSTACLES = ((1.0, 0.8, 1.6, 1.4), (-2.4, -2.2, -1.6, -1.9))


def scan_row(
    scan: Scan, params: SensorParams, cfg: Config, t0_ns: int
) -> tuple[dict[str, object], list[float | None]]:
    """One scan as the ``--json`` object (see the module docstring), and its ranges."""
    import numpy as np

    from mkflight.urg.hat import HatSettings, hat_height
    from mkflight.urg.units import step_body_angle_rad

    laser = cfg.laser
    steps = np.arange(scan.first_step, scan.first_step + scan.ranges_m.size)
    lo, hi = laser.scan_steps
    ranges = scan.ranges_m[(steps >= lo) & (steps <= hi)][::-1]  # increasing body angle
    hat = scan.ranges_m[(steps >= laser.hat_steps[0]) & (steps <= laser.hat_steps[1])]
    height = hat_height(hat, 0.0, 0.0, HatSettings.from_config(laser))
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


def _emulator(cfg: Config) -> UrgEmulator:
    """The URG emulator of ``--sim``: the sensor on the floor of :data:`DEMO_OBSTACLES`' room."""
    import functools

    from mkflight.sim.room import box_room, raycast
    from mkflight.sim.urg_scene import RoomScene, ScenePose
    from mkflight.sim.urg_server import UrgEmulator

    room = box_room(6.0, 5.0, obstacles=DEMO_OBSTACLES)
    scene = RoomScene(
        functools.partial(raycast, room),
        pose=ScenePose(x_m=0.0, y_m=0.0, yaw_rad=0.0, height_m=0.0),
        seed=cfg.sim.seed,
    )
    return UrgEmulator(scene)


async def _laser_scan(port: str | None, sim: bool, count: int, as_json: bool, cfg: Config) -> int:
    import time

    from mkflight.commands.interrupt import stop_on_signals
    from mkflight.commands.streaming import device_path, print_lines
    from mkflight.io.serial import open_serial
    from mkflight.urg.driver import UrgDriver

    stop = stop_on_signals()
    t0_ns = time.monotonic_ns()
    async with device_path(port, (lambda: _emulator(cfg)) if sim else None) as path:
        stream = await open_serial(path, URG_BAUDRATE)
        async with UrgDriver(stream, cfg.laser) as driver:
            info = await driver.connect()
            if not as_json:
                print(f"{info.summary} on {path}")
                print(f"{'t_s':>8} {'valid':>11} {'min_m':>8} {'front_m':>8} {'height_m':>8}")
            await driver.start_stream()

            async def next_line() -> str:
                scan = await driver.next_scan(timeout_s=2.0)
                row, ranges = scan_row(scan, driver.params, cfg, t0_ns)
                return json.dumps(row) if as_json else _summary_line(row, ranges)

            await print_lines(next_line, count, stop)
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
    import asyncio

    from mkflight.config import load_config

    cfg = load_config(config_path, overrides)
    return asyncio.run(_laser_scan(port, sim, count, as_json, cfg))


def add_parser(subparsers: Subparsers) -> None:
    """``laser scan``: the URG group and its one command."""
    laser = subparsers.add_parser("laser", help="the Hokuyo URG laser")
    scan = subcommands(laser, "laser_command").add_parser(
        "scan",
        parents=[config_options()],
        help="print the sensor's identity and scans with the hat's height",
        description="Start the URG (SCIP 2.0), print its identity, then N scans: the scan "
        "steps' ranges and the height from the laser hat (SPEC §7).",
    )
    add_port_or_sim(scan, "laser")
    add_count(scan, default=5, items="scans")
    add_json(scan, "one JSON object per scan and line")
    scan.set_defaults(func=Command(cmd_laser_scan))
