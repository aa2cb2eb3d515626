"""What a flight folder's recordings say the daemon sent (shared by the flight tests)."""

from __future__ import annotations

from pathlib import Path

from mkflight.logs.raw import read_raw
from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import ExternControl


def commands_sent(folder: Path) -> list[ExternControl]:
    """Every ExternControl the daemon wrote to the FC port, from ``mk.raw``."""
    parser = FrameParser()
    out: list[ExternControl] = []
    for rec in read_raw(folder / "mk.raw").records:
        if rec.kind == "w":
            out += [ExternControl.decode(f) for f in parser.feed(rec.data) if f.cmd == "b"]
    return out
