"""SimWorld: the vehicle in host time, driven by the FC model's command, read by FC and URG."""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import structlog
from structlog.testing import capture_logs

from mkflight.config import (
    Config,
    ControlConfig,
    EstimationConfig,
    LaserConfig,
    MkConfig,
    SimConfig,
    SimFcConfig,
    SimVehicleConfig,
)
from mkflight.mk.messages import ANALOG_GAS, DebugOut, ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug
from mkflight.sim.airframe import describe, random_airframe
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_timing import DebugTiming
from mkflight.sim.world import HISTORY_NS, TRUTH_PERIOD_NS, SimWorld, WorldFc

T0 = 5_000_000_000_123  # a host monotonic time: deliberately not round
MS = 1_000_000
S = 1_000_000_000
CALM = Config(sim=SimConfig(vehicle=SimVehicleConfig(gusts=False)))  # deterministic climbs
GEAR_M = 0.01  # on the floor: the landing gear's sag (a few mm) unloaded by partial thrust


@contextlib.contextmanager
def events() -> Iterator[list[MutableMapping[str, Any]]]:
    """The structlog events logged inside, whatever level an earlier test configured."""
    saved = structlog.get_config()
    structlog.reset_defaults()
    try:
        with capture_logs() as logs:
            yield logs
    finally:
        structlog.configure(**saved)


def make(
    cfg: Config = CALM,
    *,
    seed: int = 3,
    truth_path: Path | None = None,
    stick_gas_with_extern_only: bool = True,
    yaw_rad: float = 0.0,
) -> tuple[SimWorld, WorldFc]:
    world = SimWorld(
        cfg,
        seed=seed,
        t0_ns=T0,
        truth_path=truth_path,
        stick_gas_with_extern_only=stick_gas_with_extern_only,
        yaw_rad=yaw_rad,
    )
    fc = WorldFc(cfg.sim.fc, world, t_ns=T0)
    return world, fc


def take_control(fc: FcModel, t_ns: int, gas: int) -> None:
    """ExternControl with Config = 1 at ``t_ns``; the FC handles it within a few ms."""
    fc.receive(ExternControl(gas=gas, config=1).encode(), t_ns)
    fc.poll(t_ns + 10 * MS)
    assert fc.extern_active


def fly(world: SimWorld, fc: FcModel, until_ns: int, *, hold_every_ns: int = 0) -> None:
    """Advance in 20 ms polls, as the emulator's send loop does; renew the hold if asked."""
    t = world.t_ns
    next_hold = t + hold_every_ns if hold_every_ns else None
    while t < until_ns:
        t = min(until_ns, t + 20 * MS)
        if next_hold is not None and t >= next_hold:
            fc.receive(b"#bd>M==Dk\r", t)  # 'd' 5: reloads the hold counter
            next_hold += hold_every_ns
        fc.poll(t)


def test_on_the_ground_with_stick_gas_only_it_stays_down_and_level() -> None:
    world, fc = make()
    fly(world, fc, T0 + 3 * S)
    assert not fc.extern_active
    assert fc.effective_command().gas == 200  # the pilot's cap ...
    assert world.sticks.gas_counts == 0  # ... but the stick is down: motors off
    s = world.state
    assert s.on_ground
    assert s.height_m == 0.0
    assert s.pitch_rad == 0.0
    assert s.roll_rad == 0.0
    assert s.pos_w_m[:2] == (0.0, 0.0)


def test_stick_gas_below_hover_keeps_it_down_when_flown_literally() -> None:
    cfg = Config(sim=SimConfig(fc=SimFcConfig(stick_gas=60), vehicle=CALM.sim.vehicle))
    world, fc = make(cfg, stick_gas_with_extern_only=False)
    fly(world, fc, T0 + 2 * S)
    assert world.sticks.gas_counts == 60  # the pilot's stick gas, flown as it is
    assert world.state.on_ground
    assert world.state.height_m < GEAR_M


