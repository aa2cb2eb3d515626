"""Timestamped records passed between the links, the estimator and the logs.

Every record carries ``t_ns`` from the injected clock (host monotonic time at which the
data was received or measured) and SI values with their units in their names.

The records the 50 ms step builds (pose, estimate, command) are frozen ``msgspec.Struct``
values: immutable like a frozen dataclass, built ~5x faster, and (``gc=False``: they hold
only numbers, so no reference cycle can go through them) not tracked by the garbage
collector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Final

import msgspec

if TYPE_CHECKING:  # numpy stays off the import path of the MK-only commands
    import numpy as np
    import numpy.typing as npt


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


MAX_ABS_ANGLE_RAD: Final = math.pi
"""The FC reports its angles within ±180°: beyond, a value is no attitude."""
MAX_ABS_ACC_MPS2: Final = 10.0 * 9.81
"""No flight reads 10 g (a touchdown at 0.5 m/s on the gear: ~1 g); a larger value is
no specific force worth estimating with."""


def plausible_imu(imu: ImuSample) -> ImuSample:
    """``imu`` with every attitude or acceleration no FC can report replaced by NaN.

    A finite but absurd value (1e300 from a corrupted sample) would pass every
    ``isfinite`` check and make cosines, feed-forward factors and hat heights finite
    garbage; as NaN it takes the paths built for unusable samples (SPEC §5: the last safe
    command, the non-finite failsafe, a level descent).
    """
    p, r = imu.pitch_rad, imu.roll_rad
    ax, ay, az = imu.acc_x_mps2, imu.acc_y_mps2, imu.acc_z_mps2
    a, g = MAX_ABS_ANGLE_RAD, MAX_ABS_ACC_MPS2
    if abs(p) <= a and abs(r) <= a and abs(ax) <= g and abs(ay) <= g and abs(az) <= g:
        return imu  # the common case (NaN fails each comparison and goes below)
    nan = math.nan
    return replace(
        imu,
        pitch_rad=p if abs(p) <= a else nan,
        roll_rad=r if abs(r) <= a else nan,
        acc_x_mps2=ax if abs(ax) <= g else nan,
        acc_y_mps2=ay if abs(ay) <= g else nan,
        acc_z_mps2=az if abs(az) <= g else nan,
    )


@dataclass(frozen=True, slots=True, eq=False)
class Scan:
    """One laser scan, in the sensor's step order (SCIP 2.0, ``scip2.md`` §5).

    ``ranges_m[i]`` belongs to step ``first_step + i``; NaN marks an invalid value (an
    error code < 20 mm, or beyond DMAX), never a distance. Step s points at body angle
    ``-(s - 384) * 2*pi/1024`` rad (the sensor is counter-clockwise positive, our yaw
    clockwise: SPEC §1-2), i.e. step 44 is 2.086 rad to the right. ``t_ns`` is the host
    time at which the front step (384) was measured, not when the scan arrived.
    """

    t_ns: int
    ranges_m: npt.NDArray[np.float64]
    first_step: int
    seq: int = 0


class Pose2D(msgspec.Struct, frozen=True, gc=False):
    """A planar pose in the world frame W (SPEC §1): x forward, y right, psi clockwise."""

    t_ns: int
    x_m: float
    y_m: float
    yaw_rad: float


class Estimate(msgspec.Struct, frozen=True, gc=False):
    """The estimator's state at ``t_ns`` (SPEC §1, §3), in the world frame W.

    W: x forward and y right at the first scan, z down; ``height_m`` is positive up and
    ``vz_up_mps`` its rate. ``vx_mps``/``vy_mps`` are the complementary filter's world-frame
    velocity (eq 15-16); ``yaw_rad`` is clockwise. ``pose_valid``/``height_valid`` say
    whether the laser pose / hat height behind them is fresh enough to fly on.
    ``ax_ext_mps2``/``ay_ext_mps2`` are the horizontal acceleration (W) that the attitude
    does not explain — gusts, drag — as the accelerometers see it, its lasting part
    removed (:mod:`mkflight.estimation.tilt_accel`); 0 when not estimated.
    """

    t_ns: int
    x_m: float
    y_m: float
    yaw_rad: float
    height_m: float
    vx_mps: float
    vy_mps: float
    vz_up_mps: float
    pose_valid: bool = True
    height_valid: bool = True
    ax_ext_mps2: float = 0.0
    ay_ext_mps2: float = 0.0


class Command(msgspec.Struct, frozen=True, gc=False):
    """One ExternControl's content in MK counts, as the controllers decided it (SPEC §4).

    ``nick_counts``/``roll_counts``/``yaw_counts`` within +-127 with the MK's signs already
    applied (``mk.signs``), ``gas_counts`` in [0, control.gas_max]; ``take_control`` sets
    Config bit 0 (False: neutral hand-back).
    """

    t_ns: int
    nick_counts: int
    roll_counts: int
    yaw_counts: int
    gas_counts: int
    take_control: bool = True
