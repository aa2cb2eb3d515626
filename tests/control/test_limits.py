"""Command limits: the gas byte never wraps, counts stay in range, non-finite is refused."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import ControlConfig, MkConfig
from mkflight.control.limits import (
    angle_to_counts,
    clamp_norm,
    command_within_limits,
    gas_to_counts,
    tilt_limit_counts,
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


def test_the_configured_tilt_is_the_limit_not_the_byte() -> None:
    """With ``counts_per_rad`` nick and roll are held to ``max_tilt_rad`` (36 counts at the
    defaults, plus the rounding of both axes), as a vector; without it to +-127 each."""
    c, cpr = ControlConfig(), MkConfig().counts_per_rad
    assert tilt_limit_counts(c, cpr) == pytest.approx(0.30 * 120 + math.sqrt(0.5))
    assert command_within_limits(Command(0, 36, 0, 0, 100), c, counts_per_rad=cpr)
    assert command_within_limits(Command(0, -25, 26, 0, 100), c, counts_per_rad=cpr)  # 36.1
    assert not command_within_limits(Command(0, 37, 0, 0, 100), c, counts_per_rad=cpr)
    assert not command_within_limits(Command(0, 26, -26, 0, 100), c, counts_per_rad=cpr)  # 36.8
    assert not command_within_limits(Command(0, 127, -127, 40, 130), c, counts_per_rad=cpr)
    assert command_within_limits(Command(0, 127, -127, 40, 130), c)  # the byte's range only
    wide = ControlConfig(max_tilt_rad=0.5)
    assert command_within_limits(Command(0, 60, 0, 0, 100), wide, counts_per_rad=cpr)
    assert not command_within_limits(Command(0, 60, 0, 0, 100), c, counts_per_rad=cpr)
    assert not command_within_limits(Command(0, 36, 0, 0, 100), c, counts_per_rad=60.0)


@given(FINITE, FINITE, st.floats(0.05, 0.5), st.floats(10.0, 300.0))
def test_a_clamped_tilt_in_counts_is_within_the_tilt_limit(
    pitch: float, roll: float, max_tilt: float, cpr: float
) -> None:
    """What the position law does (clamp the tilt vector, convert each axis, round) always
    passes the tilt check: the rounding allowance is enough."""
    c = ControlConfig(max_tilt_rad=max_tilt)
    p, r, _ = clamp_norm(pitch, roll, max_tilt)
    cmd = Command(0, angle_to_counts(p, -1, cpr), angle_to_counts(r, -1, cpr), 0, 100)
    assert command_within_limits(cmd, c, counts_per_rad=cpr)