def test_stick_gas_above_hover_lifts_off_when_flown_literally() -> None:
    world, fc = make(stick_gas_with_extern_only=False)  # stick gas 200, hover ~104
    fly(world, fc, T0 + 1 * S)
    assert world.state.height_m > 0.5


def test_extern_gas_above_hover_climbs_and_below_stays() -> None:
    world, fc = make()
    take_control(fc, T0 + 100 * MS, gas=90)
    fly(world, fc, T0 + 1 * S, hold_every_ns=500 * MS)
    assert world.state.on_ground  # below hover gas
    assert world.state.height_m < GEAR_M
    assert world.sticks.gas_counts == 90
    take_control(fc, world.t_ns, gas=150)
    h0 = world.state.height_m
    fly(world, fc, world.t_ns + 1 * S, hold_every_ns=500 * MS)
    assert world.sticks.gas_counts == 150
    assert world.state.height_m > h0 + 0.5
    assert world.state.vel_w_mps[2] < -0.5  # climbing (z down)


def test_releasing_control_cuts_the_motors() -> None:
    world, fc = make()
    take_control(fc, T0 + 100 * MS, gas=150)
    fly(world, fc, T0 + 1 * S)
    assert world.state.height_m > 0.3
    fc.receive(ExternControl(gas=0, config=0).encode(), world.t_ns)
    fly(world, fc, world.t_ns + 3 * S)
    assert not fc.extern_active
    assert world.sticks.gas_counts == 0
    assert world.state.on_ground


def test_the_command_applies_from_the_tick_that_handled_it() -> None:
    """WorldFc advances the world before the FC acts: no wait for the next DebugOut."""
    world, fc = make()
    fc.receive(ExternControl(gas=150, config=1).encode(), T0 + 100 * MS)
    fc.poll(T0 + 110 * MS)  # handled about 4 ms after it was written
    assert fc.extern_active
    assert world.sticks.gas_counts == 0  # up to now the motors were off
    world.advance_to(T0 + 120 * MS)
    assert world.sticks.gas_counts == 150


def test_time_never_goes_back() -> None:
    world, _ = make()
    world.advance_to(T0 + 500 * MS)
    state = world.state
    assert world.advance_to(T0 + 200 * MS) is state
    assert world.t_ns == T0 + 500 * MS
    assert world.state_at(T0 + 100 * MS).t_s < state.t_s  # answered from the history
    assert world.t_ns == T0 + 500 * MS


