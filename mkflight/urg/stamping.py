"""Scan records from MD replies: ranges in metres, stamped with the host time of the front.

Each scan's 24-bit sensor timestamp (step 0) is unwrapped and mapped to the host clock by
:class:`~mkflight.urg.timesync.SensorClock` (offset + drift), and the scan is stamped with
the host time at which its front step (AFRT) was measured, not the time it arrived (~70 ms
later for a full scan, plus USB). Values outside [DMIN, DMAX] (error codes) become NaN,
never a distance. Pure: the driver hands in the reply, its arrival time and the sensor's
parameters.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from mkflight.conversions import MM_PER_M, NS_PER_S
from mkflight.msgs import Scan
from mkflight.urg.replies import ScanReply
from mkflight.urg.timesync import SensorClock
from mkflight.urg.units import SensorParams, TimestampUnwrapper

__all__ = ["ScanStamper", "range_table_m"]


FloatArray = npt.NDArray[np.float64]


def range_table_m(dmin_mm: int, dmax_mm: int) -> FloatArray:
    """Metres for every raw value 0..DMAX+1: ``v / 1000`` within [DMIN, DMAX], else NaN (§5).

    Indexed by the values clipped to DMAX+1, it converts a whole scan in one ``take``; each
    entry is the same float64 division a value-by-value conversion makes.
    """
    mm = np.arange(dmax_mm + 2, dtype=np.float64)
    return np.where((mm >= dmin_mm) & (mm <= dmax_mm), mm / MM_PER_M, np.nan)


class ScanStamper:
    """Turns the scans of one sensor into :class:`~mkflight.msgs.Scan` records."""

    def __init__(self, transport_delay_s: float) -> None:
        """Stamp with the fixed USB latency ``transport_delay_s`` (s, configured)."""
        self._transport_delay_s = transport_delay_s
        self._unwrap = TimestampUnwrapper()
        self._sensor_clock = SensorClock()
        self._table_limits: tuple[int, int] | None = None
        self._table: FloatArray = np.empty(0)

    def _ranges_m(self, reply: ScanReply, params: SensorParams) -> FloatArray:
        """The reply's values in metres, NaN outside [DMIN, DMAX] (one table lookup)."""
        limits = (params.dmin_mm, params.dmax_mm)
        if limits != self._table_limits:
            self._table, self._table_limits = range_table_m(*limits), limits
        # clipped to the table's last entry (DMAX+1: NaN) in the same call
        return self._table.take(reply.values_mm, mode="clip")

    def reset(self) -> None:
        """Forget the timer's history: the sensor's timer was reset (RS)."""
        self._unwrap.reset()
        self._sensor_clock.reset()

    def stamp(self, reply: ScanReply, t_ns: int, params: SensorParams, seq: int) -> Scan:
        """The record of ``reply``, which arrived at host time ``t_ns``; ``seq`` numbers it."""
        p = params
        sensor_ms = self._unwrap.unwrap(reply.timestamp_ms)
        # The message leaves after its end step was measured (§3.3), then crosses USB: a
        # constant delay no data can reveal (it is indistinguishable from the offset), so
        # it is configured; the varying rest is what the envelope removes.
        known_ns = p.step_offset_ns(reply.end_step) + int(self._transport_delay_s * NS_PER_S)
        self._sensor_clock.observe(sensor_ms, t_ns, known_ns)
        front_ns = self._sensor_clock.to_host_ns(sensor_ms) + p.step_offset_ns(p.afront_step)
        ranges = self._ranges_m(reply, p)
        return Scan(t_ns=front_ns, ranges_m=ranges, first_step=reply.start_step, seq=seq)
