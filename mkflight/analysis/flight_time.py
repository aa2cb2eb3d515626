"""Flight time from battery capacity and current (§L, eq 27: t = B / C).

§L and eq 27 are those of the 2011 QUT CyPhy MikroKopter documentation. Its numbers: a 2.2
Ah LiPo and 4 motors at ≈ 1.7 A (6.8 A) give 19.4 minutes, the ideal limit; x 0.9 for the
losses (voltage sag, turbulence, regulation, cables) gives 17.47 minutes; the onboard
computer and laser draw < 0.5 A more, so 0.9 x 2.2 / 7.3 h = 16.27 minutes (§L prints
16.28). A 1040 g vehicle needs 260 g of thrust per motor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mkflight.conversions import MIN_PER_H

DEFAULT_USABLE_FRACTION = 0.9
"""The original system's empirical derating factor (§L)."""

MOTORS = 4


@dataclass(frozen=True, slots=True)
class FlightTime:
    """The result of eq 27.

    Attributes:
        total_current_a: motors' current plus the extra electronics' current, A.
        ideal_min: ``capacity_ah / total_current_a`` in minutes (the absolute limit).
        derated_min: ``ideal_min x usable``.
        thrust_per_motor_g: hover thrust each motor must give (mass / 4), or None if no
            mass was given.
    """

    total_current_a: float
    ideal_min: float
    derated_min: float
    thrust_per_motor_g: float | None


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        msg = f"{name} must be a finite number > 0, got {value!r}"
        raise ValueError(msg)


def flight_time(
    *,
    capacity_ah: float,
    current_a: float,
    usable: float = DEFAULT_USABLE_FRACTION,
    extra_current_a: float = 0.0,
    mass_g: float | None = None,
) -> FlightTime:
    """Eq 27, ``t = B / C``, ideal and derated, and the per-motor thrust for a mass.

    Args:
        capacity_ah: battery capacity B, Ah (§L: 2.2).
        current_a: total motor current, A (§L: 4 x 1.7 = 6.8).
        usable: derating factor in (0, 1] (§L: 0.9).
        extra_current_a: current of the other electronics, A, added to C (§L: 0.5).
        mass_g: take-off mass, g (§L: 1040 → 260 g per motor).

    Returns:
        The ideal and derated times in minutes and the thrust per motor in grams.

    Raises:
        ValueError: a non-finite or non-positive value, ``usable`` outside (0, 1] or a
            negative ``extra_current_a``; the message names the argument.
    """
    _check_positive("capacity_ah", capacity_ah)
    _check_positive("current_a", current_a)
    _check_positive("usable", usable)
    if usable > 1:
        msg = f"usable must be in (0, 1], got {usable!r}"
        raise ValueError(msg)
    if not (math.isfinite(extra_current_a) and extra_current_a >= 0):
        msg = f"extra_current_a must be a finite number >= 0, got {extra_current_a!r}"
        raise ValueError(msg)
    if mass_g is not None:
        _check_positive("mass_g", mass_g)
    total_a = current_a + extra_current_a
    ideal_min = capacity_ah / total_a * MIN_PER_H
    return FlightTime(
        total_current_a=total_a,
        ideal_min=ideal_min,
        derated_min=ideal_min * usable,
        thrust_per_motor_g=None if mass_g is None else mass_g / MOTORS,
    )
