"""The emulated URG's timing and hat are the airframe's, never the driver's."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from mkflight.config import Config, LaserConfig, SimConfig, SimVehicleConfig
from mkflight.sim.fc_timing import DebugTiming
from mkflight.sim.live import LiveSim
from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg import UrgModel
from mkflight.sim.urg_scene import NOMINAL_HAT, FixedRanges, HatGeometry, RoomScene, ScenePose
from mkflight.sim.urg_server import USB_DELAY_S
from mkflight.sim.vehicle import VehicleParams
from mkflight.urg.codec import md_command
from mkflight.urg.replies import ReplyParser, ScanReply
from mkflight.urg.units import URG_04LX

MS = 1_000_000
T0 = 1_000_000_000_000
END_NS = URG_04LX.step_offset_ns(725)  # a full scan leaves 70.8 ms after its step 0


def scan_arrivals(model: UrgModel, until_ns: int) -> list[tuple[int, ScanReply]]:
    """(delivery time, scan) of every scan message up to ``until_ns``, event by event."""
    parser = ReplyParser()
    out: list[tuple[int, ScanReply]] = []
    while (t := model.next_event_ns()) is not None and t <= until_ns:
        for chunk in model.poll(t):
            out += [(t, r) for r in parser.feed(chunk) if isinstance(r, ScanReply)]
    return out


def delays_ms(delay_ns: int, jitter_ns: int, seed: int = 1) -> list[float]:
    """How long after its end step each of 200 scans reached the host (ms)."""
    model = UrgModel(
        FixedRanges(),
        t_ns=T0,
        scip1=False,
        delivery_delay_ns=delay_ns,
        delivery_jitter_ns=jitter_ns,
        seed=seed,
    )
    model.receive(md_command(44, 725), T0)
    arrivals = scan_arrivals(model, T0 + 20_000 * MS)
    assert len(arrivals) >= 199
    return [(t - (T0 + k * 100 * MS + END_NS)) / MS for k, (t, _) in enumerate(arrivals)]


def test_delivery_is_the_delay_plus_a_uniform_jitter_in_order() -> None:
    d = delays_ms(40 * MS, 8 * MS)
    assert min(d) >= 40.0
    assert max(d) <= 48.0
    assert statistics.mean(d) == pytest.approx(44.0, abs=0.5)  # uniform 0..8 ms
    assert statistics.pstdev(d) == pytest.approx(8 / 12**0.5, abs=0.3)
    assert delays_ms(40 * MS, 8 * MS, seed=1) == d  # seeded
    assert delays_ms(40 * MS, 8 * MS, seed=2) != d
    assert set(delays_ms(30 * MS, 0)) == {30.0}  # no jitter: the delay exactly


def test_a_jittered_reply_never_overtakes_the_one_before() -> None:
    model = UrgModel(
        FixedRanges(), t_ns=T0, scip1=False, delivery_delay_ns=0, delivery_jitter_ns=50 * MS
    )
    model.receive(md_command(44, 725), T0)
    for k in range(20):  # commands answered at once, between the scans
        model.receive(b"II\n", T0 + k * 37 * MS)
    times = [t for t, _ in scan_arrivals(model, T0 + 3000 * MS)]
    assert times == sorted(times)


async def test_the_live_urg_delay_is_30_ms_plus_the_airframes_extra_not_the_drivers() -> None:
    vehicle = SimVehicleConfig(
        laser_extra_delay_s=0.02,
        laser_jitter_s=0.006,
        debug_jitter_ticks=2,
        debug_late_fraction=0.01,
    )
    cfg = Config(
        laser=LaserConfig(transport_delay_s=0.2, hat_offset_m=0.3, hat_steps=(44, 90)),
        sim=SimConfig(vehicle=vehicle),
    )
    async with LiveSim(cfg, seed=5) as sim:
        model = sim.urg.model
        assert sim.urg.usb_delay_s == pytest.approx(USB_DELAY_S + 0.02)
        assert model.delivery_delay_ns == round((USB_DELAY_S + 0.02) * 1e9)
        assert model.delivery_jitter_ns == 6 * MS
        scene = model.source
        assert isinstance(scene, RoomScene)
        assert scene.hat == NOMINAL_HAT  # the airframe's hat, not laser.*
        assert sim.fc.model.debug_jitter.timing == DebugTiming(2, 0.01, seed=5)


def test_the_scene_uses_the_airframes_hat_geometry() -> None:
    params = VehicleParams.from_config(
        SimVehicleConfig(hat_steps=(44, 100), mirror_edge_last_step=120, hat_offset_m=0.1)
    )
    hat = HatGeometry.of(params)
    assert hat == HatGeometry((44, 100), 120, 0.1)
    assert HatGeometry((44, 127), 149, 0.05) == NOMINAL_HAT
    pose = ScenePose(height_m=0.5)
    scene = RoomScene(room_caster(box_room(6, 6)), pose=pose, hat=hat, seed=1, error_fraction=0)
    raw = scene.ranges_mm(0, np.arange(44, 726))
    at = {s: int(v) for s, v in zip(range(44, 726), raw, strict=True)}
    floor = [at[s] for s in range(44, 101)]
    assert statistics.mean(floor) == pytest.approx(600, abs=5)  # (0.5 + 0.1) m through the hat
    assert all(v == 0 or 30 <= v <= 80 for v in (at[s] for s in range(101, 121)))  # the edge
    assert all(v > 1000 for v in (at[s] for s in range(121, 726)))  # the room's walls
    nominal = RoomScene(room_caster(box_room(6, 6)), pose=pose, seed=1, error_fraction=0)
    raw = nominal.ranges_mm(0, np.arange(44, 726))
    assert statistics.mean(raw[: 127 - 44 + 1].tolist()) == pytest.approx(550, abs=5)
    assert all(v > 1000 for v in raw[150 - 44 :].tolist())
