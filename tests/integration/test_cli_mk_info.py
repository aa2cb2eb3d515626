"""``mkflight mk info`` end to end: the real CLI process against emulators on ptys."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import statistics
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mkflight.config import SimFcConfig
from mkflight.errors import LinkError
from mkflight.io.pty import PtyDevice
from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import DebugOut, ExternControl, VersionInfo
from mkflight.sim.fc_server import FcEmulator
from mkflight.sim.sources import FixedSource

MKFLIGHT = [sys.executable, "-m", "mkflight"]
ANALOG = {0: -12, 1: 31, 2: -13, 3: 33, 4: -3, 5: 14, 6: -2, 9: 118, 11: 271, 21: 120}
JSON_KEYS = {
    "t",
    "pitch_rad",
    "roll_rad",
    "yaw_rad",
    "acc_x_mps2",
    "acc_y_mps2",
    "acc_z_mps2",
    "battery_v",
}


async def run_cli(*args: str, timeout_s: float = 20.0) -> tuple[int, str, str, float]:
    """Run ``python -m mkflight ARGS``; return (exit code, stdout, stderr, wall seconds)."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    proc = await asyncio.create_subprocess_exec(
        *MKFLIGHT,
        *args,
        stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    out, err = await asyncio.wait_for(proc.communicate(), timeout_s)
    assert proc.returncode is not None
    return proc.returncode, out.decode(), err.decode(), loop.time() - start


