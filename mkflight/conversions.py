"""Unit conversion factors: the one home of every time and length scale factor.

Every ``t_ns`` in mkflight is integer nanoseconds, so the time factors are integers: an
integer divided by one (``t_ns / NS_PER_S``) is a true division, and multiples of them
(``86_400 * NS_PER_S``) stay exact. :data:`S_PER_NS` is the one float factor, for code
that multiplies (``dt_ns * S_PER_NS``): a multiplication by ``1e-9`` rounds differently
from a division by ``10**9``, so a call site that multiplies keeps multiplying.

These are conversions between units only. Physical constants that are parameters of a
model (gravity, the MK's and the URG's calibration) live in the configuration
(:mod:`mkflight.config`) or with the device they describe (:mod:`mkflight.mk.units`,
:mod:`mkflight.urg.units`).
"""

from __future__ import annotations

from typing import Final

NS_PER_S: Final = 1_000_000_000
NS_PER_MS: Final = 1_000_000
NS_PER_US: Final = 1_000
US_PER_S: Final = 1_000_000
MS_PER_S: Final = 1_000
S_PER_NS: Final = 1e-9
"""For multiplications only (``dt_ns * S_PER_NS``); divide by :data:`NS_PER_S` otherwise."""
S_PER_MIN: Final = 60
S_PER_H: Final = 3_600
MIN_PER_H: Final = 60
MM_PER_M: Final = 1_000
