"""The estimator's history: one *knot* per IMU sample, and one per scan between two.

A knot holds the inputs held from its time (the acceleration until the next knot, the
MK's gyro yaw, the measurements taken there) and the state after them: the complementary
filter's position and velocity (eq 15-17) or the Kalman filter's per axis
(:mod:`mkflight.estimation.kalman`). Never changed once in the history: the estimator
replaces knots when a late scan re-filters it (:mod:`mkflight.estimation.estimator`).
"""

from __future__ import annotations

import math

import msgspec

from mkflight.estimation.filter import complementary_step
from mkflight.estimation.kalman import (
    AxisNoise,
    AxisState,
    predict_update,
    update_position,
)

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class Knot(msgspec.Struct, gc=False):
    """One point of the history: the state at ``t_ns`` and the inputs held from it.

    A plain Struct (fields are set on a new knot, :func:`copy_knot`, before it goes into
    the history); untracked by the garbage collector: it holds numbers, tuples of numbers
    and :class:`AxisState` values, so no reference cycle can go through it.
    """

    t_ns: int
    acc_l: Vec3  # level frame FRD, m/s^2, held until the next knot (Kalman: the model's)
    mk_yaw_rad: float
    x_m: float = 0.0
    y_m: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    h_m: float = 0.0
    vz_up_mps: float = 0.0
    meas_w: Vec2 | None = None  # laser velocity (W) at this knot, the filter's measurement
    meas_z: float | None = None  # hat height rate (up), m/s
    fix_xy: Vec2 | None = None  # set: this knot is a pose anchor
    fix_h: float | None = None  # set: this knot is a height anchor
    # the Kalman filter (``estimation.filter: kalman``):
    res_l: tuple[float, float, float | None] | None = None  # the accelerometers' residual
    z_model: bool = False  # acc_l z is the thrust model's (else the accelerometer's)
    kx: AxisState | None = None  # x, y in W; z up (None: not started)
    ky: AxisState | None = None
    kz: AxisState | None = None
    fix_std_m: float = 0.0  # the pose's noise (more for a pose carried to now)


def copy_knot(k: Knot) -> Knot:
    """A new knot equal to ``k``, to set fields on before it goes into the history.

    A knot in the history is never changed (the estimator keeps a list of them to restore);
    this is ``msgspec.structs.replace`` without its keyword arguments, on the scan's path.
    """
    return Knot(
        k.t_ns, k.acc_l, k.mk_yaw_rad, k.x_m, k.y_m, k.vx_mps, k.vy_mps, k.h_m, k.vz_up_mps,
        k.meas_w, k.meas_z, k.fix_xy, k.fix_h, k.res_l, k.z_model, k.kx, k.ky, k.kz,
        k.fix_std_m,
    )  # fmt: skip


def finite(*values: float) -> bool:
    """Every value finite."""
    return all(map(math.isfinite, values))  # no generator's frame: several times a step


def knot_finite(k: Knot) -> bool:
    """The knot's state (and the Kalman filter's covariance) finite."""
    if not math.isfinite(k.x_m + k.y_m + k.vx_mps + k.vy_mps + k.h_m + k.vz_up_mps):
        return False
    for s in (k.kx, k.ky, k.kz):  # AxisState.finite, without a call per axis
        if s is not None and not math.isfinite(
            s.p + s.v + s.d + s.pp + s.pv + s.pd + s.vv + s.vd + s.dd
        ):
            return False
    return True


