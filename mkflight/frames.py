"""Frames and angles (SPEC §1): FRD body, world fixed at the first scan, psi clockwise.

Only what the link needs lives here so far; the world<->body rotations and the
level-frame acceleration join it with the estimator.
"""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to (-pi, pi]; NaN and inf stay NaN (they are invalid, not angles)."""
    if not math.isfinite(angle_rad):
        return math.nan
    wrapped = math.remainder(angle_rad, TWO_PI)
    return math.pi if wrapped <= -math.pi else wrapped
