"""LiveSim over real pseudo-terminals, read by the project's own clients; the ``sim`` command."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import numpy as np
import pytest
import structlog
import structlog.testing

from mkflight.config import Config, SimConfig, SimVehicleConfig
from mkflight.errors import ConfigError, LinkError
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import ExternControl
from mkflight.mk.units import MkCalibration
from mkflight.msgs import Scan
from mkflight.sim.live import FAULT_KINDS, Fault, LiveSim, parse_fault, parse_faults
from mkflight.urg.driver import UrgDriver
from mkflight.urg.hat import HatSettings, hat_height

CFG = Config(sim=SimConfig(vehicle=SimVehicleConfig(gusts=False)))
FRONT_STEP, LEFT_STEP = 384, 640  # straight ahead; 90 degrees to the left


async def open_mk(path: str, cfg: Config = CFG) -> MkLink:
    async def opener() -> ByteStream:
        return await open_serial(path, cfg.mk.baudrate)

    link = MkLink(
        await opener(),
        LinkSettings.from_config(cfg),
        MkCalibration.from_config(cfg.mk),
        reopen=opener,
    )
    await link.connect()
    link.subscribe()
    return link


async def open_urg(path: str, cfg: Config = CFG) -> UrgDriver:
    async def opener() -> ByteStream:
        return await open_serial(path, 115200)

    driver = UrgDriver(await opener(), cfg.laser, reopen=opener)
    await driver.connect()
    await driver.start_stream()
    return driver


def hat(scan: Scan, cfg: Config = CFG) -> float:
    lo, hi = cfg.laser.hat_steps
    i0 = lo - scan.first_step
    h = hat_height(
        scan.ranges_m[i0 : i0 + hi - lo + 1], 0.0, 0.0, HatSettings.from_config(Config().laser)
    )
    assert h.valid
    return h.height_m


def step_range(scan: Scan, step: int) -> float:
    """The median of the steps within 1 degree (a beam may read an error code: NaN)."""
    i = step - scan.first_step
    return float(np.nanmedian(scan.ranges_m[i - 3 : i + 4]))


def is_link(path: str) -> bool:
    return os.path.islink(path)


@pytest.fixture
async def sim(tmp_path: Path) -> AsyncIterator[LiveSim]:
    async with LiveSim(CFG, seed=7, truth_path=tmp_path / "truth.txt") as live:
        yield live


async def test_debug_out_and_scans_of_the_vehicle_on_the_floor(sim: LiveSim) -> None:
    link = await open_mk(sim.fc.path)
    driver = await open_urg(sim.urg.path)
    try:
        samples = [await link.next_sample(timeout_s=1.0) for _ in range(5)]
        for s in samples:
            assert s.acc_z_mps2 == pytest.approx(-9.81, abs=0.4)
            assert abs(s.pitch_rad) < 0.03
            assert abs(s.roll_rad) < 0.03
            assert s.gas_counts == 0  # the simulated pilot's stick is down
            assert 11.5 < s.battery_v < 13.0
        scans = [await driver.next_scan(timeout_s=1.0) for _ in range(3)]
        for scan in scans:
            assert hat(scan) == pytest.approx(0.0, abs=0.02)
            # default_room: the front wall 2.4 m ahead, the left wall 1.8 m to the left
            assert step_range(scan, FRONT_STEP) == pytest.approx(2.4, abs=0.05)
            assert step_range(scan, LEFT_STEP) == pytest.approx(1.8, abs=0.05)
            assert np.nanmax(scan.ranges_m) < 3.1  # every wall within the room's corners
    finally:
        await link.close()
        await driver.close()
    assert sim.world.state.on_ground
    assert sim.world.state.height_m == 0.0


async def test_extern_gas_above_hover_lifts_the_vehicle_into_the_hat_beams(
    sim: LiveSim, tmp_path: Path
) -> None:
    link = await open_mk(sim.fc.path)
    driver = await open_urg(sim.urg.path)
    try:
        await link.next_sample(timeout_s=1.0)
        before = hat(await driver.next_scan(timeout_s=1.0))
        climb_until = time.monotonic() + 1.2
        while time.monotonic() < climb_until:  # one command per DebugOut, as the step does
            link.send_extern_control(ExternControl(gas=130, config=1))
            await link.next_sample(timeout_s=1.0)
        assert sim.fc.model.extern_active
        assert sim.world.sticks.gas_counts == 130
        sample = await link.next_sample(timeout_s=1.0)
        assert sample.gas_counts == 130  # DebugOut Analog[7]: what the vehicle flies
        await driver.next_scan(timeout_s=1.0)  # may have been taken before the climb
        after = hat(await driver.next_scan(timeout_s=1.0))
        truth_m = sim.world.state.height_m
    finally:
        await link.close()  # hands control back: the motors stop
        await driver.close()
    assert before == pytest.approx(0.0, abs=0.02)
    assert after > 0.3
    assert truth_m > after  # the scan is older than the truth, and it is still climbing
    await sim.fc.wait_for(lambda m: not m.extern_active)
    rows = np.loadtxt(tmp_path / "truth.txt", skiprows=1, ndmin=2)
    assert rows[:, 3].max() > 0.3
    assert np.all(np.diff(rows[:, 0]) >= 0.05 - 1e-9)


async def scans_until_silent(driver: UrgDriver, silence_s: float) -> int:
    """Read scans until none comes for ``silence_s``; how many came."""
    count = 0
    while True:
        try:
            await driver.next_scan(timeout_s=silence_s)
        except LinkError:
            return count
        count += 1
        assert count < 20, "the scans never stopped"


async def test_a_laser_stall_fires_on_time_and_stops_the_scans() -> None:
    stall = parse_fault("laser-stall@1.0:1.0")
    async with LiveSim(CFG, seed=7, faults=[stall]) as sim:
        driver = await open_urg(sim.urg.path)
        try:
            await driver.next_scan(timeout_s=1.0)
            assert sim.fired == []
            await asyncio.wait_for(sim.faults_done.wait(), timeout=2.0)
            fired_s = time.monotonic()
            assert sim.fired == [stall]
            assert await scans_until_silent(driver, 0.4) <= 2  # sent just before the stall
            assert sim.urg.model.scans_stalled > 0
            await driver.next_scan(timeout_s=2.0)  # and they come back after it
            assert time.monotonic() - fired_s > 0.8
        finally:
            await driver.close()


@pytest.fixture
def info_events() -> Iterator[None]:
    """Events at info level whatever an earlier in-process CLI run configured (its default
    level, warning, filters info before capture_logs sees it); the setup is put back."""
    saved = structlog.get_config()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.DEBUG))
    yield
    structlog.configure(**saved)


@pytest.mark.usefixtures("info_events")
async def test_each_fired_fault_is_logged_with_its_time_on_both_clocks() -> None:
    """The ``sim fault`` line says what fired, when on the fault clock (counted from the
    fault clock's start, here an event as ``--faults-on-sigusr1`` sets it) and when on the
    host's monotonic clock, the flight logs' time base: a fault test's proof of the fault."""
    clock = asyncio.Event()
    faults = ["battery@0.3:11.0", "fc-corrupt@0.1:2"]
    with structlog.testing.capture_logs() as logs:
        async with LiveSim(CFG, seed=7, faults=faults, fault_clock=clock) as sim:
            await asyncio.sleep(0.2)
            assert sim.fired == []  # the clock has not started: nothing fires
            clock.set()
            started_s = time.monotonic()
            await asyncio.wait_for(sim.faults_done.wait(), timeout=2.0)
    origin = [r for r in logs if r["event"] == "sim fault clock started"]
    assert len(origin) == 1
    assert origin[0]["mono_s"] == pytest.approx(started_s, abs=0.05)
    fired = [r for r in logs if r["event"] == "sim fault"]
    assert [r["fault"] for r in fired] == ["fc-corrupt@0.1:2", "battery@0.3:11"]
    for rec, at_s in zip(fired, (0.1, 0.3), strict=True):
        assert rec["t_s"] == pytest.approx(at_s, abs=0.05)
        assert rec["mono_s"] - origin[0]["mono_s"] == pytest.approx(rec["t_s"], abs=0.002)


async def test_battery_and_fc_faults_reach_the_link() -> None:
    faults = ["battery@0:9.6", "fc-corrupt:3@0", "fc-garbage@0:40"]
    async with LiveSim(CFG, seed=7, faults=faults) as sim:
        await asyncio.wait_for(sim.faults_done.wait(), timeout=1.0)
        link = await open_mk(sim.fc.path)
        try:
            samples = [await link.next_sample(timeout_s=1.0) for _ in range(3)]
            assert all(s.battery_v == pytest.approx(9.6, abs=0.05) for s in samples)
        finally:
            await link.close()
        assert link.stats.parser.crc_errors >= 3
        assert link.stats.parser.discarded_bytes > 0
        assert [str(f) for f in sim.fired] == ["battery@0:9.6", "fc-corrupt@0:3", "fc-garbage@0:40"]


async def test_unplug_faults_without_a_link_get_a_temporary_one() -> None:
    async with LiveSim(CFG, faults=["fc-vanish@0.1", "fc-replug@0.2"]) as sim:
        fc_path, urg_path = sim.fc.path, sim.urg.path
        assert is_link(fc_path)
        assert os.path.basename(fc_path) == "fc"
        assert not is_link(urg_path)  # no laser plug fault: the pty itself
        await asyncio.wait_for(sim.faults_done.wait(), timeout=1.0)
        link = await open_mk(fc_path)  # the same path leads to the replugged pty
        try:
            await link.next_sample(timeout_s=1.0)
        finally:
            await link.close()
    assert not is_link(fc_path)  # the link and its directory are removed


@pytest.mark.parametrize(
    ("text", "fault"),
    [
        ("fc-vanish@1.5", Fault(1.5, "fc-vanish")),
        ("laser-stall@2:0.5", Fault(2.0, "laser-stall", 0.5)),
        ("laser-stall:0.5@2", Fault(2.0, "laser-stall", 0.5)),
        ("fc-reboot@3", Fault(3.0, "fc-reboot", 1.0)),
        ("fc-garbage@0:64", Fault(0.0, "fc-garbage", 64.0)),
        ("battery@10:0", Fault(10.0, "battery", 0.0)),
    ],
)
def test_fault_strings_parse(text: str, fault: Fault) -> None:
    assert parse_fault(text) == fault


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("fc-vanish", "no '@T'"),
        ("fc-explode@1", "unknown kind 'fc-explode'"),
        ("fc-silent@1", "fc-silent needs DUR_S"),
        ("fc-vanish@1:2", "fc-vanish takes no argument"),
        ("laser-stall:1@2:3", "two arguments"),
        ("laser-stall@soon:1", "time 'soon' is not a number"),
        ("laser-stall@-1:1", "must be finite and >= 0"),
        ("laser-stall@nan:1", "must be finite and >= 0"),
        ("laser-stall@1:0", "DUR_S '0' must be finite and > 0"),
        ("fc-garbage@1:2.5", "NBYTES '2.5' is not an integer"),
        ("battery@1:-3", "VOLTS '-3' must be finite and >= 0"),
    ],
)
def test_bad_fault_strings_name_the_string_and_the_kinds(text: str, why: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_fault(text)
    msg = str(info.value)
    assert f"fault {text!r}" in msg
    assert why in msg
    assert "KIND@T[:ARG]" in msg
    assert all(kind in msg for kind in FAULT_KINDS)


def test_schedule_is_in_time_order_and_checked_before_anything_runs() -> None:
    assert [f.kind for f in parse_faults(["battery@5:10", "fc-reboot@1"])] == [
        "fc-reboot",
        "battery",
    ]
    with pytest.raises(ConfigError, match="laser-melt"):
        LiveSim(CFG, faults=["fc-reboot@1", "laser-melt@2"])


async def test_an_existing_truth_file_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "truth.txt"
    path.write_text("keep\n")
    sim = LiveSim(CFG, truth_path=path)
    with pytest.raises(ConfigError, match="truth"):
        await sim.start()
    assert path.read_text() == "keep\n"


def test_sim_command_prints_two_paths_and_exits_0_on_sigterm(tmp_path: Path) -> None:
    truth = tmp_path / "truth.txt"
    code = (
        "import sys; from mkflight.commands.sim_run import cmd_sim; "
        "from mkflight.eventlog import configure_events; configure_events('info'); "  # as the CLI
        f"sys.exit(cmd_sim(config_path=None, overrides=['sim.vehicle.gusts=false'], seed=3, "
        f"mk_link={str(tmp_path / 'mk')!r}, laser_link=None, truth={str(truth)!r}, "
        "faults=['battery@0.1:11'], duration_s=None))"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        mk_line = proc.stdout.readline()
        laser_line = proc.stdout.readline()
        assert mk_line == f"mk {tmp_path / 'mk'}\n"
        kind, laser_path = laser_line.split()
        assert kind == "laser"
        assert os.path.exists(laser_path)
        assert (tmp_path / "mk").is_symlink()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=5.0)
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
    assert proc.returncode == 0, err
    assert out == ""  # exactly the two lines
    assert not (tmp_path / "mk").exists()
    assert np.loadtxt(truth, skiprows=1, ndmin=2).shape[1] == 4


def test_sim_command_stops_after_its_duration_and_rejects_bad_faults() -> None:
    from mkflight.commands.sim_run import cmd_sim

    with pytest.raises(ConfigError, match="fc-nope"):
        cmd_sim(
            config_path=None,
            overrides=[],
            seed=None,
            mk_link=None,
            laser_link=None,
            truth=None,
            faults=["fc-nope@1"],
            duration_s=None,
        )
    started = time.monotonic()
    assert (
        cmd_sim(
            config_path=None,
            overrides=[],
            seed=None,
            mk_link=None,
            laser_link=None,
            truth=None,
            faults=[],
            duration_s=0.3,
        )
        == 0
    )
    assert time.monotonic() - started < 3.0
