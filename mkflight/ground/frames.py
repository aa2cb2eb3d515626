"""Turns and times as the ground side's messages carry them: pure, no viewer library.

A quaternion is ``(x, y, z, w)`` of the Z-Y-X turn ``q_z(ψ) q_y(θ) q_x(φ)`` in SPEC §1's FRD
frames (yaw ψ clockwise seen from above, pitch θ nose up, roll φ right side down). ``map`` is
W turned z up: a half turn about x. The live view and the MCAP export both use these, so a
layout made on one reads the other.
"""

from __future__ import annotations

import math
from typing import Final

from mkflight.conversions import NS_PER_S

Quaternion = tuple[float, float, float, float]

MAP_TO_WORLD: Final[Quaternion] = (1.0, 0.0, 0.0, 0.0)
"""``map`` -> ``world``: a half turn about x, as (x, y, z, w)."""


def quaternion(yaw_rad: float = 0.0, pitch_rad: float = 0.0, roll_rad: float = 0.0) -> Quaternion:
    """``q_z(ψ) q_y(θ) q_x(φ)`` as (x, y, z, w)."""
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def sec_nsec(t_ns: int) -> tuple[int, int]:
    """``(sec, nsec)`` of a time in ns, nsec in [0, 1e9) (also for a time before 0)."""
    return divmod(int(t_ns), NS_PER_S)
