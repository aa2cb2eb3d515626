"""The controller: every command within its limits, or flagged invalid (SPEC §4-5)."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import ControlConfig, MkConfig
from mkflight.control.controller import Controller, ControlMode, Setpoint
from mkflight.control.limits import command_within_limits
from mkflight.msgs import Estimate

CTRL = ControlConfig()
MK = MkConfig()
ANY = st.floats(allow_nan=True, allow_infinity=True)
SMALLISH = st.one_of(st.floats(-100, 100), st.sampled_from([math.nan, math.inf, -math.inf]))


FIELDS = ("x_m", "y_m", "yaw_rad", "height_m", "vx_mps", "vy_mps", "vz_up_mps")


def est(**kw: float) -> Estimate:
    v = {"height_m": 0.6} | kw
    x, y, yaw, h, vx, vy, vz = (v.get(name, 0.0) for name in FIELDS)
    return Estimate(1, x, y, yaw, h, vx, vy, vz)


SP = Setpoint(x_m=0.0, y_m=0.0, yaw_rad=0.0, height_m=0.6)


def test_hover_at_setpoint_is_neutral_with_hover_gas() -> None:
    out = Controller(CTRL, MK).update(est(), SP, (0.0, 0.0), 11.8, 0.05)
    assert out.valid
    assert out.command is not None
    assert (out.command.nick_counts, out.command.roll_counts, out.command.yaw_counts) == (0, 0, 0)
    assert out.command.gas_counts == round(CTRL.hover_gas)
    assert out.command.take_control


def test_signs_through_the_controller() -> None:
    c = Controller(CTRL, MK)
    ahead = c.update(est(), Setpoint(0.3, 0.0, 0.0, 0.6), (0.0, 0.0), 11.8, 0.05)
    right = Controller(CTRL, MK).update(est(), Setpoint(0.0, 0.3, 0.0, 0.6), (0, 0), 11.8, 0.05)
    assert ahead.command is not None
    assert right.command is not None
    assert ahead.command.nick_counts > 0
    assert right.command.roll_counts < 0
    assert ahead.diagnostics is not None
    assert ahead.diagnostics.pitch_sp_rad < 0


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_estimate_is_invalid_and_state_unchanged(field: str, bad: float) -> None:
    c = Controller(CTRL, MK)
    c.update(est(x_m=0.1), SP, (0.0, 0.0), 11.8, 0.05)
    before = c.state
    out = c.update(est(**{field: bad}), SP, (0.0, 0.0), 11.8, 0.05)
    assert not out.valid
    assert out.command is None
    assert out.diagnostics is None
    assert out.invalid_inputs == (f"est.{field}",)
    assert c.state is before


@pytest.mark.parametrize(
    ("attitude", "battery", "name"),
    [((math.nan, 0.0), 11.8, "pitch_rad"), ((0.0, math.inf), 11.8, "roll_rad"),
     ((0.0, 0.0), math.nan, "battery_v"), ((0.0, 0.0), 0.0, "battery_v")],
)  # fmt: skip
def test_nonfinite_attitude_or_battery_is_invalid(
    attitude: tuple[float, float], battery: float, name: str
) -> None:
    out = Controller(CTRL, MK).update(est(), SP, attitude, battery, 0.05)
    assert not out.valid
    assert out.invalid_inputs == (name,)


def test_level_mode_ignores_position_and_gives_zero_tilt() -> None:
    bad = est(x_m=math.nan, vx_mps=math.inf, yaw_rad=0.0)
    out = Controller(CTRL, MK).update(
        bad, Setpoint(math.nan, 5.0, 0.3, 0.8), (0.0, 0.0), 11.8, 0.05, mode=ControlMode.LEVEL
    )
    assert out.valid
    assert out.command is not None
    assert (out.command.nick_counts, out.command.roll_counts) == (0, 0)
    assert out.command.yaw_counts < 0  # psi* > psi: turn right
    assert out.command.gas_counts > round(CTRL.hover_gas)  # climb to 0.8 m


def test_bad_dt_still_valid_p_only() -> None:
    out = Controller(CTRL, MK).update(est(), Setpoint(0.3, 0, 0, 0.6), (0, 0), 11.8, math.nan)
    assert out.valid


@given(
    st.lists(
        st.tuples(
            st.tuples(SMALLISH, SMALLISH, SMALLISH, SMALLISH, SMALLISH, SMALLISH, SMALLISH),
            st.tuples(SMALLISH, SMALLISH, SMALLISH, SMALLISH, SMALLISH),
            st.tuples(SMALLISH, SMALLISH),
            ANY,
            ANY,
            st.sampled_from(list(ControlMode)),
        ),
        min_size=1,
        max_size=12,
    )
)
def test_every_command_within_limits_or_invalid(
    steps: list[
        tuple[
            tuple[float, float, float, float, float, float, float],
            tuple[float, float, float, float, float],
            tuple[float, float],
            float,
            float,
            ControlMode,
        ]
    ],
) -> None:
    c = Controller(CTRL, MK)
    for e, s, att, battery, dt_s, mode in steps:
        before = c.state
        estimate = Estimate(1, *e, pose_valid=True)
        out = c.update(estimate, Setpoint(*s), att, battery, dt_s, mode=mode)
        if out.valid:
            assert out.command is not None
            assert out.diagnostics is not None
            assert command_within_limits(out.command, CTRL, counts_per_rad=MK.counts_per_rad)
            d = out.diagnostics
            assert all(math.isfinite(getattr(d, f.name)) for f in msgspec.structs.fields(d))
            assert math.hypot(d.pitch_sp_rad, d.roll_sp_rad) <= CTRL.max_tilt_rad + 1e-12
            assert 0 <= out.command.gas_counts <= CTRL.gas_max
        else:
            assert out.command is None
            assert out.diagnostics is None
            assert out.invalid_inputs
            assert c.state is before
        st_ = c.state
        for pid in (st_.position.pos_x, st_.position.vel_x, st_.yaw, st_.altitude.climb):
            assert math.isfinite(pid.integral)
