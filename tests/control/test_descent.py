"""The descent without the hat: it finds the floor, softly, on what is left."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import Config
from mkflight.control.descent import Descent, DescentMode, DescentParams
from mkflight.estimation.vertical import VerticalDeadReckoning

from .vertical_world import STEP_NS, VerticalWorld

PARAMS = DescentParams.from_config(Config().control, Config().mk.g_mps2)
MAX_TOUCHDOWN_MPS = 0.5  # SPEC §8: every touchdown at most this fast


def land(
    world: VerticalWorld,
    *,
    learned_hover: float | None = None,
    use_imu: bool = True,
    hat_noise_m: float | None = None,
    spike_at_m: float | None = None,
    seconds: float = 15.0,
) -> tuple[Descent, list[int], str]:
    """Hover, then descend like the flight step: model-aided vertical channel + Descent."""
    hover = world.hover_gas if learned_hover is None else learned_hover
    t_ns = 0
    gas = world.hover_gas
    world.fly(gas, 2.0)  # settled in hover
    vertical = VerticalDeadReckoning(
        t_ns=t_ns,
        height_m=world.height_m,
        vz_up_mps=world.vz_mps,
        hover_gas_counts=hover,
        gas_counts=gas,
        noise_mps2=world.noise_mps2,
        g_mps2=PARAMS.g_mps2,
    )
    descent = Descent(
        PARAMS,
        t_ns=t_ns,
        vz_up_mps=world.vz_mps,
        hover_gas_counts=hover,
        noise_mps2=world.noise_mps2,
    )
    gases: list[int] = []
    end = "timeout"
    spiked = False
    for k in range(round(seconds * 1e9 / STEP_NS)):
        world.fly(gas, STEP_NS / 1e9)
        t_ns += STEP_NS
        acc = world.accel()
        if spike_at_m is not None and not spiked and world.height_m < spike_at_m:
            acc += 6.0  # a bump that is not the floor
            spiked = True
        v = vertical.step(
            t_ns, gas_counts=gas, gas_factor=1.0, acc_up_mps2=acc if use_imu else None
        )
        hat = None
        if hat_noise_m is not None and k % 2 == 0:
            hat = (t_ns, world.height_m + float(world.rng.normal(0.0, hat_noise_m)))
        out = descent.step(
            t_ns,
            gas_factor=1.0,
            vz_up_mps=v.vz_up_mps if use_imu else None,
            height_m=v.height_m if use_imu else None,
            acc_up_mps2=acc if use_imu else None,
            hat=hat,
        )
        gas = out.gas_counts
        gases.append(gas)
        if out.stopped:
            vertical.rest()
        if out.vz_reset_mps is not None:
            vertical.set_velocity(out.vz_reset_mps)
        if out.on_floor:
            end = "floor"
            break
        if out.give_up:
            end = "gave up"
            break
    world.fly(0.0 if end == "floor" else gas, 1.0)
    return descent, gases, end


def assert_soft(world: VerticalWorld, end: str) -> None:
    assert end == "floor", end
    assert world.touchdowns, "never touched the floor"
    assert max(world.touchdowns) <= MAX_TOUCHDOWN_MPS, world.touchdowns
    assert world.height_m < 0.01


def test_a_gear_that_stops_the_vehicle_is_felt_as_a_stop() -> None:
    world = VerticalWorld(noise_mps2=0.2)
    descent, gases, end = land(world)
    assert_soft(world, end)
    assert max(world.touchdowns) == pytest.approx(PARAMS.descent_mps, abs=0.1)
    assert descent.mode is DescentMode.INERTIAL
    assert all(0 <= g <= PARAMS.gas_max for g in gases)


def test_an_instant_floor_is_found_by_the_descent_budget_and_the_probe() -> None:
    world = VerticalWorld(noise_mps2=0.2, instant_floor=True)
    _, _, end = land(world)
    assert_soft(world, end)


@pytest.mark.parametrize("seed", range(12))
def test_a_worn_prop_still_lands_softly(seed: int) -> None:
    """0.39 m/s² of vibration on AccZ (30 counts x 0.8, the envelope's worst)."""
    world = VerticalWorld(noise_mps2=0.39, seed=seed, drag_per_s=0.5)
    _, _, end = land(world)
    assert_soft(world, end)


@pytest.mark.parametrize("error", [-0.04, 0.04])
def test_a_hover_gas_learned_4_percent_off_still_lands_softly(error: float) -> None:
    world = VerticalWorld(noise_mps2=0.25, seed=3)
    _, _, end = land(world, learned_hover=world.hover_gas * (1.0 + error))
    assert_soft(world, end)


def test_a_bump_in_the_air_is_not_the_floor() -> None:
    world = VerticalWorld(noise_mps2=0.1, seed=1)
    _, _, end = land(world, spike_at_m=0.35)
    assert_soft(world, end)


def test_without_the_imu_the_hat_height_lands_it() -> None:
    world = VerticalWorld(noise_mps2=0.2, seed=2)
    descent, _, end = land(world, use_imu=False, hat_noise_m=0.002)
    assert descent.mode is DescentMode.LASER
    assert_soft(world, end)


def test_with_nothing_the_open_descent_gives_up_to_the_pilot() -> None:
    world = VerticalWorld(noise_mps2=0.2, seed=2)
    descent, gases, end = land(world, use_imu=False)
    assert descent.mode is DescentMode.OPEN
    assert end == "gave up"
    assert descent.elapsed_s == pytest.approx(PARAMS.max_s, abs=0.1)
    assert world.touchdowns[0] <= MAX_TOUCHDOWN_MPS  # it came down softly before
    assert all(0 <= g <= PARAMS.gas_max for g in gases)


ANY = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=200, deadline=None)
@given(
    st.floats(allow_nan=True, allow_infinity=True),
    st.lists(st.tuples(ANY, ANY, ANY, ANY, ANY), min_size=1, max_size=60),
)
def test_the_gas_is_always_a_byte_within_limits(
    hover: float, steps: list[tuple[float, float, float, float, float]]
) -> None:
    descent = Descent(PARAMS, t_ns=0, vz_up_mps=hover, hover_gas_counts=hover)
    t_ns = 0
    for factor, vz, h, acc, hat in steps:
        t_ns += STEP_NS
        out = descent.step(
            t_ns,
            gas_factor=factor,
            vz_up_mps=vz,
            height_m=h,
            acc_up_mps2=acc,
            hat=None if math.isnan(hat) else (t_ns, hat),
        )
        assert 0 <= out.gas_counts <= PARAMS.gas_max
        assert isinstance(out.gas_counts, int)
