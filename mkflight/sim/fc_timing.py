"""When the FC's DebugOut really leaves: its main loop's jitter and the odd late frame.

A FlightCtrl sends a subscribed DebugOut from its main loop once the period's timer has
run out (``mk-serial.md`` §7.2): 50 ticks plus the 2-tick overshoot of its delay
function, 52 ticks of 1.024 ms. A real FC's loop also does other work (the attitude
loop, the RC decoder, the compass), so a frame may leave a few ticks later than due, and
now and then, when a slow branch runs, 5-25 ms late. The timer restarts when the frame
is sent, so a late frame delays every later one too (the mean interval grows).

:class:`DebugJitter` draws that extra delay per frame for an airframe
(``VehicleParams.debug_jitter_ticks`` and ``debug_late_fraction``, SPEC §8): uniform
``0..debug_jitter_ticks`` ticks, plus, with probability ``debug_late_fraction``, 5-25 ms.
It is pure and seeded: the same seed gives the same sequence, and with both parameters
zero it draws nothing (the exact 52-tick period). The FC model (:mod:`mkflight.sim.fc`)
and the lock-step ``sim hover`` (:mod:`mkflight.sim.hover`) both use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from mkflight.conversions import NS_PER_S

TICK_NS: Final = 1_024_000  # one FC tick, 20 MHz / 8 / 256 / 10 (mk-serial.md §7.1)
LATE_MIN_S: Final = 0.005  # a late DebugOut leaves this much ...
LATE_MAX_S: Final = 0.025  # ... to this much later than due (uniform)


@dataclass(frozen=True, slots=True)
class DebugTiming:
    """An airframe's DebugOut irregularity (``VehicleParams``'s two fields) and its seed."""

    jitter_ticks: int = 0  # each DebugOut leaves 0..this many ticks late (uniform)
    late_fraction: float = 0.0  # this share of DebugOuts leaves 5-25 ms late
    seed: int = 0

    @property
    def exact(self) -> bool:
        """No jitter and no late frames: the FC's exact period."""
        return self.jitter_ticks <= 0 and self.late_fraction <= 0.0


class DebugJitter:
    """The extra ticks of each DebugOut, drawn in order from :class:`DebugTiming` (seeded)."""

    def __init__(self, timing: DebugTiming) -> None:
        """Seed the draws with ``timing.seed`` (nothing is drawn for an exact timing)."""
        self.timing = timing
        self._rng = np.random.default_rng([timing.seed, 52])
        self.frames = 0  # frames timed so far
        self.late_frames = 0  # of which 5-25 ms late

    def extra_ticks(self) -> int:
        """How many ticks after its due tick the next DebugOut leaves (>= 0)."""
        self.frames += 1
        t = self.timing
        if t.exact:
            return 0
        extra = int(self._rng.integers(0, t.jitter_ticks + 1)) if t.jitter_ticks > 0 else 0
        if t.late_fraction > 0.0 and self._rng.random() < t.late_fraction:
            self.late_frames += 1
            late_ns = self._rng.uniform(LATE_MIN_S, LATE_MAX_S) * NS_PER_S
            extra += round(late_ns / TICK_NS)
        return extra


__all__ = ["LATE_MAX_S", "LATE_MIN_S", "TICK_NS", "DebugJitter", "DebugTiming"]
