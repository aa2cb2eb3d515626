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
from bisect import bisect_left
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
    """The newest DebugOut (t_ns, pitch, roll) samples, :data:`ATTITUDE_HISTORY` of them.

    Samples come in time order (the link's clock), so :meth:`at` finds the nearest by
    bisection; :attr:`_descents` counts neighbours out of order in the window, and while
    there are any, :meth:`at` looks at every sample instead.
    """

    __slots__ = ("_descents", "_samples")

    def __init__(self) -> None:
        self._samples: deque[tuple[int, float, float]] = deque(maxlen=ATTITUDE_HISTORY)
        self._descents = 0  # i with t[i] < t[i - 1] among the kept samples

    def add(self, t_ns: int, pitch_rad: float, roll_rad: float) -> None:
        """Keep one sample's attitude (the oldest is dropped when full)."""
        samples = self._samples
        if len(samples) == ATTITUDE_HISTORY and samples[1][0] < samples[0][0]:
            self._descents -= 1  # the pair the oldest sample leaves with
        if samples and t_ns < samples[-1][0]:
            self._descents += 1
        samples.append((t_ns, pitch_rad, roll_rad))

    def at(self, t_ns: int) -> tuple[float, float]:
        """Pitch and roll of the sample nearest ``t_ns`` (the first of equals; NaN if none)."""
        samples = self._samples
        if not samples:
            return math.nan, math.nan
        if self._descents:
            best = _first_nearest(samples, t_ns)
        else:
            best = samples[_first_nearest_ordered(samples, t_ns)]
        return best[1], best[2]


def _time(sample: tuple[int, float, float]) -> int:
    return sample[0]


def _first_nearest_ordered(samples: deque[tuple[int, float, float]], t_ns: int) -> int:
    """The index of the first sample nearest ``t_ns`` among samples in time order."""
    i = bisect_left(samples, t_ns, key=_time)  # samples[i - 1] < t_ns <= samples[i]
    if i == len(samples) or (i > 0 and t_ns - samples[i - 1][0] <= samples[i][0] - t_ns):
        return bisect_left(samples, samples[i - 1][0], hi=i, key=_time)  # the first of equals
    return i


def _first_nearest(samples: deque[tuple[int, float, float]], t_ns: int) -> tuple[int, float, float]:
    """The first sample nearest ``t_ns``, looking at every one (samples out of order)."""
    best, best_dt = samples[0], abs(samples[0][0] - t_ns)
    for a in samples:  # the first nearest, as min() would (no key call per sample)
        dt = abs(a[0] - t_ns)
        if dt < best_dt:
            best, best_dt = a, dt
    return best
