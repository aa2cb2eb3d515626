"""What ``sim hover`` reports: :class:`HoverResult`, and how a flight ended (:func:`flight_end`).

How it ended (:attr:`HoverResult.end`, judged on the truth): ``landed`` (on the floor,
≤ :data:`LANDED_M`, when control went back), ``released in the air`` (handed to the pilot
above it: the run stops there, the pilot has it), ``ground`` (never above
:data:`LANDED_M`), ``flying`` (still under our control when the time ran out). Every
touchdown's downward speed is the truth of the landing's hardness (SPEC §8: ≤ 0.5 m/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

LANDED_M: Final = 0.05  # on the floor (truth height); above it when handed back: in the air

END_LANDED: Final = "landed"
END_RELEASED_IN_AIR: Final = "released in the air"
END_GROUND: Final = "ground"
END_FLYING: Final = "flying"


@dataclass(slots=True)
class HoverResult:
    """What ``sim hover`` reports (SPEC §7): precision, landing, airframe, what was learned."""

    std_x_m: float
    std_y_m: float
    std_z_m: float
    rms_x_m: float
    rms_y_m: float
    rms_z_m: float
    realtime_factor: float
    log_dir: str
    sim_s: float
    wall_s: float
    hold_s: float
    end: str  # END_LANDED, END_RELEASED_IN_AIR, END_GROUND or END_FLYING
    failsafes: list[str] = field(default_factory=list)
    cpu_us_per_step: float = 0.0
    max_height_m: float = 0.0
    final_height_m: float = 0.0
    released: bool = False  # control is the pilot's at the end (Config = 0)
    touchdowns_mps: list[float] = field(default_factory=list)  # every touchdown (truth)
    airframe: dict[str, float | int | bool | list[float]] = field(default_factory=dict)
    airframe_kind: str = "nominal"  # sim.airframe
    airframe_seed: int = 0  # sim.seed (what draws a random airframe)
    learned: dict[str, object] = field(default_factory=dict)  # FlightCore.learned()
    scans: bool = False  # the laser was ray-cast scans through the real pipeline

    @property
    def landed(self) -> bool:
        """On the floor when control went back (never "released in the air")."""
        return self.end == END_LANDED

    @property
    def touchdown_mps(self) -> float:
        """The hardest touchdown's downward speed (truth), NaN if none."""
        return max(self.touchdowns_mps) if self.touchdowns_mps else math.nan

    def as_dict(self) -> dict[str, object]:
        """The ``--json`` object and ``flight.json``'s summary (NaN as null)."""
        hardest = self.touchdown_mps
        return {
            "std_x_m": _r(self.std_x_m, 5),
            "std_y_m": _r(self.std_y_m, 5),
            "std_z_m": _r(self.std_z_m, 5),
            "rms_x_m": _r(self.rms_x_m, 5),
            "rms_y_m": _r(self.rms_y_m, 5),
            "rms_z_m": _r(self.rms_z_m, 5),
            "realtime_factor": round(self.realtime_factor, 1),
            "log_dir": self.log_dir,
            "sim_s": round(self.sim_s, 3),
            "hold_s": round(self.hold_s, 3),
            "end": self.end,
            "landed": self.landed,
            "released": self.released,
            "touchdowns_mps": [round(v, 3) for v in self.touchdowns_mps],
            "touchdown_mps": _r(hardest, 3),
            "failsafes": self.failsafes,
            "cpu_us_per_step": round(self.cpu_us_per_step, 1),
            "max_height_m": round(self.max_height_m, 3),
            "final_height_m": round(self.final_height_m, 3),
            "scans": self.scans,
            "airframe_kind": self.airframe_kind,
            "airframe_seed": self.airframe_seed,
            "airframe": self.airframe,
            "learned": self.learned,
        }


def _r(value: float, digits: int) -> float | None:
    """``value`` rounded, or None (JSON null) when not finite."""
    return round(value, digits) if math.isfinite(value) else None


def flight_end(*, max_height_m: float, in_control: bool, handed_back_m: float | None) -> str:
    """How a flight ended, from the truth (module docstring).

    Args:
        max_height_m: the highest the vehicle flew (truth).
        in_control: the last command still takes control (Config bit 0).
        handed_back_m: the truth height when control last went back, None if it never did.
    """
    if max_height_m <= LANDED_M:
        return END_GROUND
    if in_control or handed_back_m is None:
        return END_FLYING
    return END_LANDED if handed_back_m <= LANDED_M else END_RELEASED_IN_AIR
