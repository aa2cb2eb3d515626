"""The complementary filter (§H eq 15-17) and the laser's velocity (eq 18-20).

§ and eq are those of the 2011 QUT CyPhy MikroKopter documentation. Pure functions and small
frozen records; no clock, no I/O. The filter runs per axis:

    v_hat(t+1) = v_hat(t) + T * (k * (v_meas - v_hat(t)) + a(t))        (eq 15-17)

with T the interval to the next sample (from timestamps), k the gain in 1/s, ``v_meas``
the laser's velocity (the derivative of its poses, or of the hat height for the vertical
axis) and ``a(t)`` the acceleration held over the interval. Without a measurement the
correction term is left out and the filter integrates the acceleration alone.
"""

from __future__ import annotations

import math

import msgspec

from mkflight.conversions import NS_PER_S
from mkflight.frames import world_to_body, wrap_pi
from mkflight.msgs import Pose2D


def complementary_step(
    v_hat_mps: float,
    v_meas_mps: float | None,
    acc_mps2: float,
    dt_s: float,
    gain_per_s: float,
) -> float:
    """One step of the complementary filter on one axis (eq 15, 16 or 17).

    Args:
        v_hat_mps: the estimate at t, m/s.
        v_meas_mps: the measured velocity (laser or hat), m/s; None = no measurement.
        acc_mps2: the acceleration a(t) along the axis, held until t + dt, m/s^2.
        dt_s: T, the interval to the next sample, s.
        gain_per_s: k, 1/s; the estimate follows the measurement with time constant 1/k.

    Returns:
        The estimate at t + dt, m/s.
    """
    correction = 0.0 if v_meas_mps is None else gain_per_s * (v_meas_mps - v_hat_mps)
    return v_hat_mps + dt_s * (correction + acc_mps2)


class LaserVelocity(msgspec.Struct, frozen=True, gc=False):
    """The laser's velocity over the interval between two poses (eq 19, Fig. 17).

    ``vx_w_mps``/``vy_w_mps`` are in the world frame W; ``yaw_rate_radps`` is clockwise.
    ``t_ns`` is the later pose's (scan) time and ``dt_s`` the interval it spans.
    """

    t_ns: int
    dt_s: float
    vx_w_mps: float
    vy_w_mps: float
    yaw_rate_radps: float

    def in_body(self, yaw_rad: float) -> tuple[float, float]:
        """This velocity in the heading frame at yaw ``yaw_rad`` (eq 4; SPEC §1)."""
        return world_to_body(self.vx_w_mps, self.vy_w_mps, yaw_rad)


def laser_velocity(prev: Pose2D, cur: Pose2D) -> LaserVelocity | None:
    """Differentiate two successive poses over their timestamps (eq 19).

    ``v = (x(t) - x(t-1)) / T`` with T the poses' time difference, not an assumed 100 ms.

    Args:
        prev: the earlier pose (world frame).
        cur: the later pose.

    Returns:
        The world-frame velocity, or None when the poses are not strictly increasing in
        time or the result is not finite.
    """
    dt_s = (cur.t_ns - prev.t_ns) / NS_PER_S
    if dt_s <= 0.0:
        return None
    vx = (cur.x_m - prev.x_m) / dt_s
    vy = (cur.y_m - prev.y_m) / dt_s
    rate = wrap_pi(cur.yaw_rad - prev.yaw_rad) / dt_s
    if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(rate)):  # no generator
        return None
    return LaserVelocity(cur.t_ns, dt_s, vx, vy, rate)


def rate_of_change(prev_t_ns: int, prev_value: float, t_ns: int, value: float) -> float | None:
    """Derivative of a scalar over two timestamps (the hat height's, for eq 17), unit/s.

    Returns:
        ``(value - prev_value) / dt``, or None when ``dt <= 0`` or the result is not finite.
    """
    dt_s = (t_ns - prev_t_ns) / NS_PER_S
    if dt_s <= 0.0:
        return None
    rate = (value - prev_value) / dt_s
    return rate if math.isfinite(rate) else None


def predict_pose(prev: Pose2D, cur: Pose2D, horizon_s: float | None = None) -> Pose2D:
    """The one-sample prediction of the laser pose (eq 18-20).

    ``x_hat(t + h) = x(t) + (x(t) - x(t-1)) / T * h``; with ``h = T`` (the default) this
    is eq 20, ``2 x(t) - x(t-1)``. Yaw is extrapolated the same way on the wrapped
    difference.

    Args:
        prev: the pose at t - T.
        cur: the pose at t.
        horizon_s: h, how far past ``cur`` to predict, s; None = one sample (h = T).

    Returns:
        The predicted pose, stamped ``cur.t_ns + h``; ``cur`` itself when the two poses
        do not give a velocity.
    """
    vel = laser_velocity(prev, cur)
    if vel is None:
        return cur
    h_s = vel.dt_s if horizon_s is None else horizon_s
    return Pose2D(
        t_ns=cur.t_ns + round(h_s * NS_PER_S),
        x_m=cur.x_m + vel.vx_w_mps * h_s,
        y_m=cur.y_m + vel.vy_w_mps * h_s,
        yaw_rad=wrap_pi(cur.yaw_rad + vel.yaw_rate_radps * h_s),
    )
