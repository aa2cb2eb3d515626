"""Angle wrapping (SPEC §1): every heading lives in (-pi, pi]; NaN and inf are not angles."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.frames import TWO_PI, wrap_pi


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        (0.0, 0.0),
        (-0.0, 0.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3 * math.pi, math.pi),
        (-3 * math.pi, math.pi),
        (TWO_PI, 0.0),
        (-TWO_PI, 0.0),
        (math.radians(181), math.radians(-179)),
        (math.radians(359), math.radians(-1)),
        (math.radians(-181), math.radians(179)),
        (math.radians(720 + 90), math.radians(90)),
    ],
)
def test_wrap_pi_examples(angle: float, expected: float) -> None:
    assert wrap_pi(angle) == pytest.approx(expected, abs=1e-12)


def test_wrap_pi_minus_pi_is_plus_pi_exactly() -> None:
    assert wrap_pi(-math.pi) == math.pi
    assert wrap_pi(math.pi) == math.pi


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_wrap_pi_range(angle: float) -> None:
    wrapped = wrap_pi(angle)
    assert -math.pi < wrapped <= math.pi


@given(st.floats(-1e6, 1e6))
def test_wrap_pi_same_direction(angle: float) -> None:
    wrapped = wrap_pi(angle)
    assert math.cos(wrapped) == pytest.approx(math.cos(angle), abs=1e-9)
    assert math.sin(wrapped) == pytest.approx(math.sin(angle), abs=1e-9)
    turns = (angle - wrapped) / TWO_PI
    assert abs(turns - round(turns)) < 1e-9


@given(st.floats(-math.pi, math.pi).filter(lambda a: a > -math.pi))
def test_wrap_pi_keeps_angles_in_range(angle: float) -> None:
    assert wrap_pi(angle) == angle


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_wrap_pi_idempotent(angle: float) -> None:
    once = wrap_pi(angle)
    assert wrap_pi(once) == once


@given(st.sampled_from([math.nan, math.inf, -math.inf, -math.nan]))
def test_wrap_pi_non_finite_is_nan(angle: float) -> None:
    assert math.isnan(wrap_pi(angle))
