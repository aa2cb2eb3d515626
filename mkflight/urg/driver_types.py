"""The URG driver's settings, start-up information and counters (split from the driver).

:mod:`mkflight.urg.driver` re-exports them: import them from there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mkflight.config import LaserConfig
from mkflight.urg.replies import ParserStats
from mkflight.urg.units import SensorParams

__all__ = ["UrgInfo", "UrgSettings", "UrgStats", "settings_from_config"]


@dataclass(frozen=True, slots=True)
class UrgSettings:
    """Steps to stream, the fixed transport delay and the timing of the recovery rules."""

    first_step: int = 44
    last_step: int = 725
    request_timeout_s: float = 1.0
    drain_silence_s: float = 0.15
    drain_max_s: float = 1.0
    stall_s: float = 0.3
    transport_delay_s: float = 0.03
    max_restarts: int = 5
    sum_error_run: int = 3
    reopen_backoff_s: float = 0.1
    reopen_backoff_max_s: float = 2.0


def settings_from_config(laser: LaserConfig) -> UrgSettings:
    """Stream every step the configuration uses (hat and scan steps)."""
    return UrgSettings(
        first_step=min(laser.hat_steps[0], laser.scan_steps[0]),
        last_step=max(laser.hat_steps[1], laser.scan_steps[1]),
        stall_s=laser.stall_s,
        transport_delay_s=laser.transport_delay_s,
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
