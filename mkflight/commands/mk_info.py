"""``mkflight mk info``: the FC's version and DebugOut samples in SI units.

It never takes control; like every link it still closes by sending Config = 0, so an FC
left under extern control by a crashed program is handed back to the pilot.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import sys
from collections.abc import AsyncIterator

from mkflight.clock import MonotonicClock
from mkflight.commands.interrupt import next_or_stop, stop_on_signals
from mkflight.config import Config, load_config
from mkflight.conversions import NS_PER_S
from mkflight.errors import LinkError
from mkflight.io.serial import open_serial
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.units import MkCalibration
from mkflight.msgs import ImuSample

#: The keys of one ``--json`` line (SPEC §7), in order.
JSON_KEYS = (
    "t",
    "pitch_rad",
    "roll_rad",
    "yaw_rad",
    "acc_x_mps2",
    "acc_y_mps2",
    "acc_z_mps2",
    "battery_v",
)
_HEADER = (
    f"{'t_s':>8} {'pitch_rad':>10} {'roll_rad':>10} {'yaw_rad':>10} "
    f"{'acc_x_mps2':>11} {'acc_y_mps2':>11} {'acc_z_mps2':>11} {'battery_v':>9}"
)


def sample_row(sample: ImuSample, t0_ns: int) -> dict[str, float | None]:
    """One sample as the ``--json`` object: ``t`` in seconds since the command started."""
    values = (
        (sample.t_ns - t0_ns) / NS_PER_S,
        sample.pitch_rad,
        sample.roll_rad,
        sample.yaw_rad,
        sample.acc_x_mps2,
        sample.acc_y_mps2,
        sample.acc_z_mps2,
        sample.battery_v,
    )
    return {
        k: (round(v, 6) if math.isfinite(v) else None)
        for k, v in zip(JSON_KEYS, values, strict=True)
    }


def _format_row(row: dict[str, float | None]) -> str:
    def f(key: str, width: int, digits: int) -> str:
        v = row[key]
        return f"{'nan':>{width}}" if v is None else f"{v:>{width}.{digits}f}"

    return " ".join(
        (
            f("t", 8, 3),
            f("pitch_rad", 10, 4),
            f("roll_rad", 10, 4),
            f("yaw_rad", 10, 4),
            f("acc_x_mps2", 11, 3),
            f("acc_y_mps2", 11, 3),
            f("acc_z_mps2", 11, 3),
            f("battery_v", 9, 2),
        )
    )


@contextlib.asynccontextmanager
async def _port(port: str | None, sim: bool, cfg: Config) -> AsyncIterator[str]:
    """Yield the device path: ``port`` itself, or a running emulator's pty."""
    if not sim:
        assert port is not None
        yield port
        return
    from mkflight.sim.airframe import airframe_from_config
    from mkflight.sim.fc_server import FcEmulator
    from mkflight.sim.sources import RestingVehicleSource

    source = RestingVehicleSource(airframe_from_config(cfg.sim), seed=cfg.sim.seed)
    async with FcEmulator(cfg.sim.fc, source) as emulator:
        yield emulator.path


async def _mk_info(port: str | None, sim: bool, count: int, as_json: bool, cfg: Config) -> int:
    stop = stop_on_signals()
    clock = MonotonicClock()
    t0_ns = clock.now_ns()
    async with _port(port, sim, cfg) as path:
        stream = await open_serial(path, cfg.mk.baudrate)
        link = MkLink(
            stream, LinkSettings.from_config(cfg), MkCalibration.from_config(cfg.mk), clock
        )
        async with link:
            version = await link.connect()
            if not as_json:
                errors = "hardware error!" if version.has_hardware_error else "no hardware error"
                print(
                    f"FlightCtrl {version.text} on {path} (protocol "
                    f"{version.proto_major}.{version.proto_minor}, {errors})"
                )
                print(_HEADER)
            link.subscribe()
            printed = 0
            timeout_s = cfg.mk.answer_timeout_s
            while count == 0 or printed < count:
                try:
                    sample = await next_or_stop(link.next_sample(timeout_s), stop)
                except LinkError as err:
                    if link.stats.samples == 0 and link.error is None:
                        msg = (
                            f"the FlightCtrl on {path} answered 'v' but sent no DebugOut "
                            f"within {timeout_s:g} s of the subscription"
                        )
                        raise LinkError(msg) from err
                    raise
                if sample is None:
                    break
                row = sample_row(sample, t0_ns)
                line = json.dumps(row) if as_json else _format_row(row)
                print(line, flush=True)
                printed += 1
    s = link.stats
    if not as_json and (s.parser.crc_errors or s.parser.discarded_bytes):
        print(
            f"link: {s.parser.crc_errors} CRC errors, {s.parser.discarded_bytes} garbage bytes",
            file=sys.stderr,
        )
    return 0


def cmd_mk_info(
    *,
    port: str | None,
    sim: bool,
    count: int,
    as_json: bool,
    config_path: str | None,
    overrides: list[str],
) -> int:
    """Print the FC version and ``count`` DebugOut samples (0: until interrupted)."""
    cfg = load_config(config_path, overrides)
    return asyncio.run(_mk_info(port, sim, count, as_json, cfg))
