"""What the MK step and the laser task hand each other (see :mod:`mkflight.flight.tasks`).

* :class:`LaserInbox` - the scan matcher's results on their way to the MK step, which
  applies them at the start of its next step (so a replay knows exactly where each pose
  entered: the ``scan`` event names the step), with the matcher's counters for
  ``flight.json``;
* :class:`AttitudeHistory` - the newest DebugOut attitudes, from which the laser task
  takes the pitch and roll at a scan's time (the hat's tilt correction, eq 26).
"""

from __future__ import annotations

import math
from collections import deque

from mkflight.flight.laser_pipeline import LaserResult

ATTITUDE_HISTORY = 64  # DebugOut samples kept for the attitude at a scan's time (~3 s)


class LaserInbox:
    """Matcher results waiting for the MK step; how many came, their matcher CPU time."""

    __slots__ = ("_got_ns", "_pending", "matcher_cpu_s", "matches")

    def __init__(self) -> None:
        self._pending: deque[LaserResult] = deque()
        self._got_ns: dict[int, int] = {}  # scan seq -> when its result came back
        #: results the laser task got from the matcher (the pre-flight's not counted)
        self.matches = 0
        #: the matcher's compute time over those results, s
        self.matcher_cpu_s = 0.0

    def put(self, result: LaserResult) -> None:
        """Queue the pre-flight's match (no arrival time, not counted)."""
        self._pending.append(result)

    def put_matched(self, result: LaserResult, got_ns: int) -> None:
        """Queue a result that came back from the matcher at ``got_ns``, and count it."""
        self.matcher_cpu_s += result.compute_s
        self.matches += 1
        self._got_ns[result.seq] = got_ns  # the scan event says when
        self._pending.append(result)

    def peek(self) -> LaserResult | None:
        """The oldest waiting result (None: none waits)."""
        return self._pending[0] if self._pending else None

    def pop(self) -> tuple[LaserResult, int | None]:
        """The oldest waiting result and when it came back (None: the pre-flight's).

        Raises:
            IndexError: nothing waits.
        """
        result = self._pending.popleft()
        return result, self._got_ns.pop(result.seq, None)


class AttitudeHistory:
    """The newest DebugOut (t_ns, pitch, roll) samples, :data:`ATTITUDE_HISTORY` of them."""

    __slots__ = ("_samples",)

    def __init__(self) -> None:
        self._samples: deque[tuple[int, float, float]] = deque(maxlen=ATTITUDE_HISTORY)

    def add(self, t_ns: int, pitch_rad: float, roll_rad: float) -> None:
        """Keep one sample's attitude (the oldest is dropped when full)."""
        self._samples.append((t_ns, pitch_rad, roll_rad))

    def at(self, t_ns: int) -> tuple[float, float]:
        """Pitch and roll of the sample nearest ``t_ns`` (NaN if none)."""
        if not self._samples:
            return math.nan, math.nan
        best, best_dt = self._samples[0], abs(self._samples[0][0] - t_ns)
        for a in self._samples:  # the first nearest, as min() would (no key call per sample)
            dt = abs(a[0] - t_ns)
            if dt < best_dt:
                best, best_dt = a, dt
        return best[1], best[2]
