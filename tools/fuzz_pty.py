"""Fuzzing through the real MkLink and UrgDriver, on serialx over a PtyDevice.

Units of pieces (``fuzz_mk.py``, ``fuzz_urg.py``) around one valid DebugOut / current-stream
scan, written in chunks (each awaited until the client has read it); the consumer must get
every one of them, unchanged. The MK consumer answers each sample with a fuzzed ExternControl
(NaN, inf, 127.5, gas -1, nick 128 ...); what the link writes is parsed on the FC's end
(:class:`CommandSink`) and checked against the limits. On the URG's end,
:class:`ScriptedUrg` answers the driver's start-up commands as a URG-04LX.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import random
import time
from collections import Counter
from typing import Final

import numpy as np
from fuzz_mk import mk_message, random_debug, random_mk_piece, random_mk_valid
from fuzz_pieces import Advance, PassResult, Piece, Totals, check, join, random_chunks
from fuzz_urg import (
    INFO_LINES,
    LF,
    maybe_after_garbage,
    random_bad_scan,
    random_urg_extras,
    random_values,
    scip_info,
    scip_scan,
    scip_status,
)

from mkflight.config import Config, LaserConfig
from mkflight.conversions import MM_PER_M
from mkflight.errors import CommandRangeError, LinkError
from mkflight.io.pty import PtyDevice
from mkflight.io.serial import open_serial
from mkflight.mk.codec import Frame, FrameParser
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import FORBIDDEN_COMMANDS, Confirm, ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug
from mkflight.urg.driver import UrgDriver


# ================================================================= the device end of a pty
class Wire:
    """The device end of a pty: counts what it writes and what the client has read."""

    def __init__(self, device: PtyDevice) -> None:
        self.device = device
        self.written = 0
        self.read = 0
        self._event = asyncio.Event()

    def tap(self, direction: str, t_ns: int, data: bytes) -> None:
        """The client's tap: it has read ``data``."""
        if direction == "r":
            self.read += len(data)
            self._event.set()

    def write(self, data: bytes) -> None:
        self.device.write(data)
        self.written += len(data)

    async def delivered(self, timeout_s: float = 5.0) -> None:
        """Wait until the client has read everything written (and not dropped)."""
        async with asyncio.timeout(timeout_s):
            while self.read < self.written - self.device.dropped_bytes:
                self._event.clear()
                await self._event.wait()

    async def send(self, rng: random.Random, data: bytes) -> None:
        """Write ``data`` in random chunks, each read by the client before the next."""
        for chunk in random_chunks(rng, data, most=2048):
            self.write(chunk)
            await self.delivered()


# ================================================================= the MK link
_WIRE_RANGES: Final = {
    "nick": (-128, 127), "roll": (-128, 127), "yaw": (-128, 127), "height": (-128, 127),
    "gas": (0, 255), "frame": (0, 255), "config": (0, 255), "free": (0, 255),
    "remote_buttons": (0, 255),
}  # fmt: skip


def within_limits(cmd: ExternControl, settings: LinkSettings) -> bool:
    """Whether the link may send ``cmd``: whole, finite, in its wire range (``mk-serial.md``
    §5.2), nick/roll/yaw within the stick limit and gas within [0, gas_max] (SPEC §4)."""
    for name, (lo, hi) in _WIRE_RANGES.items():
        v = getattr(cmd, name)
        if isinstance(v, float) and not (math.isfinite(v) and v.is_integer()):
            return False
        if not lo <= v <= hi:
            return False
    sticks = (cmd.nick, cmd.roll, cmd.yaw)
    return max(map(abs, sticks)) <= settings.stick_max_counts and cmd.gas <= settings.gas_max


def random_command(rng: random.Random) -> ExternControl:
    """An ExternControl a buggy controller might compute: mostly fine, some not."""
    odd: tuple[float, ...] = (128, -128, 200, -300, 12.0, -12.5, math.nan, math.inf, -math.inf)

    def stick() -> int | float:
        return rng.randint(-127, 127) if rng.random() < 0.8 else rng.choice(odd)

    gas = (
        rng.randint(0, 130)
        if rng.random() < 0.8
        else rng.choice((131, 255, -1, 100.0, 99.5, math.nan))
    )
    return ExternControl(
        nick=stick(),
        roll=stick(),
        yaw=stick(),
        gas=gas,
        height=rng.randint(-128, 127) if rng.random() < 0.95 else math.nan,
        config=rng.choice((0, 1, 1, 1, 3, 256)),
        frame=rng.randrange(256),
    )


def link_category(frame: Frame) -> str:
    """The link counter a valid frame must move (``MkLink._dispatch``, mk-serial.md §2.1)."""
    if frame.addr != 1:
        return "foreign_frames"
    need = {"D": 66, "B": 1, "V": 10, "P": 52, "A": 17}.get(frame.cmd)
    if need is None:
        return "unknown_frames"
    if len(frame.payload) < need:
        return "bad_messages"
    return {"D": "samples", "V": "versions"}.get(frame.cmd, f"answers {frame.cmd}")


