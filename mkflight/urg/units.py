"""URG parameters (PP) and the pure conversions the driver needs: mm -> m, step -> angle, time.

- :func:`parse_params` turns a PP reply into :class:`SensorParams`, requiring the seven
  numeric keys (``protocols/scip2.md`` §3, §5) so nothing is hard-coded.
- :func:`ranges_m`: every value < DMIN (an error code) or > DMAX is NaN, never a distance
  (§5, SPEC §2).
- :func:`step_body_angle_rad`: the sensor counts angles counter-clockwise from above, our
  yaw is clockwise (SPEC §1), so step s lies at ``-(s - AFRT) * 2*pi / ARES`` in the body
  frame: positive to the right.
- :func:`unwrap_timestamp_ms`: the 24-bit millisecond timer wraps every 4.66 h (§3.3).

Pure Python on purpose: the driver converts to numpy where it needs arrays.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

from mkflight.conversions import MM_PER_M
from mkflight.errors import ProtocolError
from mkflight.urg.codec import TIMESTAMP_MODULUS_MS

PP_KEYS: Final = ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")
_NS_PER_MIN: Final = 60_000_000_000
_HALF_WRAP_MS: Final = TIMESTAMP_MODULUS_MS // 2


@dataclass(frozen=True, slots=True)
class SensorParams:
    """The PP parameters (§5): ranges in mm, steps, the motor speed in rpm."""

    dmin_mm: int
    dmax_mm: int
    ares_steps: int
    amin_step: int
    amax_step: int
    afront_step: int
    scan_rpm: int
    model: str = ""

    @property
    def step_angle_rad(self) -> float:
        """Angle between neighbouring steps: 2*pi / ARES (0.0061359 rad on a URG-04LX)."""
        return 2.0 * math.pi / self.ares_steps

    @property
    def scan_period_ns(self) -> int:
        """Time of one turn of the mirror: 60 s / SCAN (100 ms at 600 rpm)."""
        return _NS_PER_MIN // self.scan_rpm

    def step_offset_ns(self, step: float) -> int:
        """When ``step`` is measured after the scan's timestamp (step 0), §3.3.

        97.65625 us a step at 600 rpm and 1024 steps; 70.8 ms for step 725.
        """
        return round(step * self.scan_period_ns / self.ares_steps)


URG_04LX: Final = SensorParams(
    dmin_mm=20,
    dmax_mm=5600,
    ares_steps=1024,
    amin_step=44,
    amax_step=725,
    afront_step=384,
    scan_rpm=600,
    model="URG-04LX(Hokuyo Automatic Co.,Ltd.)",
)


def parse_params(info: Mapping[str, str]) -> SensorParams:
    """Build :class:`SensorParams` from a PP reply's info lines (§3: all seven required).

    Raises:
        ProtocolError: a key is missing, not an integer, or the values contradict each
            other (DMIN >= DMAX, AFRT outside AMIN..AMAX, ARES or SCAN not positive).
    """
    numbers: dict[str, int] = {}
    for key in PP_KEYS:
        if key not in info:
            msg = f"PP reply lacks {key} (has {', '.join(sorted(info)) or 'nothing'})"
            raise ProtocolError(msg)
        try:
            numbers[key] = int(info[key].strip())
        except ValueError as err:
            msg = f"PP {key} = {info[key]!r} is not an integer"
            raise ProtocolError(msg) from err
    params = SensorParams(
        dmin_mm=numbers["DMIN"],
        dmax_mm=numbers["DMAX"],
        ares_steps=numbers["ARES"],
        amin_step=numbers["AMIN"],
        amax_step=numbers["AMAX"],
        afront_step=numbers["AFRT"],
        scan_rpm=numbers["SCAN"],
        model=info.get("MODL", ""),
    )
    if params.ares_steps <= 0 or params.scan_rpm <= 0:
        msg = f"PP ARES = {params.ares_steps} and SCAN = {params.scan_rpm} must be positive"
        raise ProtocolError(msg)
    if not 0 <= params.dmin_mm < params.dmax_mm:
        msg = f"PP DMIN = {params.dmin_mm} is not below DMAX = {params.dmax_mm}"
        raise ProtocolError(msg)
    if not 0 <= params.amin_step <= params.afront_step <= params.amax_step:
        msg = (
            f"PP AFRT = {params.afront_step} outside AMIN..AMAX = "
            f"{params.amin_step}..{params.amax_step}"
        )
        raise ProtocolError(msg)
    return params


def ranges_m(values: Sequence[int], params: SensorParams = URG_04LX) -> list[float]:
    """Raw values (mm) to ranges in metres; < DMIN (error codes) and > DMAX are NaN (§5)."""
    low, high, nan = params.dmin_mm, params.dmax_mm, math.nan
    return [v / MM_PER_M if low <= v <= high else nan for v in values]


def step_body_angle_rad(step: float, params: SensorParams = URG_04LX) -> float:
    """Body-frame angle of ``step``: ``-(step - AFRT) * 2*pi / ARES``, positive to the right.

    The sensor's angle is counter-clockwise positive seen from above (§5), our yaw
    clockwise (SPEC §1-2), hence the sign: step 44 -> +2.086 rad, step 725 -> -2.092 rad.
    ``step`` may be fractional (the centre of a cluster, :func:`value_steps`).
    """
    return -(step - params.afront_step) * 2.0 * math.pi / params.ares_steps


def value_steps(start_step: int, end_step: int, cluster: int) -> list[float]:
    """The step each value of a scan stands for: the centre of its group (§3.1, §5).

    With cluster c > 1, value j covers steps ``start + j*c ... start + j*c + c - 1`` (the
    last group may be shorter, then its own centre is used); mkflight gives it the
    centre. With cluster 0 or 1 the result is simply ``start..end``.
    """
    group = max(cluster, 1)
    out: list[float] = []
    for first in range(start_step, end_step + 1, group):
        last = min(first + group - 1, end_step)
        out.append((first + last) / 2.0)
    return out


def unwrap_timestamp_ms(stamp_ms: int, previous_ms: int | None) -> int:
    """Extend a 24-bit sensor timestamp to an unbounded ms count (§3.3).

    Picks ``stamp_ms + k * 2**24`` nearest to ``previous_ms`` (an earlier unwrapped
    value), so both a wrap and a slightly older stamp arriving late come out right.
    ``previous_ms`` None (the first stamp, or after ``RS`` reset the timer) gives
    ``stamp_ms`` itself.
    """
    if previous_ms is None:
        return stamp_ms
    delta = (stamp_ms - previous_ms + _HALF_WRAP_MS) % TIMESTAMP_MODULUS_MS - _HALF_WRAP_MS
    return previous_ms + delta


class TimestampUnwrapper:
    """Remembers the last unwrapped stamp; call :meth:`reset` after ``RS`` (§3.3)."""

    def __init__(self) -> None:
        self.last_ms: int | None = None
        self.wraps = 0

    def unwrap(self, stamp_ms: int) -> int:
        """The unwrapped value of ``stamp_ms`` (see :func:`unwrap_timestamp_ms`)."""
        value = unwrap_timestamp_ms(stamp_ms, self.last_ms)
        self.wraps = value // TIMESTAMP_MODULUS_MS
        if self.last_ms is None or value > self.last_ms:
            self.last_ms = value
        return value

    def reset(self) -> None:
        """Forget the history: the next stamp starts a new count (the timer was reset)."""
        self.last_ms = None
        self.wraps = 0
