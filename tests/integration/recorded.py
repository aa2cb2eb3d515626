"""What a flight folder's recordings say the daemon sent (shared by the flight tests)."""

from __future__ import annotations

from pathlib import Path

from mkflight.logs.flight import extern_controls
from mkflight.logs.raw import read_raw
from mkflight.mk.messages import ExternControl


def commands_sent(folder: Path) -> list[ExternControl]:
    """Every ExternControl the daemon wrote to the FC port, from ``mk.raw``."""
    return [command for _, command in extern_controls(read_raw(folder / "mk.raw"))]