def complementary_knot(
    k: Knot,
    nxt: Knot,
    acc_w: Vec3,
    next_acc_w: Vec3 | None,
    dt_s: float,
    *,
    k_xy: float,
    k_z: float,
    carry: bool,
    horizontal: bool,
    vertical: bool,
) -> Knot:
    """``nxt`` with its state stepped from ``k`` by eq 15-17 (trapezoidal position).

    ``acc_w``: ``k``'s held acceleration in W (bias removed; z up). Eq 15 holds it over
    the interval (forward Euler): the velocity then lags the truth by half a sample
    (26 ms), which at the loop's crossover is phase the attitude's own delay cannot spare.
    With ``next_acc_w`` (``nxt``'s) the interval's acceleration is the mean of the two
    (trapezoidal). ``carry``: the laser's velocity is carried forward with the
    acceleration (latency compensation). ``horizontal``/``vertical``: whether x, y (a pose
    has given the yaw offset) and z (a height has come) are filtered yet.
    """
    ax, ay, az = acc_w
    if next_acc_w is not None:  # the mean of the interval's two samples: no half-step lag
        bx, by, bz = next_acc_w
        ax, ay, az = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
    x, y, vx, vy, meas_w = k.x_m, k.y_m, k.vx_mps, k.vy_mps, k.meas_w
    if horizontal:
        mx, my = (None, None) if meas_w is None else meas_w
        vx1 = complementary_step(vx, mx, ax, dt_s, k_xy)
        vy1 = complementary_step(vy, my, ay, dt_s, k_xy)
        x, y, vx, vy = x + 0.5 * (vx + vx1) * dt_s, y + 0.5 * (vy + vy1) * dt_s, vx1, vy1
        if meas_w is not None and carry:
            meas_w = (meas_w[0] + ax * dt_s, meas_w[1] + ay * dt_s)
    h, vz, meas_z = k.h_m, k.vz_up_mps, k.meas_z
    if vertical:
        vz1 = complementary_step(vz, meas_z, az, dt_s, k_z)
        h, vz = h + 0.5 * (vz + vz1) * dt_s, vz1
        if meas_z is not None and carry:
            meas_z += az * dt_s
    if nxt.fix_xy is not None:  # a pose anchor keeps its laser position and velocity
        x, y = nxt.fix_xy
        meas_w = nxt.meas_w
    if nxt.fix_h is not None:
        h, meas_z = nxt.fix_h, nxt.meas_z
    return msgspec.structs.replace(
        nxt, x_m=x, y_m=y, vx_mps=vx, vy_mps=vy, h_m=h, vz_up_mps=vz,
        meas_w=meas_w, meas_z=meas_z,
    )  # fmt: skip


def kalman_knot(
    k: Knot,
    nxt: Knot,
    acc_w: Vec3,
    next_acc_w: Vec3,
    res_w: tuple[float, float, float | None] | None,
    dt_s: float,
    *,
    noise_xy: AxisNoise,
    noise_z: AxisNoise,
    height_noise_m: float,
    horizontal: bool,
    vertical: bool,
) -> Knot:
    """``nxt`` with the Kalman filter stepped from ``k`` (:mod:`mkflight.estimation.kalman`).

    Predict with the model's acceleration (the mean of ``acc_w`` and ``next_acc_w``, W,
    bias removed, z up), correct with ``nxt``'s residual ``res_w`` (W, z up; None: none
    measured there) and its pose or height fix. A filter not started before ``nxt`` is
    ``nxt``'s own (where the first fix started it). When the thrust model comes or goes
    the vertical disturbance means another thing and starts again.
    """
    kx, ky, kz = k.kx, k.ky, k.kz
    if kx is None or ky is None:  # not started before nxt: nxt may be where it starts
        kx, ky = nxt.kx, nxt.ky
    elif horizontal:
        n = noise_xy
        rx, ry = (None, None) if res_w is None else (res_w[0], res_w[1])
        kx = predict_update(kx, 0.5 * (acc_w[0] + next_acc_w[0]), dt_s, n, rx)
        ky = predict_update(ky, 0.5 * (acc_w[1] + next_acc_w[1]), dt_s, n, ry)
        if nxt.fix_xy is not None:
            kx = update_position(kx, nxt.fix_xy[0], nxt.fix_std_m)
            ky = update_position(ky, nxt.fix_xy[1], nxt.fix_std_m)
    if kz is None:
        kz = nxt.kz
    elif vertical:
        n = noise_z
        rz = None if res_w is None else res_w[2]
        if nxt.z_model != k.z_model:
            dd = (n.acc_std if nxt.z_model else n.disturbance_std) ** 2
            d0 = rz if nxt.z_model and rz is not None else 0.0
            kz = msgspec.structs.replace(kz, d=d0, pd=0.0, vd=0.0, dd=dd)
        kz = predict_update(kz, 0.5 * (acc_w[2] + next_acc_w[2]), dt_s, n, rz)
        if nxt.fix_h is not None:
            kz = update_position(kz, nxt.fix_h, height_noise_m)
    x, y, vx, vy = k.x_m, k.y_m, k.vx_mps, k.vy_mps
    if kx is not None and ky is not None:
        x, y, vx, vy = kx.p, ky.p, kx.v, ky.v
    h, vz = (kz.p, kz.v) if kz is not None else (k.h_m, k.vz_up_mps)
    return Knot(  # all fields: faster than msgspec.structs.replace on the 20 Hz path
        nxt.t_ns, nxt.acc_l, nxt.mk_yaw_rad, x, y, vx, vy, h, vz,
        nxt.meas_w, nxt.meas_z, nxt.fix_xy, nxt.fix_h, nxt.res_l, nxt.z_model,
        kx, ky, kz, nxt.fix_std_m,
    )  # fmt: skip
