"""Tests of mkflight.msgs: what the flight accepts of a DebugOut sample."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from mkflight.msgs import MAX_ABS_ACC_MPS2, MAX_ABS_ANGLE_RAD, ImuSample, plausible_imu

ANY = st.floats(allow_nan=True, allow_infinity=True)


def _imu(p: float, r: float, ax: float, ay: float, az: float) -> ImuSample:
    return ImuSample(1, p, r, 0.5, ax, ay, az, 12.0)


def test_a_real_sample_passes_unchanged() -> None:
    imu = _imu(0.1, -0.2, 0.3, -0.4, -9.81)
    assert plausible_imu(imu) is imu


def test_finite_absurd_values_become_nan() -> None:
    # the fault campaign's huge-estimate: 1e300 passes isfinite, so it must not pass here
    out = plausible_imu(_imu(1e300, 1e300, 1e300, -1e300, -9.81))
    assert math.isnan(out.pitch_rad)
    assert math.isnan(out.roll_rad)
    assert math.isnan(out.acc_x_mps2)
    assert math.isnan(out.acc_y_mps2)
    assert out.acc_z_mps2 == -9.81  # the plausible field is kept


@given(ANY, ANY, ANY, ANY, ANY)
def test_every_field_is_nan_or_within_its_range(
    p: float, r: float, ax: float, ay: float, az: float
) -> None:
    out = plausible_imu(_imu(p, r, ax, ay, az))
    for before, after, bound in (
        (p, out.pitch_rad, MAX_ABS_ANGLE_RAD),
        (r, out.roll_rad, MAX_ABS_ANGLE_RAD),
        (ax, out.acc_x_mps2, MAX_ABS_ACC_MPS2),
        (ay, out.acc_y_mps2, MAX_ABS_ACC_MPS2),
        (az, out.acc_z_mps2, MAX_ABS_ACC_MPS2),
    ):
        if abs(before) <= bound:
            assert after == before
        else:
            assert math.isnan(after)
    assert (out.t_ns, out.yaw_rad, out.battery_v) == (1, 0.5, 12.0)
