"""The simulator's own MK unit conversions: SI <-> raw DebugOut counts (SPEC §1, §8).

A second opinion, not a mirror: the FC emulators encode what the simulated vehicle
measures with THIS copy of SPEC §1's table (inverted), never with the flight code's
:mod:`mkflight.mk.units` or ``cfg.mk``; the two copies are tested against each other and
against ``mk-serial.md`` §6.2's worked example (vector MK-08). The accelerometer's scales
are the airframe's own (:class:`~mkflight.sim.vehicle.VehicleParams`
``acc_nick_counts_per_g``, ``acc_roll_counts_per_g``, ``acc_z_counts_per_mps2``,
``acc_z_offset_mps2``: a random airframe's differ from the nominal ones by a few %). The
DebugOut index constants are the wire format and come from :mod:`mkflight.mk.messages`.

The FC's conventions (``mk-serial.md`` §6.1, SPEC §1; FRD body, our signs):

==============  =================================  =========================================
DebugOut        counts                             from SI
==============  =================================  =========================================
AngleNick       0.1°, + nose down                  ``-pitch_rad / ANGLE_UNIT_RAD``
AngleRoll       0.1°, + left side down             ``-roll_rad / ANGLE_UNIT_RAD``
AccNick         k_nick counts per g                ``-f_x k_nick / g``
AccRoll         k_roll counts per g                ``+f_y k_roll / g``
AccZ            k_z counts per m/s², minus offset  ``(-f_z - offset) k_z``
Gyro Compass    degrees 0..359, clockwise          ``degrees(yaw) mod 360``
Voltage         0.1 V                              ``battery_v / VOLTAGE_UNIT_V``
==============  =================================  =========================================

Counts are rounded to the nearest integer and saturated to int16 (the FC's own variables
saturate); a non-finite value encodes as 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Final

from mkflight.mk.messages import (
    ANALOG_ACC_NICK,
    ANALOG_ACC_ROLL,
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_GYRO_COMPASS,
    ANALOG_VOLTAGE,
)
from mkflight.sim.vehicle_sensors import ImuSi
from mkflight.sim.vehicle_types import VehicleParams

ANGLE_UNIT_RAD: Final = math.pi / 1800.0  # AngleNick/AngleRoll: 0.1 degree
VOLTAGE_UNIT_V: Final = 0.1  # Voltage [0.1V]
INT16_MIN: Final = -32768
INT16_MAX: Final = 32767


def _count(value: float) -> int:
    """Round to the nearest count and saturate to int16; non-finite -> 0."""
    if not math.isfinite(value):
        return 0
    return max(INT16_MIN, min(INT16_MAX, round(value)))


def encode_analog(m: ImuSi, battery_v: float, params: VehicleParams) -> dict[int, int]:
    """SI measurement -> raw DebugOut counts by index (module table), the airframe's scales.

    Only the indexes the vehicle measures; the caller adds gas, receiver level and the rest.
    """
    g = params.g_mps2
    heading_deg = math.degrees(m.yaw_rad) % 360.0 if math.isfinite(m.yaw_rad) else 0.0
    return {
        ANALOG_ANGLE_NICK: _count(-m.pitch_rad / ANGLE_UNIT_RAD),
        ANALOG_ANGLE_ROLL: _count(-m.roll_rad / ANGLE_UNIT_RAD),
        ANALOG_ACC_NICK: _count(-m.acc_x_mps2 * params.acc_nick_counts_per_g / g),
        ANALOG_ACC_ROLL: _count(m.acc_y_mps2 * params.acc_roll_counts_per_g / g),
        ANALOG_ACC_Z: _count(
            (-m.acc_z_mps2 - params.acc_z_offset_mps2) * params.acc_z_counts_per_mps2
        ),
        ANALOG_GYRO_COMPASS: _count(heading_deg) % 360,
        ANALOG_VOLTAGE: _count(battery_v / VOLTAGE_UNIT_V),
    }


def decode_analog(analog: Mapping[int, int], params: VehicleParams) -> tuple[ImuSi, float]:
    """Raw DebugOut counts -> ``(ImuSi, battery_v)``: the inverse of :func:`encode_analog`.

    ``analog`` maps index -> count (a missing index reads 0). The yaw is wrapped to
    ``(-pi, pi]``.
    """
    g = params.g_mps2
    heading = math.radians(analog.get(ANALOG_GYRO_COMPASS, 0) % 360)
    yaw = heading - 2.0 * math.pi if heading > math.pi else heading
    imu = ImuSi(
        pitch_rad=-analog.get(ANALOG_ANGLE_NICK, 0) * ANGLE_UNIT_RAD,
        roll_rad=-analog.get(ANALOG_ANGLE_ROLL, 0) * ANGLE_UNIT_RAD,
        yaw_rad=yaw,
        acc_x_mps2=-analog.get(ANALOG_ACC_NICK, 0) * g / params.acc_nick_counts_per_g,
        acc_y_mps2=analog.get(ANALOG_ACC_ROLL, 0) * g / params.acc_roll_counts_per_g,
        acc_z_mps2=-(
            analog.get(ANALOG_ACC_Z, 0) / params.acc_z_counts_per_mps2 + params.acc_z_offset_mps2
        ),
    )
    return imu, analog.get(ANALOG_VOLTAGE, 0) * VOLTAGE_UNIT_V
