"""Frames and angles (SPEC §1): FRD body, world fixed at the first scan, psi clockwise.

Body B: x forward, y right, z down. Pitch theta about y (nose up positive), roll phi about
x (right side down positive), yaw psi about z (clockwise seen from above). These are the
aerospace Z-Y-X Euler angles, so body -> world is ``R_z(psi) R_y(theta) R_x(phi)`` with the
elementary right-handed rotation matrices.

The level (heading) frame L is the body frame with pitch and roll taken out: x forward
along the horizontal heading, y right, z down. World W is L turned by yaw.

Eq numbers are those of the 2011 QUT CyPhy MikroKopter documentation.
"""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to (-pi, pi]; NaN and inf stay NaN (they are invalid, not angles)."""
    if not math.isfinite(angle_rad):
        return math.nan
    wrapped = math.remainder(angle_rad, TWO_PI)
    return math.pi if wrapped <= -math.pi else wrapped


def world_to_body(x_w: float, y_w: float, yaw_rad: float) -> tuple[float, float]:
    """Rotate a horizontal world vector into the heading frame (SPEC §1; eq 3-6).

    ``v_B.x = cos psi * v_W.x + sin psi * v_W.y``, ``v_B.y = -sin psi * v_W.x + cos psi *
    v_W.y``. Eq 5-6 carry the opposite sign of psi because their psi is the world
    with respect to the body; psi here is the vehicle's clockwise yaw in W.

    Args:
        x_w: world x component (forward at the first scan), any unit.
        y_w: world y component (right at the first scan), same unit.
        yaw_rad: yaw psi, clockwise seen from above.

    Returns:
        ``(x_b, y_b)``: forward and right components along the vehicle's heading.
    """
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * x_w + s * y_w, -s * x_w + c * y_w


def body_to_world(x_b: float, y_b: float, yaw_rad: float) -> tuple[float, float]:
    """Rotate a horizontal heading-frame vector into the world frame (inverse of eq 3-6).

    ``v_W.x = cos psi * v_B.x - sin psi * v_B.y``, ``v_W.y = sin psi * v_B.x + cos psi *
    v_B.y``: a vehicle yawed +90 deg (nose right) moving forward moves along world +y.

    Args:
        x_b: forward component, any unit.
        y_b: right component, same unit.
        yaw_rad: yaw psi, clockwise seen from above.

    Returns:
        ``(x_w, y_w)`` in the world frame.
    """
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * x_b - s * y_b, s * x_b + c * y_b


def level_acceleration(
    f_x_mps2: float,
    f_y_mps2: float,
    f_z_mps2: float,
    pitch_rad: float,
    roll_rad: float,
    g_mps2: float,
) -> tuple[float, float, float]:
    """Level-frame acceleration from the body specific force (SPEC §3; eq 9-14 exact).

    ``a = R_y(theta) R_x(phi) f + (0, 0, g)`` in FRD (z down). Eq 10, 12 and 14 are its
    one-axis cases. A vehicle at rest at any tilt reads
    ``f = (g sin theta, -g sin phi cos theta, -g cos phi cos theta)`` and gets ``a = 0``.

    Args:
        f_x_mps2: specific force along body x (forward), m/s^2 (``ImuSample.acc_x_mps2``).
        f_y_mps2: specific force along body y (right), m/s^2.
        f_z_mps2: specific force along body z (down), m/s^2; about -g in hover.
        pitch_rad: pitch theta, nose up positive.
        roll_rad: roll phi, right side down positive.
        g_mps2: gravity, m/s^2.

    Returns:
        ``(a_x, a_y, a_z)`` in m/s^2 in the level frame: forward and right along the
        heading, and down (a climb has ``a_z < 0``).
    """
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    # R_x(phi) f: undo the roll.
    y1 = cr * f_y_mps2 - sr * f_z_mps2
    z1 = sr * f_y_mps2 + cr * f_z_mps2
    # R_y(theta) (...): undo the pitch.
    a_x = cp * f_x_mps2 + sp * z1
    a_z = -sp * f_x_mps2 + cp * z1
    return a_x, y1, a_z + g_mps2


def world_acceleration(
    f_x_mps2: float,
    f_y_mps2: float,
    f_z_mps2: float,
    pitch_rad: float,
    roll_rad: float,
    yaw_rad: float,
    g_mps2: float,
) -> tuple[float, float, float]:
    """World-frame acceleration: :func:`level_acceleration` turned by yaw (SPEC §1, §3).

    Args:
        f_x_mps2: specific force along body x, m/s^2.
        f_y_mps2: specific force along body y, m/s^2.
        f_z_mps2: specific force along body z (down), m/s^2.
        pitch_rad: pitch theta, nose up positive.
        roll_rad: roll phi, right side down positive.
        yaw_rad: yaw psi in W (the estimator's, not the MK's drifting gyro yaw).
        g_mps2: gravity, m/s^2.

    Returns:
        ``(a_x, a_y, a_z)`` in m/s^2 in W (x forward at the first scan, y right, z down).
    """
    a_x, a_y, a_z = level_acceleration(f_x_mps2, f_y_mps2, f_z_mps2, pitch_rad, roll_rad, g_mps2)
    w_x, w_y = body_to_world(a_x, a_y, yaw_rad)
    return w_x, w_y, a_z
