"""``mkflight flight-time``: eq 27 (seed §L), ideal and derated, and thrust per motor."""

from __future__ import annotations

import json

from mkflight.analysis.flight_time import MOTORS, flight_time
from mkflight.conversions import MIN_PER_H
from mkflight.errors import ConfigError


def cmd_flight_time(
    *,
    capacity_ah: float,
    current_a: float,
    usable: float,
    mass_g: float | None,
    extra_current_a: float,
    as_json: bool,
) -> int:
    """Print the flight time ``t = B / C`` (eq 27) for a battery and a current draw.

    Args:
        capacity_ah: battery capacity B, Ah.
        current_a: motors' total current, A.
        usable: derating factor in (0, 1] (seed: 0.9).
        mass_g: take-off mass for the thrust per motor, g, or None.
        extra_current_a: other electronics' current, A, added to C.
        as_json: print one object with exactly ``ideal_min``, ``derated_min`` and
            ``thrust_per_motor_g`` (null without a mass).

    Raises:
        ConfigError: a value out of range (the CLI checks them first; exit 2).
    """
    try:
        result = flight_time(
            capacity_ah=capacity_ah,
            current_a=current_a,
            usable=usable,
            extra_current_a=extra_current_a,
            mass_g=mass_g,
        )
    except ValueError as err:
        raise ConfigError(str(err)) from err
    if as_json:
        print(
            json.dumps(
                {
                    "ideal_min": result.ideal_min,
                    "derated_min": result.derated_min,
                    "thrust_per_motor_g": result.thrust_per_motor_g,
                }
            )
        )
        return 0
    extra = f" + {extra_current_a:g} A extra" if extra_current_a > 0 else ""
    print(
        f"battery {capacity_ah:g} Ah, current {current_a:g} A{extra} = "
        f"{result.total_current_a:g} A  (seed §L, eq 27: t = B / C)"
    )
    print(f"ideal    {result.ideal_min:6.2f} min  ({result.ideal_min / MIN_PER_H:.3f} h)")
    print(f"derated  {result.derated_min:6.2f} min  (x {usable:g} usable)")
    if result.thrust_per_motor_g is not None:
        print(
            f"thrust per motor {result.thrust_per_motor_g:g} g  "
            f"({mass_g:g} g / {MOTORS} motors, to hover)"
        )
    return 0
