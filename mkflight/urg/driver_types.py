"""The URG driver's streamed steps, start-up information and counters.

:mod:`mkflight.urg.driver` re-exports them: import them from there. The driver's settings
are the ``laser`` config section itself (:class:`~mkflight.config.LaserConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mkflight.config import LaserConfig
from mkflight.urg.replies import ParserStats
from mkflight.urg.units import SensorParams

__all__ = ["UrgInfo", "UrgStats", "streamed_steps"]


def streamed_steps(laser: LaserConfig) -> tuple[int, int]:
    """``(first, last)`` step of the MD request: every step the configuration uses.

    The hat steps and the scan steps, and the steps between them (one MD streams one
    contiguous range).
    """
    return (
        min(laser.hat_steps[0], laser.scan_steps[0]),
        max(laser.hat_steps[1], laser.scan_steps[1]),
    )


@dataclass(frozen=True, slots=True)
class UrgInfo:
    """What the sensor said about itself at start-up (VV, PP, II)."""

    version: dict[str, str]
    params: SensorParams
    status: dict[str, str] = field(default_factory=dict)

    @property
    def summary(self) -> str:
        """One line for humans: product, firmware, serial."""
        v = self.version
        return (
            f"{v.get('PROD', '?')} firmware {v.get('FIRM', '?')} serial {v.get('SERI', '?')}, "
            f"steps {self.params.amin_step}-{self.params.amax_step}, "
            f"{self.params.scan_rpm} rpm"
        )


@dataclass(slots=True)
class UrgStats:
    """What the driver saw and did; ends up in ``flight.json``."""

    parser: ParserStats = field(default_factory=ParserStats)
    scans: int = 0
    scans_dropped: int = 0
    stale_stream_scans: int = 0
    restarts: int = 0
    stalls: int = 0
    stream_errors: int = 0
    reopens: int = 0
