"""MK raw DebugOut values <-> SI (SPEC §1 table).

The conversions are those of the 2011 QUT CyPhy MikroKopter documentation, §D eq 7-8,
TABLE I/II. Signs: the MK's AngleNick/AngleRoll are positive nose down / left side down, ours
(FRD) positive nose up / right side down, hence the minus signs. At rest the vehicle
measures the specific force f = (g sin(pitch), -g sin(roll) cos(pitch), -g cos(roll)
cos(pitch)), so AccNick reads -k_nick sin(pitch) (eq 7, TABLE I) and AccRoll
-k_roll sin(roll) cos(pitch). AccZ is eq 8's upward value minus 9.8, in 1/15.5 m/s^2.
Gyro Compass is a clockwise heading in degrees, like our psi.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mkflight.config import MkConfig
from mkflight.frames import wrap_pi
from mkflight.mk.messages import (
    ANALOG_ACC_NICK,
    ANALOG_ACC_ROLL,
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_GAS,
    ANALOG_GYRO_COMPASS,
    ANALOG_RECEIVER_LEVEL,
    ANALOG_VOLTAGE,
    DebugOut,
)
from mkflight.msgs import ImuSample

INT16_MIN = -32768
INT16_MAX = 32767


@dataclass(frozen=True, slots=True)
class MkCalibration:
    """The conversion constants (all from ``config.mk``)."""

    angle_unit_rad: float
    acc_nick_counts_per_g: float
    acc_roll_counts_per_g: float
    acc_z_counts_per_mps2: float
    acc_z_offset_mps2: float
    voltage_unit_v: float
    g_mps2: float

    @classmethod
    def from_config(cls, mk: MkConfig) -> MkCalibration:
        """Take the constants from the ``mk`` config section."""
        return cls(
            angle_unit_rad=math.radians(mk.angle_unit_deg),
            acc_nick_counts_per_g=mk.acc_nick_counts_per_g,
            acc_roll_counts_per_g=mk.acc_roll_counts_per_g,
            acc_z_counts_per_mps2=mk.acc_z_counts_per_mps2,
            acc_z_offset_mps2=mk.acc_z_offset_mps2,
            voltage_unit_v=mk.voltage_unit_v,
            g_mps2=mk.g_mps2,
        )


DEFAULT_CALIBRATION = MkCalibration.from_config(MkConfig())


def imu_from_debug(debug: DebugOut, t_ns: int, cal: MkCalibration) -> ImuSample:
    """Convert one DebugOut into SI (SPEC §1 table)."""
    return imu_from_analog(debug.analog, t_ns, cal)


def imu_from_analog(a: tuple[int, ...], t_ns: int, cal: MkCalibration) -> ImuSample:
    """Convert a DebugOut's 32 analog values into SI (SPEC §1 table)."""
    return ImuSample(
        t_ns=t_ns,
        pitch_rad=-a[ANALOG_ANGLE_NICK] * cal.angle_unit_rad,
        roll_rad=-a[ANALOG_ANGLE_ROLL] * cal.angle_unit_rad,
        yaw_rad=wrap_pi(math.radians(a[ANALOG_GYRO_COMPASS])),
        acc_x_mps2=-a[ANALOG_ACC_NICK] * cal.g_mps2 / cal.acc_nick_counts_per_g,
        acc_y_mps2=a[ANALOG_ACC_ROLL] * cal.g_mps2 / cal.acc_roll_counts_per_g,
        acc_z_mps2=-(a[ANALOG_ACC_Z] / cal.acc_z_counts_per_mps2 + cal.acc_z_offset_mps2),
        battery_v=a[ANALOG_VOLTAGE] * cal.voltage_unit_v,
        gas_counts=a[ANALOG_GAS] // 4,
        receiver_level=a[ANALOG_RECEIVER_LEVEL],
    )


def _count(value: float) -> int:
    """Round to the nearest count and saturate to int16 (the FC's own variables saturate)."""
    if not math.isfinite(value):
        return 0
    return max(INT16_MIN, min(INT16_MAX, round(value)))


def analog_from_si(
    *,
    pitch_rad: float,
    roll_rad: float,
    yaw_rad: float,
    acc_x_mps2: float,
    acc_y_mps2: float,
    acc_z_mps2: float,
    battery_v: float,
    cal: MkCalibration,
) -> dict[int, int]:
    """The inverse of :func:`imu_from_debug`: SI values -> raw DebugOut counts by index.

    Used by the FlightCtrl emulator to publish what a vehicle state would read.
    """
    heading_deg = math.degrees(yaw_rad) % 360.0 if math.isfinite(yaw_rad) else 0.0
    return {
        ANALOG_ANGLE_NICK: _count(-pitch_rad / cal.angle_unit_rad),
        ANALOG_ANGLE_ROLL: _count(-roll_rad / cal.angle_unit_rad),
        ANALOG_GYRO_COMPASS: _count(heading_deg) % 360,
        ANALOG_ACC_NICK: _count(-acc_x_mps2 * cal.acc_nick_counts_per_g / cal.g_mps2),
        ANALOG_ACC_ROLL: _count(acc_y_mps2 * cal.acc_roll_counts_per_g / cal.g_mps2),
        ANALOG_ACC_Z: _count((-acc_z_mps2 - cal.acc_z_offset_mps2) * cal.acc_z_counts_per_mps2),
        ANALOG_VOLTAGE: _count(battery_v / cal.voltage_unit_v),
    }
