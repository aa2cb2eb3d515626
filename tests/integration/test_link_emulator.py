"""MkLink against the FlightCtrl emulator over real pseudo-terminals: the safety behaviours."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mkflight.config import Config, MkConfig, SimFcConfig, SimVehicleConfig
from mkflight.errors import LinkError
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION
from mkflight.sim.fc_server import FcEmulator
from mkflight.sim.sources import RestingVehicleSource
from mkflight.sim.vehicle import VehicleParams

SETTINGS = LinkSettings.from_config(Config())


@pytest.fixture
async def emulator(tmp_path: Path) -> AsyncIterator[FcEmulator]:
    source = RestingVehicleSource(VehicleParams.from_config(SimVehicleConfig()), seed=3)
    async with FcEmulator(SimFcConfig(), source, link=tmp_path / "fc0") as emu:
        yield emu


async def open_link(
    emulator: FcEmulator, settings: LinkSettings = SETTINGS, failed: asyncio.Event | None = None
) -> MkLink:
    async def opener() -> ByteStream:
        try:
            return await open_serial(emulator.path, 57600)
        except LinkError:
            if failed is not None:
                failed.set()
            raise

    link = MkLink(await opener(), settings, DEFAULT_CALIBRATION, reopen=opener)
    await link.connect()
    link.subscribe()
    return link


async def test_take_control_then_release_on_close(emulator: FcEmulator) -> None:
    link = await open_link(emulator)
    for _ in range(5):
        sample = await link.next_sample(timeout_s=1.0)
        assert sample.acc_z_mps2 == pytest.approx(-9.81, abs=0.3)
        link.send_extern_control(ExternControl(nick=10, roll=-5, gas=120, config=1))
    await emulator.wait_for(lambda m: m.extern_active)
    assert emulator.model.effective_command().gas == 120
    await link.close()
    await emulator.wait_for(lambda m: not m.extern_active)
    assert emulator.model.last_extern is not None
    assert emulator.model.last_extern.config == 0
    assert link.stats.confirms >= 5  # the release frames were confirmed
    assert link.stats.confirms_lost == 0


async def test_extern_gas_is_capped_by_the_stick(tmp_path: Path) -> None:
    source = RestingVehicleSource(VehicleParams.from_config(SimVehicleConfig()), seed=3)
    async with FcEmulator(SimFcConfig(stick_gas=100), source) as emulator:
        link = await open_link(emulator)
        await link.next_sample(timeout_s=1.0)
        link.send_extern_control(ExternControl(gas=120, config=1))  # the pilot holds 100
        await emulator.wait_for(lambda m: m.extern_active)
        assert emulator.model.effective_command().gas == 100
        for _ in range(3):
            sample = await link.next_sample(timeout_s=1.0)
        assert sample.gas_counts == 100  # DebugOut Analog[7] shows the cap
        await link.close()


async def test_a_stalled_consumer_lets_the_fc_drop_extern_control(emulator: FcEmulator) -> None:
    """No renewals without a live control step: the FC's hold runs out (~5.2 s)."""
    link = await open_link(emulator)
    await link.next_sample(timeout_s=1.0)
    link.send_extern_control(ExternControl(nick=20, gas=100, config=1))
    await emulator.wait_for(lambda m: m.extern_active)
    # The consumer stops asking for samples: nothing refreshes the FC's hold.
    await emulator.wait_for(lambda m: not m.extern_active, timeout_s=8.0)
    assert emulator.model.hold_counts == 0
    await link.close(release=False)


async def test_fc_reboot_is_detected_and_the_stream_resumes(emulator: FcEmulator) -> None:
    link = await open_link(emulator)
    await link.next_sample(timeout_s=1.0)
    link.send_extern_control(ExternControl(gas=100, config=1))
    await emulator.wait_for(lambda m: m.extern_active)
    emulator.reboot(boot_s=0.3)
    sample = await link.next_sample(timeout_s=3.0)  # re-subscribed after staleness
    assert sample.battery_v == pytest.approx(12.4, abs=0.05)
    assert link.stats.stale_events == 1
    await link.next_sample(timeout_s=1.0)  # the consumer's next call asks the version
    await emulator.wait_for(lambda m: m.rx_by_cmd["v"] >= 1)  # heard by the rebooted FC
    for _ in range(5):  # the 'V' answer follows within a sample period or two
        if link.stats.versions >= 2:
            break
        await link.next_sample(timeout_s=1.0)
    assert link.stats.versions >= 2
    assert not emulator.model.extern_active  # a reboot forgets extern control
    await link.close()


async def test_silence_then_recovery(emulator: FcEmulator) -> None:
    link = await open_link(emulator)
    await link.next_sample(timeout_s=1.0)
    emulator.silence_for(0.5)
    await link.next_sample(timeout_s=2.0)
    assert link.stats.stale_events == 1
    assert link.stale_for_s() < 0.1
    await link.close()


async def test_unplug_and_replug_with_reopen(emulator: FcEmulator) -> None:
    settings = LinkSettings.from_config(
        Config(mk=MkConfig(reopen_backoff_s=0.05, reopen_backoff_max_s=0.2))
    )
    failed = asyncio.Event()
    link = await open_link(emulator, settings, failed)
    await link.next_sample(timeout_s=1.0)
    emulator.vanish()
    with pytest.raises(LinkError, match="vanished"):
        await link.next_sample(timeout_s=1.0)
    reopening = asyncio.create_task(link.reopen(max_wait_s=5.0))
    await asyncio.wait_for(failed.wait(), 2.0)  # an attempt failed on the missing device
    emulator.replug()
    version = await reopening
    assert version.text == "0.84a"
    sample = await link.next_sample(timeout_s=1.0)
    assert sample.acc_z_mps2 == pytest.approx(-9.81, abs=0.3)
    assert link.stats.reopens == 1
    await link.close()


async def test_garbage_and_crc_errors_are_counted(emulator: FcEmulator) -> None:
    link = await open_link(emulator)
    await link.next_sample(timeout_s=1.0)
    emulator.inject_garbage(b"\xff" * 50 + b"#bD==\r")
    emulator.corrupt_next(2)
    for _ in range(5):
        await link.next_sample(timeout_s=1.0)
    assert link.stats.parser.crc_errors >= 2
    assert link.stats.parser.discarded_bytes >= 50
    await link.close()
