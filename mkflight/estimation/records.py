"""Records the estimator hands to the logs and ``flight.json`` (TABLE III).

TABLE and eq are those of the 2011 QUT CyPhy MikroKopter documentation.
"""

from __future__ import annotations

import msgspec


class LaserStep(msgspec.Struct, frozen=True, gc=False):
    """What the 100 ms log (TABLE III) needs from the last accepted pose.

    ``w_vel_*`` is the laser velocity in W (eq 19), ``b_vel_*`` the same in the heading
    frame at the scan's yaw (eq 4), ``b_esti_vel_*`` the filter's current velocity in the
    heading frame at the current yaw (eq 15-16), all m/s; NaN when the laser gave no
    velocity (first pose, or a gap). ``x_m``/``y_m``/``yaw_rad`` are the laser pose
    (``CurrentPosition``). ``compensated`` is False when the history did not reach back
    to the scan (eq 18-20 used instead) or latency compensation is off.
    """

    t_ns: int
    w_vel_x_mps: float
    w_vel_y_mps: float
    b_vel_x_mps: float
    b_vel_y_mps: float
    b_esti_vel_x_mps: float
    b_esti_vel_y_mps: float
    x_m: float
    y_m: float
    yaw_rad: float
    compensated: bool


class EstimatorCounters(msgspec.Struct, frozen=True, gc=False):
    """Counts of inputs the estimator refused or could not use (for ``flight.json``)."""

    imu_rejected: int = 0
    pose_rejected: int = 0
    height_rejected: int = 0
    height_missing: int = 0
    out_of_order: int = 0
    imu_gaps: int = 0
    history_misses: int = 0
