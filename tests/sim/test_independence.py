"""The simulator is a second opinion: its vehicle side reads none of the flight's constants.

SPEC §8: nothing of the simulated airframe, its sensors, its encoders or its
links may come from ``mk``, ``control``, ``estimation`` or ``laser``, the flight code's
calibration objects, or the URG driver's ``transport_delay_s``. Only the modules that *are*
the flight side (``sim hover``'s :mod:`mkflight.sim.hover_flight` and
:mod:`mkflight.sim.hover`, which run the daemon's core and decode with its calibration)
and the envelope's tools that run such flights may. The behaviour is tested too
(``test_world.py``: the same bytes fly the same vehicle whatever those sections say).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

SIM = Path(__file__).resolve().parents[2] / "mkflight" / "sim"
FLIGHT_SIDE = {"hover.py", "hover_flight.py", "envelope.py"}  # run FlightCore on a cfg
FORBIDDEN = re.compile(
    r"cfg\.(mk|control|estimation|laser)\b|\bMkCalibration\b|\banalog_from_si\b"
    r"|\bimu_from_debug\b|\bLaserConfig\b|\bMkConfig\b|\bControlConfig\b"
    r"|\bEstimationConfig\b|\.transport_delay_s\b|streamed_steps"
)


def code_lines(path: Path) -> list[tuple[int, str]]:
    """The lines outside docstrings and comments (a docstring may name what is not read)."""
    out: list[tuple[int, str]] = []
    in_doc = False
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        quotes = line.count('"""')
        if in_doc or quotes:
            if quotes % 2:
                in_doc = not in_doc
            continue
        out.append((n, line.split("#", 1)[0]))
    return out


SIMULATED_SIDE = sorted(p for p in SIM.glob("*.py") if p.name not in FLIGHT_SIDE)


@pytest.mark.parametrize("path", SIMULATED_SIDE, ids=lambda p: p.name)
def test_the_simulated_side_reads_nothing_of_the_flight(path: Path) -> None:
    hits = [
        f"{path.name}:{n}: {line.strip()}" for n, line in code_lines(path) if FORBIDDEN.search(line)
    ]
    assert hits == []


def test_the_check_sees_the_flight_side() -> None:
    hits = [line for _, line in code_lines(SIM / "hover_flight.py") if FORBIDDEN.search(line)]
    assert any("MkCalibration.from_config(cfg.mk)" in line for line in hits)
