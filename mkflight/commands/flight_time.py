"""``mkflight flight-time``: eq 27 (§L), ideal and derated, and thrust per motor."""

from __future__ import annotations

import json

from mkflight import cli_types
from mkflight.analysis.flight_time import MOTORS, flight_time
from mkflight.commands.args import DOCUMENT, Command, Subparsers, add_json
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
        usable: derating factor in (0, 1] (§L: 0.9).
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
        f"{result.total_current_a:g} A  (§L, eq 27: t = B / C)"
    )
    print(f"ideal    {result.ideal_min:6.2f} min  ({result.ideal_min / MIN_PER_H:.3f} h)")
    print(f"derated  {result.derated_min:6.2f} min  (x {usable:g} usable)")
    if result.thrust_per_motor_g is not None:
        print(
            f"thrust per motor {result.thrust_per_motor_g:g} g  "
            f"({mass_g:g} g / {MOTORS} motors, to hover)"
        )
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``flight-time``."""
    flight = subparsers.add_parser(
        "flight-time",
        help="flight time from battery capacity and current (eq 27)",
        description=f"t = B / C (eq 27, §L of {DOCUMENT}): the ideal time, the time "
        "derated by --usable, and the thrust each of the 4 motors gives to hover --mass-g.",
    )
    flight.add_argument(
        "--capacity-ah",
        type=cli_types.positive,
        required=True,
        metavar="C",
        help="battery capacity, Ah",
    )
    flight.add_argument(
        "--current-a",
        type=cli_types.positive,
        required=True,
        metavar="I",
        help="motors' current, A",
    )
    flight.add_argument(
        "--usable",
        type=cli_types.fraction,
        default=0.9,
        metavar="F",
        help="derating factor in (0, 1] (default 0.9, as in §L)",
    )
    flight.add_argument(
        "--extra-current-a",
        type=cli_types.non_negative,
        default=0.0,
        metavar="A",
        help="other electronics' current, added to I (§L: 0.5)",
    )
    flight.add_argument(
        "--mass-g", type=cli_types.positive, metavar="M", help="take-off mass, g: thrust per motor"
    )
    add_json(flight)
    flight.set_defaults(func=Command(cmd_flight_time))
