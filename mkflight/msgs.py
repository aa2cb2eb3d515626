"""Timestamped records passed between the links, the estimator and the logs.

Every record carries ``t_ns`` from the injected clock (host monotonic time at which the
data was received or measured) and SI values with their units in their names.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One FlightCtrl DebugOut in SI units (SPEC §1 table; body frame FRD).

    ``acc_*_mps2`` is the specific force the accelerometers measure (a vehicle at rest
    reads ``(0, 0, -g)`` when level), not the acceleration. ``gas_counts`` is the gas the
    FC actually uses (min of stick and extern gas), ``receiver_level`` the RC signal
    quality (0 = no RC).
    """

    t_ns: int
    pitch_rad: float
    roll_rad: float
    yaw_rad: float
    acc_x_mps2: float
    acc_y_mps2: float
    acc_z_mps2: float
    battery_v: float
    gas_counts: int = 0
    receiver_level: int = 0
