"""The MK link's settings and counters (:mod:`mkflight.mk.link` re-exports them)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Final

from mkflight.config import Config
from mkflight.conversions import NS_PER_MS
from mkflight.io.stream import Opener, Tap
from mkflight.mk.codec import ParserStats

__all__ = ["STICK_MAX_COUNTS", "LinkSettings", "LinkStats", "Opener", "Tap"]

STICK_MAX_COUNTS: Final = 127
"""Largest nick/roll/yaw magnitude the link sends (SPEC §4)."""


@dataclass(frozen=True, slots=True)
class LinkSettings:
    """The link's timing and limits: ``config.mk``, two of ``config.safety``, one of ``control``.

    No defaults: :meth:`from_config` is the one way to build it, so every value has one
    home, the configuration. ``gas_max`` and ``stick_max_counts`` make the link the last
    gate on outgoing commands (SPEC §4: gas in [0, gas_max], nick/roll within
    +-:data:`STICK_MAX_COUNTS`) whatever the caller computed.
    """

    baudrate: int
    debug_interval_10ms: int
    resubscribe_s: float
    stale_s: float
    """``safety.mk_stale_s``: no DebugOut for this long is stale data."""
    release_after_stale_s: float
    """``safety.mk_release_s``: stale this long, control goes back to the pilot."""
    version_retry_s: float
    answer_timeout_s: float
    min_frame_gap_s: float
    confirm_every: int
    """``mk.confirm_every``: every how many commands that take control one is numbered."""
    release_frames: int
    release_interval_s: float
    reopen_backoff_s: float
    reopen_backoff_max_s: float
    gas_max: int
    """``control.gas_max``."""
    stick_max_counts: int

    @classmethod
    def from_config(cls, cfg: Config) -> LinkSettings:
        """The link's values from the three sections of ``cfg`` that hold them."""
        mk = cfg.mk
        return cls(
            baudrate=mk.baudrate,
            debug_interval_10ms=mk.debug_interval_10ms,
            resubscribe_s=mk.resubscribe_s,
            stale_s=cfg.safety.mk_stale_s,
            release_after_stale_s=cfg.safety.mk_release_s,
            version_retry_s=mk.version_retry_s,
            answer_timeout_s=mk.answer_timeout_s,
            min_frame_gap_s=mk.min_frame_gap_s,
            confirm_every=mk.confirm_every,
            release_frames=mk.release_frames,
            release_interval_s=mk.release_interval_s,
            reopen_backoff_s=mk.reopen_backoff_s,
            reopen_backoff_max_s=mk.reopen_backoff_max_s,
            gas_max=cfg.control.gas_max,
            stick_max_counts=STICK_MAX_COUNTS,
        )


@dataclass(slots=True)
class LinkStats:
    """What the link saw and did; ends up in ``flight.json``."""

    parser: ParserStats = field(default_factory=ParserStats)
    samples: int = 0
    samples_dropped: int = 0
    foreign_frames: int = 0
    unknown_frames: int = 0
    bad_messages: int = 0
    versions: int = 0
    subscriptions: int = 0
    stale_events: int = 0
    stale_releases: int = 0
    blind_commands: int = 0
    commands_sent: int = 0
    confirms: int = 0
    confirms_lost: int = 0
    frames_written: int = 0
    bytes_written: int = 0
    delayed_writes: int = 0
    superseded_commands: int = 0
    reopens: int = 0
    rtt_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))

    def summary(self) -> dict[str, int | float | None]:
        """Flat counters for logs and ``flight.json``."""
        rtts = sorted(self.rtt_ns)
        median = rtts[len(rtts) // 2] / NS_PER_MS if rtts else None
        return {
            "bytes_in": self.parser.bytes_in,
            "frames_in": self.parser.frames,
            "crc_errors": self.parser.crc_errors,
            "garbage_bytes": self.parser.discarded_bytes,
            "malformed_frames": self.parser.malformed + self.bad_messages,
            "overflows": self.parser.overflows,
            "samples": self.samples,
            "samples_dropped": self.samples_dropped,
            "foreign_frames": self.foreign_frames,
            "stale_events": self.stale_events,
            "stale_releases": self.stale_releases,
            "blind_commands": self.blind_commands,
            "subscriptions": self.subscriptions,
            "commands_sent": self.commands_sent,
            "superseded_commands": self.superseded_commands,
            "confirms": self.confirms,
            "confirms_lost": self.confirms_lost,
            "reopens": self.reopens,
            "rtt_median_ms": median,
        }
