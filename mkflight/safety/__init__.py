"""Safety (SPEC §5): the pure, latched, prioritised failsafe state machine."""

from __future__ import annotations

from mkflight.safety.failsafe import (
    Cause,
    Failsafe,
    FailsafeAction,
    FailsafeInputs,
    FailsafeOutput,
    StopRequest,
    TransitionEvent,
)

__all__ = [
    "Cause",
    "Failsafe",
    "FailsafeAction",
    "FailsafeInputs",
    "FailsafeOutput",
    "StopRequest",
    "TransitionEvent",
]
