"""The pilot takes over by moving a stick (SPEC §5: "pilot moves the sticks ... release").

The FC reports its receiver channels in the 'P' answer to a 'p' request (mk-serial.md
§5.4; ``PPM_in``, around 0 at the sticks' centre). The daemon asks every
``PPM_PERIOD_S``; :class:`PilotWatch` takes the first answer after the pre-flight (the
vehicle on the ground, the pilot's hands off) as the baseline and reports an override
when nick, roll or yaw moves more than ``threshold_counts`` from it. The override is
latched: the failsafe releases at once and for good.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

from mkflight.mk.messages import Ppm

#: The MK's default channel map (mk-serial.md §5.4): PPM_in index of each stick.
CH_ROLL: Final = 2
CH_NICK: Final = 3
CH_YAW: Final = 4
STICK_CHANNELS: Final = (CH_NICK, CH_ROLL, CH_YAW)
PPM_PERIOD_S: Final = 0.5
"""How often the daemon asks for the sticks: a 'P' answer is 60 bytes (≈ 10 ms of line)."""


@dataclass(slots=True)
class PilotWatch:
    """Latches an override when a stick leaves its baseline by more than the threshold."""

    threshold_counts: int
    baseline: tuple[int, ...] | None = None
    override: bool = False
    moved: dict[int, int] = field(default_factory=dict)

    def update(self, ppm: Ppm) -> bool:
        """One 'P' answer; True once (and from then on) a stick has been moved."""
        values = tuple(ppm.channels[ch] for ch in STICK_CHANNELS)
        if self.baseline is None:
            self.baseline = values
            return self.override
        for ch, value, base in zip(STICK_CHANNELS, values, self.baseline, strict=True):
            if abs(value - base) > self.threshold_counts:
                self.override = True
                self.moved[ch] = value
        return self.override
