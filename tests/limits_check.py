"""Every command a flight sent, checked against the limits that flight was configured with.

One implementation for the flight tests (issue 18): the tilt ``hypot(nick, roll)`` within
``control.max_tilt_rad`` in counts at ``mk.counts_per_rad`` (plus the rounding of both
axes, :func:`mkflight.control.limits.tilt_limit_counts`), ``|yaw| <=
control.yaw_max_counts``, ``0 <= gas <= control.gas_max``. A range check of the decoded
signed bytes (``-127 <= v <= 127``) proves nothing: every byte but -128 passes it, a
60-count tilt (twice the configured one) too.

The limits are those of the :class:`~mkflight.config.Config` the flight flew, read from
its ``flight.json`` (:func:`flown_config`), so a test that flies with ``--set`` is held to
what it set.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

from mkflight.config import Config, config_from_dict
from mkflight.control.limits import tilt_limit_counts
from mkflight.logs.flight_json import read_flight_json

Counts = tuple[float, float, float, float]
"""One command's (nick, roll, yaw, gas) in MK counts, as sent."""


def flown_config(folder: Path) -> Config:
    """The config the flight in ``folder`` flew with, from its ``flight.json``."""
    return config_from_dict(read_flight_json(folder).config, source=f"{folder}/flight.json")


def limit_violations(commands: Iterable[Counts], cfg: Config) -> list[str]:
    """What is wrong with each command outside ``cfg``'s limits (empty: all within).

    Each entry names the command's index, its counts and the limit it broke.
    """
    tilt_max = tilt_limit_counts(cfg.control, cfg.mk.counts_per_rad)
    yaw_max, gas_max = cfg.control.yaw_max_counts, cfg.control.gas_max
    problems: list[str] = []
    for i, (nick, roll, yaw, gas) in enumerate(commands):
        tilt = math.hypot(nick, roll)
        if not tilt <= tilt_max:
            problems.append(
                f"#{i}: tilt {tilt:.1f} counts (nick {nick:g}, roll {roll:g}) > {tilt_max:.1f}"
            )
        if not abs(yaw) <= yaw_max:
            problems.append(f"#{i}: |yaw| {abs(yaw):g} counts > {yaw_max}")
        if not 0 <= gas <= gas_max:
            problems.append(f"#{i}: gas {gas:g} counts outside [0, {gas_max}]")
    return problems


def assert_within_limits(commands: Iterable[Counts], cfg: Config) -> None:
    """Fail naming the first few commands outside ``cfg``'s limits (see the module doc)."""
    problems = limit_violations(commands, cfg)
    assert not problems, f"{len(problems)} limit violations: {problems[:5]}"
