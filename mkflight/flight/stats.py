"""The daemon's own timing figures: command latency, step period and jitter, CPU (SPEC §9).

Pure bookkeeping, fed by :mod:`mkflight.flight.app`, summarised into ``flight.json``:

* **latency**: DebugOut arrival (the host time its bytes were read) to the ExternControl
  frame written to the port, per step (SPEC §9: median ≤ 1 ms, p99 ≤ 5 ms).
* **step period**: the interval between consecutive DebugOut-driven steps. The FC sends
  every ≈ 53 ms (its 'd' interval of 5 x 10 ms on its own clock), so the jitter is the
  deviation from the flight's median interval (SPEC §9: p99 ≤ 2 ms); an interval longer
  than 1.5 medians is a **missed step**. Each DebugOut re-subscription ('d', every ≤ 2 s)
  makes the FC answer at once and restart its period (mk-serial.md §7.2): the interval
  that contains one is the FC's doing, not the daemon's, and is counted apart
  (``restarted_periods``), not as jitter. The arrival jitter is the FC's and its wire's
  (a DebugOut waits behind a confirm or a compass frame at 57600 baud): what the daemon
  adds to the period of its commands is the change of latency from one step to the next,
  ``added_jitter_p99_ms`` = p99 of |latency(k) - latency(k-1)|.
* **overruns**: steps whose own processing (arrival to the end of the step, logs
  included) took longer than :data:`OVERRUN_S`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from mkflight.conversions import NS_PER_MS, NS_PER_S

OVERRUN_S = 0.010
"""A step that takes longer than this (arrival to done) is an overrun: 1/5 of the period."""
MISSED_FACTOR = 1.5
"""An interval longer than this many median periods means a DebugOut (a step) was missed."""
KEEP = 20_000
"""Samples kept per figure: ~17 minutes of 53 ms steps (a longer flight keeps the newest)."""


class Ring:
    """The newest :data:`KEEP` integer samples in a buffer allocated once.

    A ``deque`` of Python ints allocates an object per step and grows for the first
    17 minutes of a flight; this does neither, so a long run's memory is flat from the start.
    """

    __slots__ = ("_buf", "_n")

    def __init__(self, size: int = KEEP) -> None:
        self._buf: npt.NDArray[np.int64] = np.zeros(size, np.int64)
        self._n = 0  # samples ever appended

    def append(self, value: int) -> None:
        """Keep ``value``, dropping the oldest when full."""
        self._buf[self._n % len(self._buf)] = value
        self._n += 1

    def __len__(self) -> int:
        return min(self._n, len(self._buf))

    def last(self) -> int:
        """The newest sample (IndexError when empty)."""
        if not self._n:
            msg = "empty ring"
            raise IndexError(msg)
        return int(self._buf[(self._n - 1) % len(self._buf)])

    def values(self) -> npt.NDArray[np.int64]:
        """The kept samples, oldest first (a copy)."""
        size = len(self._buf)
        if self._n <= size:
            return self._buf[: self._n].copy()
        head = self._n % size
        return np.concatenate((self._buf[head:], self._buf[:head]))


def percentile(values: list[float], q: float) -> float:
    """The ``q``-th percentile (nearest rank) of ``values``; NaN when empty."""
    if not values:
        return math.nan
    ordered = sorted(values)
    rank = min(len(ordered) - 1, max(0, math.ceil(q / 100.0 * len(ordered)) - 1))
    return ordered[rank]


@dataclass(slots=True)
class StepStats:
    """Per-step timing of one flight (see the module docstring)."""

    latency_ns: Ring = field(default_factory=Ring)
    period_ns: Ring = field(default_factory=Ring)
    busy_ns: Ring = field(default_factory=Ring)
    steps: int = 0
    overruns: int = 0
    delayed_commands: int = 0
    restarted_periods: int = 0
    _last_arrival_ns: int | None = None
    _restart_pending: bool = False

    def on_resubscribe(self) -> None:
        """A 'd' went out: the interval up to the next sample is the FC's restart, not jitter."""
        self._restart_pending = True

    def on_step(self, arrival_ns: int, written_ns: int | None, done_ns: int) -> None:
        """Record one step: its DebugOut arrival, its command's write (None: queued), its end."""
        self.steps += 1
        if self._restart_pending:
            self._restart_pending = False
            self.restarted_periods += 1
        elif self._last_arrival_ns is not None and arrival_ns > self._last_arrival_ns:
            self.period_ns.append(arrival_ns - self._last_arrival_ns)
        self._last_arrival_ns = arrival_ns
        if written_ns is None:
            self.delayed_commands += 1
        else:
            self.latency_ns.append(max(0, written_ns - arrival_ns))
        busy = max(0, done_ns - arrival_ns)
        self.busy_ns.append(busy)
        if busy > OVERRUN_S * NS_PER_S:
            self.overruns += 1

    def last_latency_ms(self) -> float:
        """The newest step's latency (ms), NaN before the first."""
        return self.latency_ns.last() / NS_PER_MS if len(self.latency_ns) else math.nan

    def summary(self) -> dict[str, float | int]:
        """Medians and percentiles in ms, counts; for ``flight.json`` and the benchmarks."""
        lat: list[float] = (self.latency_ns.values() / NS_PER_MS).tolist()
        per: list[float] = (self.period_ns.values() / NS_PER_MS).tolist()
        busy: list[float] = (self.busy_ns.values() / NS_PER_MS).tolist()
        median_period = percentile(per, 50)
        jitter = [abs(p - median_period) for p in per]
        missed = sum(1 for p in per if p > MISSED_FACTOR * median_period)
        added = [abs(b - a) for a, b in itertools.pairwise(lat)]
        return {
            "steps": self.steps,
            "latency_median_ms": round(percentile(lat, 50), 4),
            "latency_p99_ms": round(percentile(lat, 99), 4),
            "latency_max_ms": round(max(lat), 4) if lat else math.nan,
            "period_median_ms": round(median_period, 4),
            "jitter_p99_ms": round(percentile(jitter, 99), 4),
            "added_jitter_p99_ms": round(percentile(added, 99), 4),
            "missed_steps": missed,
            "busy_median_ms": round(percentile(busy, 50), 4),
            "busy_p99_ms": round(percentile(busy, 99), 4),
            "restarted_periods": self.restarted_periods,
            "overruns": self.overruns,
            "delayed_commands": self.delayed_commands,
        }