class CommandSink:
    """The FC's end of the link: parses every byte the link writes, checks every command."""

    def __init__(self, device: PtyDevice, settings: LinkSettings) -> None:
        self._device = device
        self._settings = settings
        self.parser = FrameParser()
        self.frames: Counter[str] = Counter()
        self.violations: list[str] = []
        self._event = asyncio.Event()

    async def run(self) -> None:
        with contextlib.suppress(LinkError):
            while True:
                for frame in self.parser.feed(await self._device.read()):
                    self._check(frame)
                self._event.set()

    def _check(self, frame: Frame) -> None:
        self.frames[frame.cmd] += 1
        bad = frame.addr != 1 or frame.cmd in FORBIDDEN_COMMANDS or frame.cmd not in "vdbpa"
        if frame.cmd == "b":
            ec = ExternControl.decode(frame)
            bad = bad or not (within_limits(ec, self._settings) and ec.config in (0, 1, 3))
        if bad:
            self.violations.append(f"the link wrote {frame}")

    async def received(self, n: int, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while self.parser.stats.bytes_in < n:
                self._event.clear()
                await self._event.wait()


def link_valid(rng: random.Random) -> Piece[Frame]:
    """A valid frame for the link's stream that is neither a sample (one DebugOut a unit,
    so that each can be checked) nor a confirm it could be waiting for."""
    piece = random_mk_valid(rng)
    frame = piece.valid[0]
    if link_category(frame) == "samples":
        return mk_message(random_debug(rng, addr=0))
    if link_category(frame) == "answers B":
        return mk_message(Confirm(0))  # Frame numbers 1..255 only: never awaited
    return piece


async def run_mk_link(n: int, rng: random.Random, advance: Advance = lambda k: None) -> PassResult:
    """``n`` frame pieces through a real MkLink on a pty, a valid DebugOut in every unit."""
    result = PassResult("MK link (pty)")
    started = time.perf_counter()
    settings = LinkSettings.from_config(Config())
    device = PtyDevice("fuzz-fc")
    wire = Wire(device)
    sink = CommandSink(device, settings)
    sink_task = asyncio.create_task(sink.run())
    serial = await open_serial(device.path, settings.baudrate)
    link = MkLink(serial, settings, DEFAULT_CALIBRATION, tap=wire.tap)
    link.start()
    totals, want, sent = Totals(), Counter[str](), Counter[str]()
    samples = out_of_limit = 0
    try:
        while result.tried < n:
            debug = random_debug(rng)
            pieces, tried = [mk_message(debug)], 1
            for _ in range(rng.randrange(4)):
                if tried < n - result.tried:
                    budget = n - result.tried - tried
                    piece, k = random_mk_piece(rng, lambda: link_valid(rng), budget)
                    pieces.append(piece)
                    tried += k
            rng.shuffle(pieces)
            unit = join(pieces)
            totals.add(unit)
            want.update(link_category(f) for f in unit.valid)
            await wire.send(rng, unit.data)
            sample = await link.next_sample(timeout_s=2.0)
            samples += sample == imu_from_debug(debug, sample.t_ns, DEFAULT_CALIBRATION)
            command = random_command(rng)
            ok = within_limits(command, settings)
            try:
                link.send_extern_control(command)
                sent["commands accepted"] += 1
                out_of_limit += not ok
                if rng.random() < 0.2:  # let it reach the wire (else a newer one replaces it)
                    await link.drain()
            except CommandRangeError:
                sent["commands refused"] += 1
                if ok:
                    result.mismatch("MK link", [f"refused {command}"])
            result.tried += tried
            advance(tried)
        await link.close()
        await sink.received(link.stats.bytes_written)
    except Exception as err:  # out of the link, or a timeout: the figure this pass is for
        result.exception(err, b"")
    finally:
        await link.close(release=False)
        sink_task.cancel()
        await device.close()
    s = link.stats
    # The link keeps no frames, only counters: its parser's are checked against the pieces',
    # the frames by kind against the link's own counters.
    result.mismatch("MK link", check(s.parser, totals, totals.valid_bytes))
    kinds = ("samples", "foreign_frames", "unknown_frames", "bad_messages", "versions")
    got = {k: getattr(s, k) for k in kinds}
    got["answers"] = s.parser.frames - sum(got.values())  # confirms, PPM, labels
    want["answers"] = totals.valid - sum(want[k] for k in kinds)
    result.mismatch(
        "MK link", [f"{k} = {v}, want {want[k]}" for k, v in got.items() if v != want[k]]
    )
    result.mismatch(
        "MK link",
        [
            f"{k} = {getattr(s, k)}, want 0"
            for k in ("samples_dropped", "confirms")
            if getattr(s, k)
        ],
    )
    written = sink.parser.stats
    if written.discarded_bytes or written.bytes_in != s.bytes_written:
        what = f"wrote {s.bytes_written} bytes, the FC read {written.bytes_in}"
        what += f", {written.discarded_bytes} outside frames"
        result.mismatch("MK link", [what])
    result.out_of_limit = out_of_limit + len(sink.violations)
    result.problems.extend(sink.violations[:5])
    result.valid = totals.valid
    result.found = samples + sum(min(v, want[k]) for k, v in got.items() if k != "samples")
    result.missed = result.valid - result.found
    result.notes = {**sent, **{f"written {k!r}": v for k, v in sorted(sink.frames.items())}}
    result.notes.update({k: v for k, v in dataclasses.asdict(s.parser).items() if v})
    result.seconds = time.perf_counter() - started
    return result


# ================================================================= the URG driver
class ScriptedUrg:
    """The sensor's end of the driver: answers its commands as a URG-04LX in SCIP 2.0."""

    def __init__(self, wire: Wire, totals: Totals) -> None:
        self._wire = wire
        self._totals = totals
        self.answers = 0
        self.md: str | None = None

    async def run(self) -> None:
        pending = b""
        with contextlib.suppress(LinkError):
            while True:
                pending += await self._wire.device.read()
                *lines, pending = pending.split(LF)
                for line in lines:
                    self._answer(line.decode("ascii", "replace"))

    def _answer(self, command: str) -> None:
        name = command[:2]
        if command == "SCIP2.0":
            reply = scip_status(command, "0E")
        elif name in INFO_LINES:
            reply = scip_info(name, [(f"{k}:{v}", 0) for k, v in INFO_LINES[name]])
        elif name in ("QT", "RS", "BM", "TM", "MD"):
            reply = scip_status(command, "00")
            self.md = command if name == "MD" else self.md
        else:
            reply = scip_status(command, "0E")
        piece = reply.piece()
        self._totals.add(piece)
        self._wire.write(piece.data)
        self.answers += 1


async def run_urg_driver(
    n: int, rng: random.Random, advance: Advance = lambda k: None
) -> PassResult:
    """``n`` scan pieces through a real UrgDriver on a pty, a valid scan of its stream in every
    unit; the others have a bad sum, are cut short, or belong to a stream it replaced."""
    result = PassResult("URG driver (pty)")
    started = time.perf_counter()
    np_rng = np.random.default_rng(rng.getrandbits(64))
    device = PtyDevice("fuzz-urg")
    wire, totals = Wire(device), Totals()
    sensor = ScriptedUrg(wire, totals)
    sensor_task = asyncio.create_task(sensor.run())
    driver = UrgDriver(await open_serial(device.path, 115200), LaserConfig(), tap=wire.tap)
    units = scans = stale = 0
    stamp = rng.randrange(1 << 24)
    try:
        await driver.connect()
        await driver.start_stream()
        assert sensor.md is not None
        tag = sensor.md.partition(";")[2]
        while result.tried < n:
            stamp = (stamp + 100) % (1 << 24)
            values = random_values(np_rng, 682, 3)
            current = scip_scan("MD", (44, 725, 1), values, stamp, tag=tag)
            pieces, tried = [maybe_after_garbage(rng, current.piece())], 1
            for _ in range(rng.randrange(4)):
                if tried < n - result.tried:
                    bad = random_bad_scan(rng, current) if rng.random() < 0.8 else None
                    if bad is None:  # a scan of the stream before
                        bad = scip_scan("MD", (44, 725, 1), values, stamp, tag=tag + "0").piece()
                        stale += 1
                    pieces.append(maybe_after_garbage(rng, bad))
                    tried += 1
                pieces.append(random_urg_extras(rng))
            rng.shuffle(pieces)
            unit = join(pieces)
            totals.add(unit)
            await wire.send(rng, unit.data)
            units += 1
            scan = await driver.next_scan(timeout_s=2.0)
            ranges = np.where((values >= 20) & (values <= 5600), values / MM_PER_M, np.nan)
            scans += scan.first_step == 44 and np.array_equal(scan.ranges_m, ranges, equal_nan=True)
            result.tried += tried
            advance(tried)
        await driver.close()
    except Exception as err:  # out of the driver, or a timeout: the figure this pass is for
        result.exception(err, b"")
    finally:
        await driver.close()
        sensor_task.cancel()
        await device.close()
    s = driver.stats
    # The driver keeps no replies, only counters: its parser's are checked against the
    # pieces' (its answers to the start-up commands included), the scans by its own.
    result.mismatch("URG driver", check(s.parser, totals, totals.valid_bytes))
    want = {"scans": units, "stale_stream_scans": stale, "scans_dropped": 0, "restarts": 0}
    want.update(stalls=0, stream_errors=0)
    result.mismatch(
        "URG driver",
        [f"{k} = {getattr(s, k)}, want {v}" for k, v in want.items() if getattr(s, k) != v],
    )
    others = totals.valid - sensor.answers - units - stale
    got_others = s.parser.replies - sensor.answers - s.scans - s.stale_stream_scans
    result.valid = totals.valid - sensor.answers
    result.found = scans + min(s.stale_stream_scans, stale) + min(got_others, others)
    result.missed = result.valid - result.found
    result.notes = {k: v for k, v in dataclasses.asdict(s.parser).items() if v}
    result.notes.update(scans=s.scans, stale_stream_scans=s.stale_stream_scans)
    result.notes["start-up replies"] = sensor.answers
    result.seconds = time.perf_counter() - started
    return result
