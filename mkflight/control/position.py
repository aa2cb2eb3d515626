"""Horizontal position control (SPEC §4; §C eq 1-6, §H eq 21-22).

§ and eq are those of the 2011 QUT CyPhy MikroKopter documentation.

Cascade, like PX4's ``PositionControl``:

1. position PD on the world error (eq 1-2) -> velocity set-point in W, its vector norm
   limited to ``control.max_speed_mps``; the D term is on the measurement, i.e.
   ``-kd_xy * v_hat`` (the estimator's velocity is the position's derivative);
2. velocity PID (eq 21-22, on the estimate's world velocity v_hat) -> desired horizontal
   acceleration in W, each axis limited to ``g * max_tilt_rad`` (the anti-windup bound);
3. W -> heading frame B by yaw (``frames.world_to_body``, SPEC §1:
   ``a_B.x = cos psi a_W.x + sin psi a_W.y``, ``a_B.y = -sin psi a_W.x + cos psi a_W.y``;
   eq 5-6 use the opposite psi);
4. tilt (small angle): pitch ``theta* = -a_x / g`` (FRD: to accelerate forward the nose
   goes down, i.e. negative pitch), roll ``phi* = a_y / g`` (right side down to go right);
5. the tilt VECTOR's norm is clamped to ``control.max_tilt_rad`` (direction kept);
6. MK counts = ``mk.signs.<axis> * angle * mk.counts_per_rad``, clamped to +-127, rounded.
   With the default signs (-1) a target ahead gives positive nick, one to the right
   negative roll. With ``counts_per_rad * max_tilt_rad > 127`` the per-axis count clamp can
   bend the direction slightly; with the defaults (120 * 0.30 = 36) it never acts.
"""

from __future__ import annotations

import math

import msgspec

from mkflight.config import ControlConfig, MkConfig
from mkflight.control.limits import all_finite, angle_to_counts, clamp_norm
from mkflight.control.pid import PidGains, PidState, gains_of_config, pid_update
from mkflight.frames import world_to_body


class PositionState(msgspec.Struct, frozen=True, gc=False):
    """The four PIDs' states: position x/y (outer) and velocity x/y (inner), all in W."""

    pos_x: PidState = msgspec.field(default_factory=PidState)
    pos_y: PidState = msgspec.field(default_factory=PidState)
    vel_x: PidState = msgspec.field(default_factory=PidState)
    vel_y: PidState = msgspec.field(default_factory=PidState)


class PositionResult(msgspec.Struct, frozen=True, gc=False):
    """One step of the horizontal cascade, with every intermediate for the logs."""

    vel_sp_x_mps: float
    vel_sp_y_mps: float
    acc_x_w_mps2: float
    acc_y_w_mps2: float
    acc_x_b_mps2: float
    acc_y_b_mps2: float
    pitch_sp_rad: float
    roll_sp_rad: float
    tilt_clamped: bool
    nick_counts: int
    roll_counts: int
    state: PositionState


@gains_of_config
def position_gains(control: ControlConfig) -> PidGains:
    """The position loop (eq 1-2 plus an integral): kp_xy, ki_xy, kd_xy; no output clamp."""
    # The integral takes up what biases the velocity estimate (an accelerometer bias b
    # leaves the complementary filter off by b/k) and the airframe's trim: without it the
    # vehicle would hover at a steady offset of b / (k * kp_xy).
    return PidGains(
        kp=control.kp_xy,
        ki=control.ki_xy,
        kd=control.kd_xy,
        integral_limit=control.max_speed_mps,
    )


@gains_of_config
def velocity_gains(control: ControlConfig, g_mps2: float) -> PidGains:
    """The velocity PID (eq 21-22), output +-g*max_tilt (m/s^2), integral within that."""
    a_max = g_mps2 * control.max_tilt_rad
    return PidGains(
        kp=control.kp_vxy,
        ki=control.ki_vxy,
        kd=control.kd_vxy,
        integral_limit=a_max,
        output_min=-a_max,
        output_max=a_max,
    )


def position_step(
    control: ControlConfig,
    mk: MkConfig,
    state: PositionState,
    *,
    x_sp_m: float,
    y_sp_m: float,
    x_m: float,
    y_m: float,
    vx_mps: float,
    vy_mps: float,
    yaw_rad: float,
    dt_s: float,
    ff_ax_w_mps2: float = 0.0,
    ff_ay_w_mps2: float = 0.0,
) -> PositionResult | None:
    """Run the horizontal cascade once (eq 1-2, 21-22, 3-6; SPEC §4).

    Args:
        control: gains and limits.
        mk: ``signs``, ``counts_per_rad`` and ``g_mps2``.
        state: the previous step's state (``PositionState()`` to start).
        x_sp_m: position set-point x in W (m).
        y_sp_m: position set-point y in W (m).
        x_m: estimated position x in W (m).
        y_m: estimated position y in W (m).
        vx_mps: estimated world velocity x (m/s, eq 15).
        vy_mps: estimated world velocity y (m/s, eq 16).
        yaw_rad: estimated heading psi (clockwise, rad).
        dt_s: seconds since the previous step (from timestamps).
        ff_ax_w_mps2: acceleration feed-forward in W (m/s^2): countering the turbulence
            the estimator sees (``control.disturbance_ff``); non-finite: 0.
        ff_ay_w_mps2: the same along y.

    Returns:
        The result, or None if any input is non-finite (the state is then unchanged and
        the caller keeps it).
    """
    if not all_finite(x_sp_m, y_sp_m, x_m, y_m, vx_mps, vy_mps, yaw_rad):
        return None
    g = mk.g_mps2
    pg = position_gains(control)
    px = pid_update(pg, state.pos_x, error=x_sp_m - x_m, measurement=x_m, dt_s=dt_s, rate=vx_mps)
    py = pid_update(pg, state.pos_y, error=y_sp_m - y_m, measurement=y_m, dt_s=dt_s, rate=vy_mps)
    if not (px.valid and py.valid):
        return None
    vsx, vsy, _ = clamp_norm(px.output, py.output, control.max_speed_mps)

    vg = velocity_gains(control, g)
    ffx = ff_ax_w_mps2 if math.isfinite(ff_ax_w_mps2) else 0.0
    ffy = ff_ay_w_mps2 if math.isfinite(ff_ay_w_mps2) else 0.0
    ax = pid_update(
        vg, state.vel_x, error=vsx - vx_mps, measurement=vx_mps, dt_s=dt_s, feedforward=ffx
    )
    ay = pid_update(
        vg, state.vel_y, error=vsy - vy_mps, measurement=vy_mps, dt_s=dt_s, feedforward=ffy
    )
    if not (ax.valid and ay.valid):
        return None
    abx, aby = world_to_body(ax.output, ay.output, yaw_rad)
    pitch, roll, clamped = clamp_norm(-abx / g, aby / g, control.max_tilt_rad)
    return PositionResult(
        vel_sp_x_mps=vsx,
        vel_sp_y_mps=vsy,
        acc_x_w_mps2=ax.output,
        acc_y_w_mps2=ay.output,
        acc_x_b_mps2=abx,
        acc_y_b_mps2=aby,
        pitch_sp_rad=pitch,
        roll_sp_rad=roll,
        tilt_clamped=clamped,
        nick_counts=angle_to_counts(pitch, mk.signs.nick, mk.counts_per_rad),
        roll_counts=angle_to_counts(roll, mk.signs.roll, mk.counts_per_rad),
        state=PositionState(px.state, py.state, ax.state, ay.state),
    )
