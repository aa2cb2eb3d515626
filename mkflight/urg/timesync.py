"""Mapping the URG's millisecond timer to the host clock: offset and drift (SPEC §2).

Each scan carries the sensor time of its step 0 (``scip2.md`` §3.3); it reaches the host
after the end step was measured, then the USB transfer, then the host's own scheduling,
so ``host_arrival - sensor_time`` is the offset plus a delay that is never negative and
often large. The *smallest* such difference is the best evidence of the offset: this is
the passive synchronisation of E. Olson, "A passive solution to the sensor
synchronization problem" (IROS 2010). Between good samples the clocks drift apart, so the
retained minimum is allowed to rise at the largest plausible drift rate; the drift itself
is estimated from the slope of the minima over a long window, which turns the envelope
into a straight line through the best samples.

``to_host_ns`` then gives, for a sensor time, the host time at which it *happened*: the
scan's data arrive ~100 ms after its step 0, but each scan is stamped with when it was
taken.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from mkflight.conversions import NS_PER_MS


@dataclass(frozen=True, slots=True)
class SyncSettings:
    """Bounds of the estimator (crystal oscillators drift by tens of ppm)."""

    max_drift_ppm: float = 200.0
    bin_ms: int = 1000  # one envelope point per bin: its smallest delay
    window_bins: int = 120  # the drift fit uses the last two minutes
    min_bins_for_drift: int = 10


class SensorClock:
    """Online estimate of host time as a function of (unwrapped) sensor milliseconds."""

    def __init__(self, settings: SyncSettings | None = None) -> None:
        self._s = settings or SyncSettings()
        self._offset_ns: float | None = None  # host - sensor at _ref_sensor_ms
        self._ref_sensor_ms = 0.0
        self._drift = 0.0  # host seconds per sensor second, minus 1
        self._bins: deque[tuple[float, float]] = deque(maxlen=self._s.window_bins)
        self._bin_index: int | None = None
        self._bin_best: tuple[float, float] | None = None
        self.samples = 0

    @property
    def synced(self) -> bool:
        """True once at least one observation was made."""
        return self._offset_ns is not None

    @property
    def drift_ppm(self) -> float:
        """The current drift estimate, host relative to sensor, in ppm."""
        return self._drift * 1e6

    def reset(self) -> None:
        """Forget everything (the sensor timer was reset with ``RS``)."""
        self.__init__(self._s)  # type: ignore[misc]

    def observe(self, sensor_ms: float, host_ns: int, min_delay_ns: int = 0) -> None:
        """Add one observation: the event at ``sensor_ms`` was seen on the host at ``host_ns``.

        ``min_delay_ns`` is the part of the delay known for certain (e.g. the time from
        step 0 to the scan's end step), removed before the envelope is taken.
        """
        self.samples += 1
        host = float(host_ns - min_delay_ns)
        p = host - sensor_ms * NS_PER_MS  # offset + unknown delay >= 0
        if self._offset_ns is None:
            self._offset_ns, self._ref_sensor_ms = p, sensor_ms
        else:
            # Olson: the estimate falls to any smaller delay at once, and rises no faster
            # than the largest drift the clocks can have.
            elapsed_ns = abs(sensor_ms - self._ref_sensor_ms) * NS_PER_MS
            slack = elapsed_ns * self._s.max_drift_ppm * 1e-6
            self._offset_ns = min(p, self._offset_at(sensor_ms) + slack)
            self._ref_sensor_ms = sensor_ms
        self._update_drift(sensor_ms, p)

    def _offset_at(self, sensor_ms: float) -> float:
        assert self._offset_ns is not None
        return self._offset_ns + self._drift * (sensor_ms - self._ref_sensor_ms) * NS_PER_MS

    def _update_drift(self, sensor_ms: float, p: float) -> None:
        index = int(sensor_ms // self._s.bin_ms)
        if self._bin_index is None or index != self._bin_index:
            if self._bin_best is not None:
                self._bins.append(self._bin_best)
                self._fit_drift()
            self._bin_index, self._bin_best = index, (sensor_ms, p)
        elif self._bin_best is not None and p < self._bin_best[1]:
            self._bin_best = (sensor_ms, p)

    def _fit_drift(self) -> None:
        if len(self._bins) < self._s.min_bins_for_drift:
            return
        n = len(self._bins)
        xs = [b[0] * NS_PER_MS for b in self._bins]
        ys = [b[1] for b in self._bins]
        mx, my = sum(xs) / n, sum(ys) / n
        sxx = sum((x - mx) ** 2 for x in xs)
        if sxx <= 0:
            return
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
        limit = self._s.max_drift_ppm * 1e-6
        self._drift = max(-limit, min(limit, slope))

    def to_host_ns(self, sensor_ms: float) -> int:
        """The host time at which sensor time ``sensor_ms`` happened.

        Raises:
            RuntimeError: before the first observation.
        """
        if self._offset_ns is None:
            msg = "sensor clock not synchronised yet"
            raise RuntimeError(msg)
        return round(sensor_ms * NS_PER_MS + self._offset_at(sensor_ms))