async def start_streaming(path: str, count: int) -> asyncio.subprocess.Process:
    """Start ``mk info --port PATH --count N --json`` and return once its first line is out."""
    proc = await asyncio.create_subprocess_exec(
        *MKFLIGHT,
        "mk",
        "info",
        "--port",
        path,
        "--count",
        str(count),
        "--json",
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert proc.stdout is not None
    await asyncio.wait_for(proc.stdout.readline(), 10)
    return proc


def error_lines(stderr: str) -> list[str]:
    """The ``error:`` lines (events are JSON lines on a non-terminal stderr)."""
    return [line for line in stderr.splitlines() if line.startswith("error:")]


@pytest.fixture
async def emulator() -> AsyncIterator[FcEmulator]:
    settings = SimFcConfig(mk3mag_frames=True)
    async with FcEmulator(settings, FixedSource(ANALOG)) as emu:
        yield emu


async def test_json_samples_equal_the_emulator_values_at_the_subscribed_rate(
    emulator: FcEmulator,
) -> None:
    code, out, err, _ = await run_cli(
        "mk", "info", "--port", emulator.path, "--count", "20", "--json"
    )
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert len(rows) == 20
    # mk-serial.md §6.2, the worked example of these raw values through SPEC §1's table.
    expected = {
        "pitch_rad": 0.020944,
        "roll_rad": -0.054105,
        "yaw_rad": -1.553343,  # Gyro Compass 271° = -89°
        "acc_x_mps2": 0.210341,
        "acc_y_mps2": 0.536474,
        "acc_z_mps2": -9.670968,
        "battery_v": 11.8,
    }
    for row in rows:
        assert set(row) == JSON_KEYS
        for key, value in expected.items():
            assert row[key] == pytest.approx(value, abs=1e-6), key
    gaps_s = [b["t"] - a["t"] for a, b in itertools.pairwise(rows)]
    assert 0.045 <= statistics.median(gaps_s) <= 0.065  # 'd' 5 = 50 FC ticks ≈ 53 ms
    assert all(gap > 0 for gap in gaps_s)
    # It never took control, and it handed control back on exit.
    commands = emulator.model.last_extern
    assert commands is not None
    assert (commands.config, commands.gas, commands.nick) == (0, 0, 0)
    assert not emulator.model.extern_active


async def test_sim_prints_version_header_and_samples() -> None:
    code, out, err, _ = await run_cli("mk", "info", "--sim", "--count", "5")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("FlightCtrl 0.84a on /dev/pts/")
    assert "no hardware error" in lines[0]
    assert lines[1].split() == [
        "t_s",
        "pitch_rad",
        "roll_rad",
        "yaw_rad",
        "acc_x_mps2",
        "acc_y_mps2",
        "acc_z_mps2",
        "battery_v",
    ]
    samples = [[float(x) for x in line.split()] for line in lines[2:]]
    assert len(samples) == 5
    for s in samples:
        assert s[6] == pytest.approx(-9.81, abs=0.3)  # at rest: f_z = -g
        assert s[7] == pytest.approx(12.4, abs=0.05)


async def test_survives_garbage_and_crc_errors_mid_stream(emulator: FcEmulator) -> None:
    proc = await start_streaming(emulator.path, 30)
    emulator.inject_garbage(b"\x00\xff#\r garbage \r\n" * 5)
    emulator.corrupt_next(3)
    out, err = await asyncio.wait_for(proc.communicate(), 20)
    assert proc.returncode == 0, err.decode()
    assert len(out.decode().splitlines()) == 29
    assert emulator.model.tx_corrupted == 3


async def test_missing_port_exits_2_naming_it() -> None:
    code, out, err, _ = await run_cli("mk", "info", "--port", "/dev/ttyNOPE9")
    assert code == 2
    assert out == ""
    assert error_lines(err) == ["error: serial port '/dev/ttyNOPE9' does not exist"]
    assert "Traceback" not in err


class Responder:
    """A pty device that answers every chunk it receives with fixed bytes (or nothing)."""

    def __init__(self, reply: bytes) -> None:
        self.reply = reply
        self.device = PtyDevice("fake")
        self.received = bytearray()
        self._task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        with contextlib.suppress(LinkError):
            while True:
                self.received += await self.device.read()
                if self.reply:
                    self.device.write(self.reply)

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        await self.device.close()


@pytest.mark.parametrize(
    "reply",
    [b"", b"\x00\xffAT+OK\r\n#garbage\r#bV=BMH============PI\r"],
    ids=["silent", "garbage"],
)
async def test_no_flightctrl_exits_1_within_3_s(reply: bytes) -> None:
    responder = Responder(reply)
    try:
        code, out, err, wall_s = await run_cli("mk", "info", "--port", responder.device.path)
    finally:
        await responder.close()
    assert code == 1
    assert out == ""
    lines = error_lines(err)
    assert len(lines) == 1
    assert lines[0].startswith(f"error: no FlightCtrl answered on {responder.device.path}")
    assert wall_s < 3.0
    assert "Traceback" not in err
    # It asked (several times) and, to be safe, sent Config = 0 frames too.
    frames = FrameParser().feed(bytes(responder.received))
    assert sum(f.cmd == "v" for f in frames) >= 4
    releases = [ExternControl.decode(f) for f in frames if f.cmd == "b"]
    assert releases
    assert all(r.config == 0 and r.gas == 0 for r in releases)


async def test_version_but_no_debugout_is_a_clear_runtime_error() -> None:
    responder = Responder(VersionInfo(0, 84, 11, 0, 0).encode())
    try:
        code, _, err, _ = await run_cli("mk", "info", "--port", responder.device.path)
    finally:
        await responder.close()
    assert code == 1
    assert error_lines(err) == [
        f"error: the FlightCtrl on {responder.device.path} answered 'v' but sent no "
        "DebugOut within 2 s of the subscription"
    ]


async def test_vanishing_port_is_reported(emulator: FcEmulator) -> None:
    proc = await start_streaming(emulator.path, 0)
    emulator.vanish()
    _, err = await asyncio.wait_for(proc.communicate(), 10)
    assert proc.returncode == 1
    (line,) = error_lines(err.decode())
    assert emulator.path in line
    assert "vanished" in line


async def test_sigint_stops_a_continuous_run_cleanly(emulator: FcEmulator) -> None:
    proc = await start_streaming(emulator.path, 0)
    proc.send_signal(2)
    _, err = await asyncio.wait_for(proc.communicate(), 10)
    assert proc.returncode == 0, err.decode()
    assert emulator.model.last_extern is not None
    assert emulator.model.last_extern.config == 0  # released on the way out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "control.nope=1"], "control.nope: unknown key"),
        (["--set", "mk.baudrate=fast"], "mk.baudrate: Expected `int`"),
        (["--set", "control.gas_max=300"], "control.gas_max: Expected `int` <= 255"),
        (["--config", "/nonexistent/cfg.yaml"], "/nonexistent/cfg.yaml: cannot read"),
    ],
)
async def test_bad_config_exits_2_naming_the_key(args: list[str], needle: str) -> None:
    code, out, err, _ = await run_cli("mk", "info", "--sim", "--count", "1", *args)
    assert code == 2
    assert out == ""
    (line,) = error_lines(err)
    assert needle in line
    assert "Traceback" not in err


async def test_config_file_is_used(tmp_path: Path, emulator: FcEmulator) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mk:\n  debug_interval_10ms: 10\n")
    code, out, err, _ = await run_cli(
        "mk", "info", "--port", emulator.path, "--count", "6", "--json", "--config", str(cfg)
    )
    assert code == 0, err
    times = [json.loads(line)["t"] for line in out.splitlines()]
    assert 0.09 <= statistics.median(b - a for a, b in itertools.pairwise(times)) <= 0.12


@pytest.mark.parametrize(
    "args",
    [["mk", "info"], ["mk", "info", "--port", "x", "--sim"], ["mk", "info", "--count", "-1"], []],
)
async def test_usage_errors_exit_2_with_one_line(args: list[str]) -> None:
    code, out, err, _ = await run_cli(*args)
    assert code == 2
    assert out == ""
    assert len(err.strip().splitlines()) == 1
    assert err.startswith("error: ")


async def test_version_flag() -> None:
    code, out, _, _ = await run_cli("--version")
    assert code == 0
    assert out.startswith("mkflight ")


def test_debugout_fixture_matches_the_emulator_source() -> None:
    """The values above are MK-08's (mk-serial.md §6.2), less Gas which the FC computes."""
    assert DebugOut.from_values(ANALOG).analog[9] == 118
