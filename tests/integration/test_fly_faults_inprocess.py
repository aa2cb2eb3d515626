"""Faults that enter inside the daemon: NaN in the estimate, a crash in the step (issue 8).

The daemon (:class:`FlightApp`) and the simulator (:class:`LiveSim`) run in this test's
event loop on real ptys; the fault goes in through the app's ``sample_filter`` seam.
Every ExternControl the daemon wrote is read back from ``mk.raw``.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import os
import signal
import socket
import tempfile
from pathlib import Path

import pytest

from mkflight.config import Config
from mkflight.control.phases import Phase
from mkflight.flight.app import FlightApp, FlightOptions
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.step import ImuStepOutput
from mkflight.logs.events import read_events
from mkflight.logs.raw import read_raw
from mkflight.logs.schema import Crash, Failsafe, Stop, StopDeadline
from mkflight.msgs import ImuSample
from mkflight.sim.live import LiveSim
from tests.integration.recorded import assert_landed_softly, commands_sent
from tests.limits_check import assert_within_limits, flown_config

#: Real-time flights in this process, whose main thread runs below the background
#: flights' priority: they run once those have ended (tests/background.py).
pytestmark = pytest.mark.realtime


class HoldFault:
    """Lets the flight reach HOLD, then after ``after_steps`` steps applies ``fault``."""

    def __init__(self, after_steps: int, fault: str) -> None:
        self.after_steps = after_steps
        self.fault = fault
        self.hold_steps = 0
        self.injected = 0

    def on_step(self, out: ImuStepOutput) -> None:
        if out.phase is Phase.HOLD:
            self.hold_steps += 1

    def filter(self, sample: ImuSample) -> ImuSample:
        if self.hold_steps < self.after_steps:
            return sample
        self.injected += 1
        if self.fault == "crash":
            msg = "injected crash in the step"
            raise RuntimeError(msg)
        if self.fault == "sigterm":
            if self.injected == 1:
                os.kill(os.getpid(), signal.SIGTERM)  # the daemon's handler, not the default
            return sample
        return dataclasses.replace(sample, acc_x_mps2=math.nan, pitch_rad=math.inf)


async def _fly(
    tmp_path: Path, fault: HoldFault, *, stop_deadline_s: float = 9.0
) -> tuple[int, str, Path]:
    cfg = Config()
    folder = tmp_path / "flight"
    folder.mkdir()
    sim = LiveSim(cfg, seed=3, truth_path=str(folder / "truth.txt"), truth_origin_ns=0)
    mk, laser = await sim.start()
    try:
        app = FlightApp(
            cfg,
            FlightOptions(
                mk_port=mk,
                laser_port=laser,
                log_dir=folder,
                duration_s=40.0,
                stop_deadline_s=stop_deadline_s,
            ),
            on_step=fault.on_step,
            sample_filter=fault.filter,
        )
        report = await app.fly()
    finally:
        await sim.stop()
    return report.exit_code, report.reason, folder


async def test_nan_in_the_estimate_lands_with_every_command_in_limits(tmp_path: Path) -> None:
    fault = HoldFault(after_steps=40, fault="nan")
    code, reason, folder = await _fly(tmp_path, fault)
    assert fault.injected > 0
    assert code == 0, reason
    assert reason.startswith("failsafe:")
    events = read_events(folder / "events.jsonl").events
    causes = [e.cause for e in events if isinstance(e, Failsafe)]
    assert "nonfinite" in causes
    cmds = commands_sent(folder)
    assert_within_limits([(c.nick, c.roll, c.yaw, c.gas) for c in cmds], flown_config(folder))
    assert int(cmds[-1].config) == 0
    assert_landed_softly(folder)  # on the hat alone, level: the FC's samples are garbage


async def test_a_crash_in_the_step_releases_and_exits_1(tmp_path: Path) -> None:
    fault = HoldFault(after_steps=20, fault="crash")
    code, reason, folder = await _fly(tmp_path, fault)
    assert code == 1
    assert "injected crash" in reason
    cmds = commands_sent(folder)
    assert int(cmds[-1].config) == 0  # handed back to the pilot at once
    assert sum(1 for c in cmds[-5:] if int(c.config) == 0) >= 3  # several release frames
    events = read_events(folder / "events.jsonl").events
    assert any(isinstance(e, Crash) and e.task == "mk-step" for e in events)
    read_raw(folder / "mk.raw")  # the recording is readable to its end


async def test_a_landing_that_overruns_its_deadline_is_released(tmp_path: Path) -> None:
    """SIGTERM in HOLD with a 0.3 s deadline (a landing takes seconds): the watchdog ends
    the flight, the shutdown hands control back, exit 1 naming the deadline."""
    fault = HoldFault(after_steps=20, fault="sigterm")
    code, reason, folder = await _fly(tmp_path, fault, stop_deadline_s=0.3)
    assert code == 1
    assert "did not end within 0.3 s" in reason
    events = read_events(folder / "events.jsonl").events
    assert any(isinstance(e, Stop) and e.request == "sigterm" for e in events)
    assert any(isinstance(e, StopDeadline) for e in events)
    assert int(commands_sent(folder)[-1].config) == 0


async def test_a_full_disk_mid_flight_lands_softly(tmp_path: Path) -> None:
    """ENOSPC on the tables and events in HOLD: logging stops, the vehicle lands (SPEC §5),
    every command stays in limits, and the exit (1) names the log failure."""
    cfg = Config()
    folder = tmp_path / "flight"
    folder.mkdir()
    sim = LiveSim(cfg, seed=5, truth_path=str(folder / "truth.txt"), truth_origin_ns=0)
    mk, laser = await sim.start()
    hold_steps = 0
    app: FlightApp | None = None

    def full_disk(*_: object, **__: object) -> None:
        raise OSError(28, "No space left on device")

    def on_step(out: ImuStepOutput) -> None:
        nonlocal hold_steps
        hold_steps += out.phase is Phase.HOLD
        if hold_steps == 30 and app is not None and app.ports.logs is not None:
            app.ports.logs.t4.write_row = full_disk  # type: ignore[method-assign]
            app.ports.logs.events.write = full_disk  # type: ignore[method-assign]

    try:
        app = FlightApp(
            cfg,
            FlightOptions(mk_port=mk, laser_port=laser, log_dir=folder, duration_s=40.0),
            on_step=on_step,
        )
        report = await app.fly()
    finally:
        await sim.stop()
    assert report.exit_code == 1, report.reason  # landed, but the logs are incomplete
    assert report.reason.startswith("log write failed")
    assert report.summary.final_phase == "RELEASED"
    assert "No space left" in str(report.summary.log_error)
    cmds = commands_sent(folder)
    assert_within_limits([(c.nick, c.roll, c.yaw, c.gas) for c in cmds], flown_config(folder))
    assert_landed_softly(folder)


async def test_systemd_hears_ready_watchdog_status_and_stopping(tmp_path: Path) -> None:
    """Type=notify: READY only after the pre-flight, WATCHDOG from the steps, STATUS lines
    with the phase, STOPPING at the end (a real unix datagram socket stands in)."""
    cfg = Config()
    folder = tmp_path / "flight"
    folder.mkdir()
    address = str(Path(tempfile.mkdtemp(prefix="n", dir="/tmp")) / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(address)
    sock.setblocking(False)
    datagrams: list[str] = []  # read as they come: a unix datagram queue holds only ~10
    loop = asyncio.get_running_loop()
    loop.add_reader(sock.fileno(), lambda: datagrams.append(sock.recv(4096).decode()))
    sim = LiveSim(cfg, seed=2, truth_path=str(folder / "truth.txt"), truth_origin_ns=0)
    mk, laser = await sim.start()
    try:
        app = FlightApp(
            cfg,
            FlightOptions(mk_port=mk, laser_port=laser, log_dir=folder, duration_s=8.0),
            notifier=Notifier(address, watchdog_usec=1_000_000),
        )
        report = await app.fly()
    finally:
        await sim.stop()
    loop.remove_reader(sock.fileno())
    while True:  # what arrived after the last reader callback
        try:
            datagrams.append(sock.recv(4096).decode())
        except BlockingIOError:
            break
    sock.close()
    assert report.exit_code == 0, report.reason
    assert datagrams[0].startswith("STATUS=") or datagrams[0] == "READY=1"
    ready = datagrams.index("READY=1")
    assert "WATCHDOG=1" not in datagrams[:ready]  # nothing pings before the checks passed
    watchdogs = datagrams.count("WATCHDOG=1")
    assert watchdogs >= 8  # ~4 a second over a 10 s flight
    assert any(d.startswith("STATUS=HOLD") for d in datagrams)
    assert "STOPPING=1" in datagrams[-3:]
    assert app.notifier.failures == 0
