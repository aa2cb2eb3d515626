"""The step event's remembered rounding is ``round`` itself, value for value and sign for sign."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.flight import flight_logs
from mkflight.flight.flight_logs import Rounder


def _same(a: float, b: float) -> bool:
    """Equal as the event's JSON would write them: the value, the sign of zero, NaN."""
    return (math.isnan(a) and math.isnan(b)) or (
        a == b and math.copysign(1, a) == math.copysign(1, b)
    )


@given(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=50), st.sampled_from([2, 4])
)
def test_a_rounder_gives_rounds_numbers_the_first_time_and_every_time(
    values: list[float], ndigits: int
) -> None:
    rounder = Rounder(ndigits)
    for value in values + values[::-1]:  # the second time from its memory
        assert _same(rounder(value), round(value, ndigits))


def test_zeros_of_either_sign_and_nan_are_never_taken_from_memory() -> None:
    rounder = Rounder(4)
    for value in (-0.0, 0.0, -0.0, 0.00001, -0.00001, 0.00001, -0.00001, math.nan, math.nan):
        assert _same(rounder(value), round(value, 4))
    assert math.copysign(1, rounder(-0.00001)) == -1.0  # -0.0, as round gives it


def test_memory_starts_again_when_full(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(flight_logs, "ROUNDED_MEMO_SIZE", 8)
    rounder = Rounder(2)
    for i in range(100):
        value = 11.1 + i * 0.0037
        assert rounder(value) == round(value, 2)
        assert rounder(value) == round(value, 2)
