"""The simulated LiPo pack (§L, §M): open-circuit voltage by charge, current by thrust.

§ and Fig. are those of the 2011 QUT CyPhy MikroKopter documentation. Each pack
discharges differently (its Fig. 26); this is a generic 1C curve. The terminal voltage the
FC reads is ``open_circuit_v - I R`` (see :mod:`mkflight.sim.vehicle`).
"""

from __future__ import annotations

import bisect
import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mkflight.sim.vehicle_types import VehicleParams

#: Per-cell LiPo open-circuit voltage vs state of charge (a generic 1C discharge curve;
#: Fig. 26 shows each pack differs). (state of charge, volts per cell).
LIPO_OCV_V: tuple[tuple[float, float], ...] = tuple(
    zip(
        (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0),
        (3.30, 3.55, 3.68, 3.74, 3.77, 3.80, 3.84, 3.87, 3.92, 3.98, 4.06, 4.20),
        strict=True,
    )
)
_SOC = tuple(p[0] for p in LIPO_OCV_V)
_OCV = tuple(p[1] for p in LIPO_OCV_V)


def open_circuit_v(used_ah: float, params: VehicleParams) -> float:
    """Pack open-circuit voltage after ``used_ah`` (§M; :data:`LIPO_OCV_V`)."""
    soc = min(max(1.0 - used_ah / params.battery_capacity_ah, 0.0), 1.0)
    i = min(max(bisect.bisect_right(_SOC, soc) - 1, 0), len(_SOC) - 2)
    frac = (soc - _SOC[i]) / (_SOC[i + 1] - _SOC[i])
    return params.battery_cells * (_OCV[i] + frac * (_OCV[i + 1] - _OCV[i]))


def current_a(thrust_n: float, battery_v: float, params: VehicleParams) -> float:
    """Pack current: avionics + motors, ``(T/W)^1.5`` at constant power (§L)."""
    ratio = max(thrust_n, 0.0) / (params.mass_kg * params.g_mps2)
    volts = max(battery_v, 0.1 * params.hover_voltage_v)
    motors = params.hover_current_a * ratio * math.sqrt(ratio) * params.hover_voltage_v / volts
    return params.avionics_current_a + motors


def open_circuit_segment(used_ah: float, params: VehicleParams) -> tuple[float, float, float]:
    """``(volts, dv_per_ah, until_ah)``: the OCV at ``used_ah`` and its line up to ``until_ah``.

    :func:`open_circuit_v` is linear in the charge between two points of
    :data:`LIPO_OCV_V`: up to ``until_ah`` it is ``volts + dv_per_ah (used - used_ah)``
    exactly, so the vehicle's sub-steps need no table look-up (at the curve's ends, where it
    is flat, the slope is 0 and ``until_ah`` is infinite or the empty pack's charge).
    """
    cap = params.battery_capacity_ah
    soc = 1.0 - used_ah / cap
    volts = open_circuit_v(used_ah, params)
    if soc <= _SOC[0] or soc > _SOC[-1]:
        return volts, 0.0, math.inf if soc <= _SOC[0] else (1.0 - _SOC[-1]) * cap
    i = min(max(bisect.bisect_left(_SOC, soc) - 1, 0), len(_SOC) - 2)
    slope_per_soc = params.battery_cells * (_OCV[i + 1] - _OCV[i]) / (_SOC[i + 1] - _SOC[i])
    return volts, -slope_per_soc / cap, (1.0 - _SOC[i]) * cap
