"""What a flight folder's recordings say the daemon sent (shared by the flight tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mkflight.logs.flight import extern_controls
from mkflight.logs.raw import read_raw
from mkflight.mk.messages import ExternControl
from mkflight.sim.truth import parse_touchdowns


def commands_sent(folder: Path) -> list[ExternControl]:
    """Every ExternControl the daemon wrote to the FC port, from ``mk.raw``."""
    return [command for _, command in extern_controls(read_raw(folder / "mk.raw"))]


def assert_landed_softly(folder: Path) -> None:
    """Issue 17: every landing is judged by its touchdown speed, from the simulator's truth
    (its '# touchdown T S' lines): at least one after the hover, every one <= 0.5 m/s,
    and the vehicle on the floor at the end (never "released in the air")."""
    text = (folder / "truth.txt").read_text(encoding="utf-8")
    truth = np.loadtxt(folder / "truth.txt", skiprows=1, ndmin=2)
    touchdowns = parse_touchdowns(text)
    flew = truth[truth[:, 3] > 0.3, 0]
    assert flew.size, "never flew"
    after = [speed for t, speed in touchdowns if t > flew[0]]
    assert after, f"no touchdown after the take-off: {touchdowns}"
    assert max(after) <= 0.5, f"touchdowns {after} m/s"
    assert truth[-1, 3] < 0.05  # on the floor
