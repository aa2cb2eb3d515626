"""``mkflight mk info`` and ``mk release``: the FC's version and samples; hand it back.

``info`` never takes control; like every link it still closes by sending Config = 0, so
an FC left under extern control by a crashed program is handed back to the pilot.
``release`` sends only that (:mod:`mkflight.mk.release`), for the service's
``ExecStopPost=`` after a daemon that died without releasing.
"""

from __future__ import annotations

import json
import math
import sys
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
    from mkflight.msgs import ImuSample
    from mkflight.sim.fc_server import FcEmulator

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


def _emulator(cfg: Config) -> FcEmulator:
    """The FC emulator of ``--sim``: a vehicle resting on the ground, seeded by ``sim.seed``."""
    from mkflight.sim.airframe import airframe_from_config
    from mkflight.sim.fc_server import FcEmulator
    from mkflight.sim.sources import RestingVehicleSource

    source = RestingVehicleSource(airframe_from_config(cfg.sim), seed=cfg.sim.seed)
    return FcEmulator(cfg.sim.fc, source)


async def _mk_info(port: str | None, sim: bool, count: int, as_json: bool, cfg: Config) -> int:
    from mkflight.clock import MonotonicClock
    from mkflight.commands.interrupt import stop_on_signals
    from mkflight.commands.streaming import device_path, print_lines
    from mkflight.errors import LinkError
    from mkflight.io.serial import open_serial
    from mkflight.mk.link import LinkSettings, MkLink
    from mkflight.mk.units import MkCalibration

    stop = stop_on_signals()
    clock = MonotonicClock()
    t0_ns = clock.now_ns()
    async with device_path(port, (lambda: _emulator(cfg)) if sim else None) as path:
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
            timeout_s = cfg.mk.answer_timeout_s

            async def next_line() -> str:
                try:
                    sample = await link.next_sample(timeout_s)
                except LinkError as err:
                    if link.stats.samples == 0 and link.error is None:
                        msg = (
                            f"the FlightCtrl on {path} answered 'v' but sent no DebugOut "
                            f"within {timeout_s:g} s of the subscription"
                        )
                        raise LinkError(msg) from err
                    raise
                row = sample_row(sample, t0_ns)
                return json.dumps(row) if as_json else _format_row(row)

            await print_lines(next_line, count, stop)
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
    import asyncio

    from mkflight.config import load_config

    cfg = load_config(config_path, overrides)
    return asyncio.run(_mk_info(port, sim, count, as_json, cfg))


#: Longest wait for the port to open (a USB adapter that hangs must not hang the command).
OPEN_TIMEOUT_S = 2.0


async def _mk_release(port: str, cfg: Config) -> int:
    import asyncio

    from mkflight.errors import LinkError
    from mkflight.io.serial import open_serial
    from mkflight.mk.release import release

    mk = cfg.mk
    interval_s = max(mk.release_interval_s, mk.min_frame_gap_s)
    budget_s = OPEN_TIMEOUT_S + mk.release_frames * interval_s + mk.answer_timeout_s
    try:
        async with asyncio.timeout(budget_s):
            stream = await open_serial(port, mk.baudrate)
            try:
                result = await release(
                    stream,
                    count=mk.release_frames,
                    interval_s=interval_s,
                    confirm_timeout_s=mk.answer_timeout_s,
                )
            finally:
                await stream.close()
    except TimeoutError as err:
        msg = f"{port}: the release did not finish within {budget_s:g} s (a hung port?)"
        raise LinkError(msg) from err
    if not result.confirmed:
        msg = (
            f"sent {result.sent} Config = 0 frames on {port}, but the FlightCtrl confirmed "
            f"none within {mk.answer_timeout_s:g} s (is it powered, on this port, at "
            f"{mk.baudrate} baud?)"
        )
        raise LinkError(msg)
    print(
        f"released: the FlightCtrl on {port} confirmed {len(result.confirmed)} of "
        f"{result.sent} Config = 0 frames"
    )
    return 0


def cmd_mk_release(*, port: str | None, config_path: str | None, overrides: list[str]) -> int:
    """Send Config = 0 (neutral, gas 0) frames so the FC leaves extern control at once.

    Raises:
        PortNotFoundError: the port does not exist (exit 2).
        LinkError: it cannot be opened or written, it hung, or no frame was confirmed.
    """
    import asyncio

    from mkflight.config import load_config

    cfg = load_config(config_path, overrides)
    return asyncio.run(_mk_release(port or cfg.mk.port, cfg))


def add_parser(subparsers: Subparsers) -> None:
    """``mk info`` and ``mk release``: the FlightCtrl group."""
    mk = subparsers.add_parser("mk", help="the MikroKopter FlightCtrl link")
    commands = subcommands(mk, "mk_command")
    info = commands.add_parser(
        "info",
        parents=[config_options()],
        help="print the FC version and DebugOut samples in SI units",
        description="Connect to a FlightCtrl, print its version, then N DebugOut samples "
        "converted to SI units (SPEC §1). Takes no control: on exit it sends Config = 0.",
    )
    add_port_or_sim(info, "mk")
    add_count(info, default=10, items="samples")
    add_json(info, "one JSON object per sample and line")
    info.set_defaults(func=Command(cmd_mk_info))
    release = commands.add_parser(
        "release",
        parents=[config_options()],
        help="hand the FC back to the pilot: send Config = 0 (for ExecStopPost=)",
        description="Send mk.release_frames neutral ExternControl frames (sticks 0, gas 0, "
        "Config = 0) mk.release_interval_s apart, and wait up to mk.answer_timeout_s for "
        "the FC's confirms: the FC leaves extern control at once instead of after its "
        "≈ 5 s hold. Asks nothing else of the FC. Exit 0 once a frame is confirmed, 1 if "
        "none is (or the port hangs), 2 if the port does not exist.",
    )
    release.add_argument("--port", metavar="DEV", help="serial device of the FC (default mk.port)")
    release.set_defaults(func=Command(cmd_mk_release))
