"""AirframeLearner: biases, hover gas and vibration from the steady part of a flight."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.estimation.learner import LEARN_TAU_S, MIN_LEARN_S, AirframeLearner

STEP_NS = 53_248_000


def feed(
    learner: AirframeLearner,
    seconds: float,
    *,
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0),
    noise: float = 0.0,
    gas: float = 90.0,
    factor: float = 0.9,
    steady: bool = True,
    t0_ns: int = 0,
    seed: int = 0,
) -> int:
    """Samples of a vehicle that holds (no true acceleration) with these sensor errors."""
    rng = np.random.default_rng(seed)
    t_ns = t0_ns
    for _ in range(round(seconds * 1e9 / STEP_NS)):
        t_ns += STEP_NS
        n = rng.normal(0.0, noise, 3)
        acc = (bias[0] + n[0], bias[1] + n[1], bias[2] + n[2])
        f_body = (n[0], n[1], -9.81 + n[2])
        learner.observe(
            t_ns,
            acc_level_mps2=acc,
            f_body_mps2=f_body,
            gas_factor=factor,
            gas_counts=gas,
            steady=steady,
        )
    return t_ns


def test_nothing_is_learned_before_min_learn_s() -> None:
    learner = AirframeLearner(11.8)
    feed(learner, MIN_LEARN_S - 0.5)
    learned = learner.learned()
    assert not learner.ready
    assert learned.bias_level_mps2 is None
    assert learned.hover_gas_counts is None
    assert learned.vibration_mps2 is None


def test_bias_hover_gas_and_vibration_are_learned() -> None:
    learner = AirframeLearner(11.8)
    feed(learner, 40.0, bias=(0.16, -0.2, 0.5), noise=0.3, gas=90.0, factor=0.9)
    learned = learner.learned()
    assert learned.bias_level_mps2 == pytest.approx((0.16, -0.2, 0.5), abs=0.05)
    assert learned.hover_gas_counts == pytest.approx(100.0)  # 90 counts at a factor 0.9
    assert learned.vibration_mps2 == pytest.approx((0.3, 0.3, 0.3), rel=0.15)
    assert learned.steady_s == pytest.approx(40.0, abs=0.1)


def test_the_biases_are_learned_at_rest_before_take_off() -> None:
    """On the floor, motors off: no vibration, the biases settle in MIN_REST_S; then HOLD
    refines them (a shift of the AccZ offset with the motors running is followed)."""
    learner = AirframeLearner(11.8)
    t_ns = 0
    for _ in range(20):  # the handshake: 1 s at rest, a slight AccZ offset
        t_ns += STEP_NS
        learner.observe(
            t_ns,
            acc_level_mps2=(0.1, -0.05, 0.2),
            f_body_mps2=(0.1, -0.05, -9.61),
            gas_factor=0.9,
            gas_counts=0.0,
            steady=False,
            at_rest=True,
        )
    learned = learner.learned()
    assert learned.bias_level_mps2 == pytest.approx((0.1, -0.05, 0.2))
    assert learned.hover_gas_counts is None  # nothing of the kind at rest
    assert learned.vibration_mps2 is None
    feed(learner, 60.0, bias=(0.1, -0.05, 0.3), noise=0.2, t0_ns=t_ns + STEP_NS)
    bias = learner.learned().bias_level_mps2
    assert bias is not None
    assert bias[2] == pytest.approx(0.3, abs=0.03)


def test_unsteady_steps_teach_nothing() -> None:
    learner = AirframeLearner(11.8)
    t_ns = feed(learner, 20.0, bias=(1.0, 1.0, 1.0), gas=50.0, steady=False)
    assert not learner.ready
    feed(learner, 20.0, bias=(0.1, 0.0, 0.0), gas=90.0, t0_ns=t_ns)
    learned = learner.learned()
    assert learned.bias_level_mps2 == pytest.approx((0.1, 0.0, 0.0), abs=1e-9)
    assert learned.hover_gas_counts == pytest.approx(100.0)


def test_the_averages_follow_a_change_within_a_few_time_constants() -> None:
    learner = AirframeLearner(11.8)
    t_ns = feed(learner, 30.0, gas=90.0, factor=0.9)
    feed(learner, 50.0, gas=99.0, factor=0.9, t0_ns=t_ns)  # the pack sagged: more gas
    hover = learner.learned().hover_gas_counts
    assert hover is not None
    assert hover == pytest.approx(110.0, abs=0.2)


def test_a_gap_is_not_a_difference() -> None:
    learner = AirframeLearner(11.8)
    t_ns = feed(learner, 10.0)
    learner.observe(
        t_ns + 2_000_000_000,  # 2 s later: no weight, no difference
        acc_level_mps2=(50.0, 50.0, 50.0),
        f_body_mps2=(50.0, 50.0, 50.0),
        gas_factor=0.9,
        gas_counts=90.0,
        steady=True,
    )
    learned = learner.learned()
    assert learned.bias_level_mps2 == pytest.approx((0.0, 0.0, 0.0))
    assert learned.vibration_mps2 == pytest.approx((0.0, 0.0, 0.0))


@settings(max_examples=50, deadline=None)
@given(
    st.lists(
        st.tuples(*(st.floats(allow_nan=True, allow_infinity=True) for _ in range(4))),
        min_size=1,
        max_size=40,
    )
)
def test_non_finite_input_never_enters(values: list[tuple[float, float, float, float]]) -> None:
    learner = AirframeLearner(11.8)
    t_ns = feed(learner, 10.0, bias=(0.1, 0.1, 0.1), noise=0.1)
    for a, f, factor, gas in values:
        t_ns += STEP_NS
        learner.observe(
            t_ns,
            acc_level_mps2=(a, a, a),
            f_body_mps2=(f, f, f),
            gas_factor=factor,
            gas_counts=gas,
            steady=True,
        )
    learned = learner.learned()
    assert learned.bias_level_mps2 is not None
    assert learned.hover_gas_counts is not None
    assert learned.vibration_mps2 is not None
    assert all(math.isfinite(v) and abs(v) <= 3.0 for v in learned.bias_level_mps2)
    assert math.isfinite(learned.hover_gas_counts)
    assert all(math.isfinite(v) for v in learned.vibration_mps2)


def rest(learner: AirframeLearner, seconds: float, bias: tuple[float, float, float]) -> int:
    """Standing on the floor, motors off: the biases exactly, no vibration."""
    t_ns = 0
    for _ in range(round(seconds * 1e9 / STEP_NS)):
        t_ns += STEP_NS
        learner.observe(
            t_ns,
            acc_level_mps2=bias,
            f_body_mps2=(0.0, 0.0, -9.81),
            gas_factor=0.9,
            gas_counts=0.0,
            steady=False,
            at_rest=True,
        )
    return t_ns


def test_the_vertical_bias_at_rest_outweighs_a_short_noisy_hold() -> None:
    """2 s at rest, then 8 s of HOLD whose mean is 0.05 m/s² off: z keeps the rest
    value's weight of 20 s, decaying over LEARN_TAU_S (e^-0.8 of it left), where a plain
    time mean would keep 2/10; x and y count the rest like the hold."""
    learner = AirframeLearner(11.8)
    t_ns = rest(learner, 2.0, (0.3, 0.3, 0.40))
    feed(learner, 8.0, bias=(0.1, 0.1, 0.45), t0_ns=t_ns)
    bias = learner.learned().bias_level_mps2
    assert bias is not None
    kept = math.exp(-8.0 / LEARN_TAU_S)
    assert bias[2] == pytest.approx(0.40 * kept + 0.45 * (1 - kept), abs=0.002)
    assert bias[0] == pytest.approx(0.3 * 0.2 + 0.1 * 0.8, abs=0.01)
