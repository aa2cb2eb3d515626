"""Eq 27 (seed §L): the seed's flight-time numbers."""

from __future__ import annotations

import math

import pytest

from mkflight.analysis.flight_time import DEFAULT_USABLE_FRACTION, flight_time


def test_seed_ideal_and_derated() -> None:
    """2.2 Ah at 6.8 A: 0.323 h = 19.4 min ideal; x 0.9: 17.47 min (the seed prints 17.4)."""
    result = flight_time(capacity_ah=2.2, current_a=6.8)
    assert DEFAULT_USABLE_FRACTION == 0.9
    assert round(result.ideal_min, 1) == 19.4
    assert round(result.ideal_min / 60, 3) == 0.324  # the seed truncates to 0.323 h
    assert round(result.derated_min, 2) == 17.47
    assert result.thrust_per_motor_g is None


def test_seed_with_the_electronics() -> None:
    """0.9 x 2.2 / (6.8 + 0.5) h = 16.27 min.

    The seed prints 16.28 (0.9 x 2.2 / 7.3 x 60 = 16.2740, so 16.27 to two decimals).
    """
    result = flight_time(capacity_ah=2.2, current_a=6.8, usable=0.9, extra_current_a=0.5)
    assert result.total_current_a == pytest.approx(7.3)
    assert round(result.derated_min, 2) == 16.27


def test_seed_thrust_per_motor() -> None:
    """1040 g on four motors: 260 g each."""
    result = flight_time(capacity_ah=2.2, current_a=6.8, mass_g=1040)
    assert result.thrust_per_motor_g == 260


def test_usable_one_is_ideal() -> None:
    result = flight_time(capacity_ah=5.0, current_a=10.0, usable=1.0)
    assert result.ideal_min == result.derated_min == 30.0


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"capacity_ah": 0.0}, "capacity_ah"),
        ({"capacity_ah": math.nan}, "capacity_ah"),
        ({"current_a": -1.0}, "current_a"),
        ({"current_a": math.inf}, "current_a"),
        ({"usable": 0.0}, "usable"),
        ({"usable": 1.01}, "usable"),
        ({"extra_current_a": -0.1}, "extra_current_a"),
        ({"mass_g": 0.0}, "mass_g"),
    ],
)
def test_bad_values_name_the_argument(kwargs: dict[str, float], name: str) -> None:
    args: dict[str, float] = {"capacity_ah": 2.2, "current_a": 6.8, **kwargs}
    with pytest.raises(ValueError, match=rf"^{name} must"):
        flight_time(**args)
