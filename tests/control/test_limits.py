"""Command limits: the gas byte never wraps, counts stay in range, non-finite is refused."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import ControlConfig
from mkflight.control.limits import (
    angle_to_counts,
    clamp_norm,
    command_within_limits,
    gas_to_counts,
)
from mkflight.msgs import Command

FINITE = st.floats(allow_nan=False, allow_infinity=False)


@given(FINITE, st.integers(0, 255))
def test_gas_never_leaves_its_range(gas: float, gas_max: int) -> None:
    out = gas_to_counts(gas, gas_max)
    assert type(out) is int
    assert 0 <= out <= gas_max


def test_negative_gas_is_zero_not_a_wrapped_byte() -> None:
    assert gas_to_counts(-1.0, 130) == 0
    assert gas_to_counts(-1e300, 130) == 0
    assert gas_to_counts(1e300, 130) == 130
    assert gas_to_counts(99.6, 130) == 100


@given(FINITE, st.sampled_from([-1, 1]), st.floats(0.1, 1000))
def test_angle_counts_within_127(angle: float, sign: int, scale: float) -> None:
    out = angle_to_counts(angle, sign, scale)
    assert type(out) is int
    assert -127 <= out <= 127


def test_angle_counts_sign_and_scale() -> None:
    assert angle_to_counts(-0.1, -1, 120.0) == 12  # nose down -> positive nick
    assert angle_to_counts(0.1, -1, 120.0) == -12
    assert angle_to_counts(0.1, 1, 120.0) == 12
    assert angle_to_counts(5.0, -1, 120.0) == -127


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="non-finite"):
        gas_to_counts(bad, 130)
    with pytest.raises(ValueError, match="non-finite"):
        angle_to_counts(bad, -1, 120.0)


def test_clamp_norm_keeps_direction() -> None:
    x, y, clamped = clamp_norm(3.0, 4.0, 1.0)
    assert clamped
    assert (x, y) == pytest.approx((0.6, 0.8))
    assert clamp_norm(0.3, 0.4, 1.0) == (0.3, 0.4, False)


def test_command_within_limits() -> None:
    c = ControlConfig()
    assert command_within_limits(Command(0, 127, -127, 40, 130), c)
    assert not command_within_limits(Command(0, 128, 0, 0, 0), c)
    assert not command_within_limits(Command(0, 0, 0, 41, 0), c)
    assert not command_within_limits(Command(0, 0, 0, 0, -1), c)
    assert not command_within_limits(Command(0, 0, 0, 0, 131), c)
    assert not command_within_limits(Command(0, 0.5, 0, 0, 0), c)  # type: ignore[arg-type]
