"""What the daemon measures of its own hover (SPEC §9): CPU in HOLD, the HOLD precision.

Pure bookkeeping fed once per step by the MK step (:mod:`mkflight.flight.mk_step`):

* **CPU in steady hover**: the process's CPU time and the matcher's (the worker reports
  its compute time per scan; the step passes the running total) between the start and
  the end of HOLD, as % of one core;
* **precision estimate**: the std of the estimate minus the set-point (x, y, height) in
  HOLD, from :data:`SETTLE_S` after it began until a stop is requested (as ``sim hover``
  and ``analyze precision`` count). It is the estimate's own view; the simulator's truth
  gives the real one (``analyze precision --truth``). Kept as running sums (Welford), not
  a list of samples: a flight of hours holds a few numbers, and its memory stays flat.
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import dataclass, field

from mkflight.control.controller import Setpoint
from mkflight.control.phases import Phase
from mkflight.conversions import MS_PER_S, NS_PER_S
from mkflight.msgs import Estimate

SETTLE_S = 3.0

_Clocks = tuple[float, float, float]  # process CPU s, wall s, matcher CPU s


@dataclass(slots=True)
class HoldMonitor:
    """CPU and precision over HOLD (see the module docstring)."""

    _cpu_start: _Clocks | None = None
    _cpu_end: _Clocks | None = None
    _t0_ns: int | None = None
    _n: int = 0
    _mean: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    _m2: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    @staticmethod
    def _clocks(matcher_cpu_s: float) -> _Clocks:
        return time.process_time(), time.perf_counter(), matcher_cpu_s

    def on_step(
        self,
        t_ns: int,
        phase: Phase,
        est: Estimate,
        sp: Setpoint | None,
        stopping: bool,
        *,
        matcher_cpu_s: float,
    ) -> None:
        """One step's phase, estimate and set-point; the matcher's CPU time so far, s."""
        if phase is Phase.HOLD and self._cpu_start is None:
            self._cpu_start = self._clocks(matcher_cpu_s)
        elif phase is not Phase.HOLD and self._cpu_start is not None and self._cpu_end is None:
            self._cpu_end = self._clocks(matcher_cpu_s)
        if phase is not Phase.HOLD or sp is None or not est.pose_valid:
            return
        if self._t0_ns is None:
            self._t0_ns = t_ns
        if (t_ns - self._t0_ns) / NS_PER_S >= SETTLE_S and not stopping:
            self._add((est.x_m - sp.x_m, est.y_m - sp.y_m, est.height_m - sp.height_m))

    def _add(self, errors: tuple[float, float, float]) -> None:
        """Welford's update of the per-axis mean and sum of squared deviations."""
        self._n += 1
        for i, e in enumerate(errors):
            delta = e - self._mean[i]
            self._mean[i] += delta / self._n
            self._m2[i] += delta * (e - self._mean[i])

    def cpu_percent(self, matcher_cpu_s: float) -> dict[str, float] | None:
        """Daemon and matcher CPU during HOLD, % of one core (None without a HOLD).

        ``matcher_cpu_s``: the matcher's CPU time so far, for a HOLD that has not ended.
        """
        if self._cpu_start is None:
            return None
        start, end = self._cpu_start, self._cpu_end or self._clocks(matcher_cpu_s)
        wall_s = end[1] - start[1]
        if wall_s <= 0:
            return None
        return {
            "daemon": round(100.0 * (end[0] - start[0]) / wall_s, 2),
            "matcher": round(100.0 * (end[2] - start[2]) / wall_s, 2),
            "hold_s": round(wall_s, 1),
        }

    def precision(self) -> dict[str, float | int] | None:
        """Std of the HOLD errors per axis (None with fewer than two samples)."""
        if self._n < 2:
            return None
        std = [math.sqrt(max(0.0, m2) / self._n) for m2 in self._m2]  # population std
        return {
            "std_x_m": round(std[0], 5),
            "std_y_m": round(std[1], 5),
            "std_z_m": round(std[2], 5),
            "samples": self._n,
        }


@dataclass(slots=True)
class GcWatch:
    """The garbage collector's pauses during the flight (a stop-the-world pause delays a step).

    The daemon freezes everything that exists at READY (``gc.freeze()``: imports, config,
    the pre-flight's objects), so the collections in flight walk only what the flight
    allocates; this records how long they take.
    """

    collections: int = 0
    full_collections: int = 0
    max_pause_ms: float = 0.0
    _t0: float = 0.0

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        pause_ms = (time.perf_counter() - self._t0) * MS_PER_S
        self.collections += 1
        self.full_collections += info.get("generation") == 2
        self.max_pause_ms = max(self.max_pause_ms, pause_ms)

    def install(self) -> None:
        """Start recording (idempotent)."""
        if self._callback not in gc.callbacks:
            gc.callbacks.append(self._callback)

    def uninstall(self) -> None:
        """Stop recording."""
        if self._callback in gc.callbacks:
            gc.callbacks.remove(self._callback)

    def summary(self) -> dict[str, float | int]:
        """Counts and the longest pause, for ``flight.json``."""
        return {
            "collections": self.collections,
            "full_collections": self.full_collections,
            "max_pause_ms": round(self.max_pause_ms, 3),
        }
