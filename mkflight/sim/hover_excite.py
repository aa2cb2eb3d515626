"""The set-point excitation of ``sim hover --excite`` (the input ``analyze latency`` needs)."""

from __future__ import annotations

import numpy as np

from mkflight.conversions import NS_PER_S


class Excitation:
    """A random square wave per axis: ±amplitude, each level held 1.5-3 s (uniform, seeded).

    Random dwell times make the commands broadband enough for a clean cross-correlation
    (a fixed period would give a periodic curve with several equal peaks).
    """

    MIN_DWELL_S = 1.5
    MAX_DWELL_S = 3.0

    def __init__(self, amplitude_m: float, rng: np.random.Generator) -> None:
        self.amplitude_m = amplitude_m
        self._rng = rng
        self._level = [1.0, -1.0]
        self._next_ns: list[int] | None = None

    def _dwell_ns(self) -> int:
        return int(self._rng.uniform(self.MIN_DWELL_S, self.MAX_DWELL_S) * NS_PER_S)

    def offset_m(self, t_ns: int) -> tuple[float, float]:
        """The (dx, dy) offset at ``t_ns`` (times must not go back)."""
        if self._next_ns is None:
            self._next_ns = [t_ns + self._dwell_ns(), t_ns + self._dwell_ns()]
        for axis in (0, 1):
            while t_ns >= self._next_ns[axis]:
                self._level[axis] = -self._level[axis]
                self._next_ns[axis] += self._dwell_ns()
        return self.amplitude_m * self._level[0], self.amplitude_m * self._level[1]
