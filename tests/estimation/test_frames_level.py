"""World<->body rotation and level-frame acceleration (SPEC §1, §3; seed eq 3-6, 9-14).

Sign mapping of the seed's eq 9-14 to ours (SPEC §1). The seed's one-axis equations are
written in the MK's angle convention: its theta and phi are the MK's AngleNick and
AngleRoll, i.e. ``theta_seed = -theta`` and ``phi_seed = -phi`` (the MK's nick and roll are
the negation of our pitch and roll). Its ``a_x``, ``a_y`` are the accelerometer readings in
m/s^2. For y that is the MK's AccRoll * g / k_roll = f_y (SPEC table: ``f_y = +AccRoll g/k``).
For x the MK's AccNick * g / k_nick is ``-f_x`` (SPEC table: ``f_x = -AccNick g/k``); eq 10
holds with ``a_x = f_x``, and the appendix code, which uses the MK's AccNick, negates its
``ddotX`` to compensate (line 97). Eq 13-14's ``a_z`` is upward (eq 8 gives the upward
value), ``a_z = -f_z``, and its Q z'' is up, ``= -a_z(level, FRD)``. Eq 9-14 assume the
other axes' level accelerations are zero (hover, one tilt at a time); there they are exact
and equal to ``R_y(theta) R_x(phi) f + (0, 0, g)``.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.frames import body_to_world, level_acceleration, world_acceleration, world_to_body

G = 9.81
TILT = st.floats(-1.4, 1.4)
ANGLE = st.floats(-10.0, 10.0)
ACC = st.floats(-20.0, 20.0)
COMP = st.floats(-100.0, 100.0)


def static_specific_force(pitch: float, roll: float) -> tuple[float, float, float]:
    """SPEC §1: what a vehicle at rest reads at this tilt."""
    return (
        G * math.sin(pitch),
        -G * math.sin(roll) * math.cos(pitch),
        -G * math.cos(roll) * math.cos(pitch),
    )


def specific_force_from_level(
    a_l: tuple[float, float, float], pitch: float, roll: float
) -> tuple[float, float, float]:
    """Inverse of the level rotation, built independently: f = R_x(phi)^T R_y(theta)^T (a - g)."""
    x, y, z = a_l[0], a_l[1], a_l[2] - G
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    x1, z1 = cp * x - sp * z, sp * x + cp * z  # R_y(theta)^T
    return x1, cr * y + sr * z1, -sr * y + cr * z1  # R_x(phi)^T


@given(TILT, TILT)
def test_static_tilt_gives_zero_level_acceleration(pitch: float, roll: float) -> None:
    a = level_acceleration(*static_specific_force(pitch, roll), pitch, roll, G)
    assert a == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


@given(TILT, TILT, ANGLE)
def test_static_tilt_gives_zero_world_acceleration(pitch: float, roll: float, yaw: float) -> None:
    a = world_acceleration(*static_specific_force(pitch, roll), pitch, roll, yaw, G)
    assert a == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


@given(ACC, ACC, ACC, TILT, TILT)
def test_level_acceleration_inverts_the_attitude(
    ax: float, ay: float, az: float, pitch: float, roll: float
) -> None:
    f = specific_force_from_level((ax, ay, az), pitch, roll)
    assert level_acceleration(*f, pitch, roll, G) == pytest.approx((ax, ay, az), abs=1e-9)


def test_signs_thrust_only() -> None:
    """Nose down accelerates forward, right side down accelerates right (SPEC §1)."""
    thrust = (0.0, 0.0, -G / math.cos(0.2))
    ax, ay, az = level_acceleration(*thrust, -0.2, 0.0, G)
    assert ax > 0
    assert ay == pytest.approx(0.0)
    assert az == pytest.approx(0.0, abs=1e-12)
    ax, ay, az = level_acceleration(*(0.0, 0.0, -G / math.cos(0.2)), 0.0, 0.2, G)
    assert ay > 0
    assert ax == pytest.approx(0.0)
    ax, ay, az = level_acceleration(0.0, 0.0, -G - 1.0, 0.0, 0.0, G)
    assert az == pytest.approx(-1.0)  # a climb is negative down


def test_table_i_row_45_deg_reads_the_spec_specific_force() -> None:
    """TABLE I: pitch +45 deg (nose up, right hand) -> AccNick -432: f_x = +0.71 g = g sin 45."""
    acc_nick_counts = -432.0
    f_x = -acc_nick_counts * G / 606.3
    assert f_x == pytest.approx(static_specific_force(math.radians(45), 0.0)[0], rel=0.01)


@given(ACC, TILT)
def test_eq10_is_the_one_axis_case(a_fwd: float, pitch: float) -> None:
    f = specific_force_from_level((a_fwd, 0.0, 0.0), pitch, 0.0)
    theta_seed, a_x = -pitch, f[0]
    eq10 = (a_x + G * math.sin(theta_seed)) / math.cos(theta_seed)
    assert level_acceleration(*f, pitch, 0.0, G)[0] == pytest.approx(eq10, abs=1e-9)
    assert eq10 == pytest.approx(a_fwd, abs=1e-9)
    # The appendix, line 97, with the MK's own AccNick and AngleNick:
    acc_nick_si, mk_pitch = -f[0], -pitch
    ddot_x = -(acc_nick_si - G * math.sin(mk_pitch)) / math.cos(mk_pitch)
    assert ddot_x == pytest.approx(a_fwd, abs=1e-9)


@given(ACC, TILT)
def test_eq12_is_the_one_axis_case(a_right: float, roll: float) -> None:
    f = specific_force_from_level((0.0, a_right, 0.0), 0.0, roll)
    phi_seed, a_y = -roll, f[1]  # a_y = AccRoll * g / k = f_y
    eq12 = (a_y - G * math.sin(phi_seed)) / math.cos(phi_seed)
    assert level_acceleration(*f, 0.0, roll, G)[1] == pytest.approx(eq12, abs=1e-9)
    assert eq12 == pytest.approx(a_right, abs=1e-9)


@given(ACC, TILT, TILT)
def test_eq14_is_the_one_axis_case(a_up: float, pitch: float, roll: float) -> None:
    f = specific_force_from_level((0.0, 0.0, -a_up), pitch, roll)
    a_z = -f[2]  # eq 8's upward specific force
    eq14 = a_z / (math.cos(roll) * math.cos(pitch)) - G
    assert -level_acceleration(*f, pitch, roll, G)[2] == pytest.approx(eq14, abs=1e-9)
    assert eq14 == pytest.approx(a_up, abs=1e-9)


@given(COMP, COMP, ANGLE)
def test_world_to_body_matches_spec_formulas(x_w: float, y_w: float, yaw: float) -> None:
    c, s = math.cos(yaw), math.sin(yaw)
    assert world_to_body(x_w, y_w, yaw) == pytest.approx(
        (c * x_w + s * y_w, -s * x_w + c * y_w), abs=1e-9
    )


@given(COMP, COMP, ANGLE)
def test_world_body_round_trip(x: float, y: float, yaw: float) -> None:
    assert body_to_world(*world_to_body(x, y, yaw), yaw) == pytest.approx((x, y), abs=1e-9)
    assert world_to_body(*body_to_world(x, y, yaw), yaw) == pytest.approx((x, y), abs=1e-9)
    bx, by = world_to_body(x, y, yaw)
    assert math.hypot(bx, by) == pytest.approx(math.hypot(x, y), abs=1e-9)


def test_yaw_clockwise_examples() -> None:
    """Nose turned 90 deg right (psi = +pi/2): body forward is world right (+y)."""
    assert body_to_world(1.0, 0.0, math.pi / 2) == pytest.approx((0.0, 1.0), abs=1e-12)
    assert world_to_body(0.0, 1.0, math.pi / 2) == pytest.approx((1.0, 0.0), abs=1e-12)
    assert world_to_body(1.0, 0.0, math.pi / 2) == pytest.approx((0.0, -1.0), abs=1e-12)


def test_world_acceleration_rotates_the_level_part() -> None:
    f = specific_force_from_level((1.0, 0.0, 0.5), 0.1, -0.2)
    w = world_acceleration(*f, 0.1, -0.2, math.pi / 2, G)
    assert w == pytest.approx((0.0, 1.0, 0.5), abs=1e-9)
