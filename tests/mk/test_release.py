"""``mkflight mk release``: the Config = 0 frames on a real pty, and the emulated FC let go.

The expected bytes are built from the protocol's table (mk-serial.md §5.2: Frame at
payload offset 9, Config at 10, every other byte 0) with the codec, and tied to vector
MK-11 (the same frame with Frame 9), not from :class:`ExternControl`.
"""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mkflight.cli import main
from mkflight.config import SimFcConfig
from mkflight.io.pty import PtyDevice
from mkflight.io.serial import open_serial
from mkflight.mk.codec import ADDR_FC, FrameParser, encode_frame
from mkflight.mk.messages import ExternControl
from mkflight.mk.release import release_frames
from mkflight.sim.fc_server import FcEmulator
from mkflight.sim.sources import FixedSource

from .vectors import MK_11

MKFLIGHT = [sys.executable, "-m", "mkflight"]
FRAMES = 5  # mk.release_frames' default
TIMEOUT_SET = "mk.answer_timeout_s=0.3"  # no FC on the pty: do not wait the 2 s default


def protocol_frame(frame_no: int) -> bytes:
    """A neutral 'b' frame, gas 0, Config 0, as §5.2's table lays the 11 bytes out."""
    return encode_frame(ADDR_FC, "b", bytes(9) + bytes((frame_no, 0)))


def test_the_protocol_frame_is_vector_mk11_and_the_release_sends_it() -> None:
    assert protocol_frame(9) == MK_11.data == b"#bb============?M==PF\r"
    assert release_frames(FRAMES) == [protocol_frame(i) for i in range(1, FRAMES + 1)]


async def run_cli(*args: str, timeout_s: float = 20.0) -> tuple[int, str, str]:
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
    return proc.returncode, out.decode(), err.decode()


async def test_the_bytes_on_the_wire_are_the_release_frames_and_nothing_else() -> None:
    """No FC behind the pty: the frames still go out, then exit 1 with one error line."""
    device = PtyDevice("fc")
    expected = b"".join(protocol_frame(i) for i in range(1, FRAMES + 1))
    received = bytearray()
    complete = asyncio.Event()

    async def capture() -> None:
        while True:
            received.extend(await device.read())
            if len(received) >= len(expected):
                complete.set()

    reader = asyncio.create_task(capture())
    try:
        code, out, err = await run_cli("mk", "release", "--port", device.path, "--set", TIMEOUT_SET)
        await asyncio.wait_for(complete.wait(), 2)  # what the process wrote, all read
    finally:
        reader.cancel()
        await device.close()
    assert bytes(received) == expected
    frames = FrameParser().feed(bytes(received))
    decoded = [ExternControl.decode(f) for f in frames]
    assert [(c.config, c.gas, c.nick, c.roll, c.yaw) for c in decoded] == [(0, 0, 0, 0, 0)] * 5
    assert code == 1
    assert out == ""
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert errors == [
        f"error: sent 5 Config = 0 frames on {device.path}, but the FlightCtrl confirmed none "
        "within 0.3 s (is it powered, on this port, at 57600 baud?)"
    ]
    assert err.splitlines()[0] == "config: built-in defaults with 1 --set"


@pytest.fixture
async def fc(tmp_path: Path) -> AsyncIterator[FcEmulator]:
    settings = SimFcConfig(mk3mag_frames=False, external_control=200)
    async with FcEmulator(settings, FixedSource({}), link=tmp_path / "mkflight-fc") as emu:
        yield emu


async def test_an_fc_left_under_extern_control_is_handed_back(fc: FcEmulator) -> None:
    """A daemon took control with gas 90, then died without a release: mk release ends it."""
    daemon = await open_serial(fc.path, 57600)
    daemon.write(ExternControl(gas=90, nick=-20, frame=7, config=1).encode())
    await fc.wait_for(lambda m: m.rx_by_cmd["b"] >= 1)
    await daemon.close()  # killed: no Config = 0 went out
    assert fc.model.extern_active
    assert fc.model.effective_command().gas == 90

    code, out, err = await run_cli("mk", "release", "--port", fc.path)
    assert code == 0, err
    assert out == f"released: the FlightCtrl on {fc.path} confirmed 5 of 5 Config = 0 frames\n"
    assert not fc.model.extern_active  # at once, not after the ≈ 5.2 s hold
    assert fc.model.rx_by_cmd["b"] == 1 + FRAMES
    last = fc.model.last_extern
    assert last is not None
    assert (last.config, last.gas, last.nick, last.frame) == (0, 0, 0, FRAMES)


async def test_a_hung_port_times_out_with_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An adapter whose open never returns: exit 1 after the budget, not a hang."""
    import mkflight.commands.mk_info as mk_info
    import mkflight.io.serial as serial

    async def never(path: str, baudrate: int) -> None:
        await asyncio.Event().wait()

    monkeypatch.setattr(serial, "open_serial", never)
    monkeypatch.setattr(mk_info, "OPEN_TIMEOUT_S", 0.2)
    loop = asyncio.get_running_loop()
    start = loop.time()
    code = await asyncio.to_thread(
        main, ["mk", "release", "--port", "/dev/null", "--set", "mk.answer_timeout_s=0.1"]
    )
    assert code == 1
    assert loop.time() - start < 5
    err = capsys.readouterr().err
    assert "error: /dev/null: the release did not finish within" in err
    assert len([ln for ln in err.splitlines() if ln.startswith("error:")]) == 1


async def test_a_missing_port_is_a_usage_error() -> None:
    code, out, err = await run_cli("mk", "release", "--port", "/dev/ttyNOPE7")
    assert code == 2
    assert out == ""
    assert err.splitlines()[-1] == "error: serial port '/dev/ttyNOPE7' does not exist"