def test_pose_at_interpolates_the_history_and_advances_for_later_times() -> None:
    world, fc = make()
    take_control(fc, T0 + 100 * MS, gas=160)
    fly(world, fc, T0 + 1500 * MS)
    now = world.t_ns
    # A time halfway between two stored states: the mean of their poses.
    t_a, t_b = now - 300 * MS, now - 290 * MS
    a, b = world.pose_at(t_a), world.pose_at(t_b)
    mid = world.pose_at((t_a + t_b) // 2)
    assert b.height_m > a.height_m  # climbing
    assert mid.height_m == pytest.approx((a.height_m + b.height_m) / 2, rel=1e-9)
    assert mid.x_m == pytest.approx((a.x_m + b.x_m) / 2, abs=1e-12)
    assert world.t_ns == now  # nothing advanced
    # The past is consistent with what the present was then.
    heights = [world.pose_at(now - k * 50 * MS).height_m for k in range(10)]
    assert heights == sorted(heights, reverse=True)
    # Later: advances the vehicle.
    later = world.pose_at(now + 100 * MS)
    assert world.t_ns == now + 100 * MS
    assert later.height_m > world.pose_at(now).height_m


def test_history_keeps_about_a_second() -> None:
    world, _ = make()
    world.advance_to(T0 + 3 * S)
    oldest = world.state_at(T0)  # long gone: the oldest kept state
    assert (world.t_ns - T0) / S - oldest.t_s <= HISTORY_NS / S + 0.02
    assert oldest.t_s >= 3.0 - HISTORY_NS / S - 0.02


def test_yaw_interpolates_the_short_way_round() -> None:
    world, fc = make(yaw_rad=math.pi - 0.3)
    take_control(fc, T0 + 10 * MS, gas=150)
    fc.receive(ExternControl(gas=150, yaw=-40, config=1).encode(), T0 + 300 * MS)
    fly(world, fc, T0 + 1500 * MS)  # turning clockwise (0.8 rad/s) through +-pi
    yaws = [world.pose_at(T0 + 1500 * MS - k * 5 * MS).yaw_rad for k in range(190)]
    steps = np.abs(np.diff(np.unwrap(yaws)))
    assert np.max(steps) < 0.05
    assert all(-math.pi <= y <= math.pi for y in yaws)
    assert min(yaws) < -3.0 < 3.0 < max(yaws)  # it did cross +-pi


def test_debug_out_at_rest_reads_level_and_minus_g() -> None:
    world, fc = make()
    samples = []
    for k in range(1, 41):
        t = T0 + k * 53 * MS
        fc.poll(t)
        samples.append(imu_from_debug(fc.debug_out(t), t, DEFAULT_CALIBRATION))  # the flight's
    pitch = np.array([s.pitch_rad for s in samples])
    roll = np.array([s.roll_rad for s in samples])
    acc_z = np.array([s.acc_z_mps2 for s in samples])
    acc_x = np.array([s.acc_x_mps2 for s in samples])
    assert abs(pitch.mean()) < 0.03  # minus the flight's trim (std 5 mrad) and noise
    assert abs(roll.mean()) < 0.03
    assert acc_z.mean() == pytest.approx(-9.81, abs=0.3)
    assert abs(acc_x.mean()) < 0.3
    assert samples[-1].gas_counts == 0  # motors off
    assert samples[-1].battery_v == pytest.approx(world.state.battery_v, abs=0.15)


def test_battery_override_is_what_the_fc_reads() -> None:
    world, fc = make()
    world.battery_override_v = 9.9
    values = world.analog(T0 + 60 * MS, fc)
    imu = imu_from_debug(DebugOut.from_values(dict(values)), T0, DEFAULT_CALIBRATION)
    assert imu.battery_v == pytest.approx(9.9, abs=1e-6)
    assert world.state.battery_v > 11.0  # the vehicle itself is not affected


def test_gas_in_the_debug_out_is_what_the_vehicle_flies() -> None:
    world, fc = make()
    take_control(fc, T0 + 100 * MS, gas=120)
    world.advance_to(T0 + 200 * MS)
    assert world.analog(T0 + 200 * MS, fc)[ANALOG_GAS] == 4 * 120


def test_truth_rows_are_written_at_most_every_50_ms(tmp_path: Path) -> None:
    path = tmp_path / "truth.txt"
    world, fc = make(truth_path=path)
    take_control(fc, T0 + 100 * MS, gas=150)
    fly(world, fc, T0 + 2 * S)  # not closed: a killed process leaves this
    rows = np.loadtxt(path, skiprows=1, ndmin=2)
    assert rows.shape[1] == 4
    assert world.truth_rows == rows.shape[0]
    assert rows[0].tolist() == [0.0, 0.0, 0.0, 0.0]
    dt = np.diff(rows[:, 0])
    assert dt.min() >= TRUTH_PERIOD_NS / S - 1e-9
    assert dt.max() <= TRUTH_PERIOD_NS / S + 0.011  # one history chunk late at most
    assert rows[-1, 0] == pytest.approx(2.0, abs=0.06)
    assert rows[-1, 3] == pytest.approx(world.state.height_m, abs=0.2)
    assert rows[-1, 3] > 0.5  # z is height, up
    header = path.read_text().splitlines()[:3]
    assert header[:2] == ["t x y z", f"# t0_ns {T0} (host monotonic clock at t = 0)"]
    assert header[2].startswith("# airframe {")
    airframe = json.loads(header[2].removeprefix("# airframe "))
    assert airframe == {"kind": "nominal", "seed": 1, **describe(world.params)}
    world.close()


def test_truth_file_is_never_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "truth.txt"
    path.write_text("keep\n")
    with pytest.raises(FileExistsError):
        make(truth_path=path)
    assert path.read_text() == "keep\n"


def test_same_seed_same_flight() -> None:
    def final(seed: int) -> tuple[float, float, float]:
        world, fc = make(Config(), seed=seed)  # gusts on
        take_control(fc, T0 + 100 * MS, gas=150)
        fly(world, fc, T0 + 1 * S)
        return world.state.pos_w_m

    assert final(4) == final(4)
    assert final(4) != final(5)


def test_a_touchdown_is_logged_kept_and_written_before_the_next_truth_row(tmp_path: Path) -> None:
    path = tmp_path / "truth.txt"
    world, fc = make(truth_path=path)
    take_control(fc, T0 + 100 * MS, gas=150)
    fly(world, fc, T0 + 1 * S)
    assert world.touchdowns == ()
    top_m = world.state.height_m
    with events() as logs:
        fc.receive(ExternControl(gas=0, config=0).encode(), world.t_ns)  # motors off: it falls
        fly(world, fc, world.t_ns + 3 * S)
    assert len(world.touchdowns) == 1
    t_s, speed = world.touchdowns[0]
    assert speed > 2.0  # a free fall from above 0.5 m
    (event,) = [e for e in logs if e["event"] == "sim touchdown"]
    assert event["speed_mps"] == pytest.approx(speed, abs=1e-3)
    assert event["t_s"] == pytest.approx(t_s, abs=1e-3)
    assert event["height_m"] >= top_m
    assert event["extern_active"] is False
    world.close()
    lines = path.read_text().splitlines()
    (i,) = [k for k, line in enumerate(lines) if line.startswith("# touchdown")]
    _, _, t_text, speed_text = lines[i].split()
    assert float(t_text) == pytest.approx(t_s, abs=1e-4)  # the rows' time base (origin t0)
    assert float(speed_text) == pytest.approx(speed, abs=1e-4)
    assert len(lines[i + 1].split()) == 4  # a row follows
    rows = np.loadtxt(path, skiprows=1, ndmin=2)  # the comments are skipped
    assert rows.shape[1] == 4


def test_the_airframe_is_the_sims_and_logged_once() -> None:
    cfg = Config(sim=SimConfig(airframe="random", seed=9))
    with events() as logs:
        world, fc = make(cfg)
    assert world.params == random_airframe(9)
    (event,) = [e for e in logs if e["event"] == "sim airframe"]
    assert event["kind"] == "random"
    assert event["seed"] == 9
    assert event["flight_seed"] == 3
    assert event["hover_gas_counts"] == pytest.approx(world.params.hover_gas_counts, abs=1e-6)
    p = world.params
    assert fc.debug_jitter.timing == DebugTiming(p.debug_jitter_ticks, p.debug_late_fraction, 3)


def test_the_vehicle_reads_nothing_of_the_flights_config() -> None:
    """mk, control, laser and estimation are the flight's: the same bytes fly the same vehicle."""
    other = Config(
        mk=MkConfig(counts_per_rad=80.0, acc_nick_counts_per_g=500.0, acc_z_counts_per_mps2=12.0),
        control=ControlConfig(hover_gas=80, hover_voltage_v=12.5),
        laser=LaserConfig(transport_delay_s=0.1, hat_offset_m=0.2, hat_steps=(44, 100)),
        estimation=EstimationConfig(filter_gain_per_s=1.0),
        sim=CALM.sim,
    )

    def flight(cfg: Config) -> tuple[list[object], list[dict[int, int]]]:
        world, fc = make(cfg)
        take_control(fc, T0 + 100 * MS, gas=130)
        states: list[object] = []
        debug: list[dict[int, int]] = []
        for k in range(30):
            t = T0 + 200 * MS + k * 53 * MS
            fc.receive(ExternControl(nick=10 - k, roll=k % 7, gas=120, config=1).encode(), t)
            fc.poll(t + 20 * MS)
            states.append(world.state)
            debug.append(dict(world.analog(t + 20 * MS, fc)))
        return states, debug

    assert flight(CALM) == flight(other)
