"""The PID (SPEC §4): derivative on measurement, separate clamps, dt guards, NaN safety."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.control.pid import PidGains, PidState, pid_reset, pid_update

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)


def test_proportional_only() -> None:
    res = pid_update(PidGains(kp=2.0), PidState(), error=1.5, measurement=0.0, dt_s=0.1)
    assert res.valid
    assert res.output == pytest.approx(3.0)
    assert res.i == 0.0
    assert res.d == 0.0


def test_derivative_is_on_measurement_not_error() -> None:
    gains = PidGains(kp=0.0, kd=1.0)
    s = pid_update(gains, PidState(), error=0.0, measurement=1.0, dt_s=0.1).state
    # A set-point step (error jumps) with a constant measurement: no derivative kick.
    res = pid_update(gains, s, error=10.0, measurement=1.0, dt_s=0.1)
    assert res.d == 0.0
    # The measurement rising by 0.2 in 0.1 s: d = -kd * 2.
    res = pid_update(gains, res.state, error=10.0, measurement=1.2, dt_s=0.1)
    assert res.d == pytest.approx(-2.0)


def test_measured_rate_replaces_differencing() -> None:
    res = pid_update(PidGains(kp=0.0, kd=0.5), PidState(), error=0, measurement=3, dt_s=0, rate=4)
    assert res.d == pytest.approx(-2.0)


def test_angle_derivative_wraps_across_pi() -> None:
    gains = PidGains(kp=0.0, kd=1.0, angle=True)
    s = pid_update(gains, PidState(), error=0.0, measurement=math.radians(179), dt_s=0.1).state
    res = pid_update(gains, s, error=0.0, measurement=math.radians(-179), dt_s=0.1)
    assert res.d == pytest.approx(-math.radians(2) / 0.1)


def test_integral_clamp_is_separate_from_output_clamp() -> None:
    gains = PidGains(kp=0.0, ki=1.0, integral_limit=0.5, output_min=-10, output_max=10)
    s = PidState()
    for _ in range(100):
        res = pid_update(gains, s, error=1.0, measurement=0.0, dt_s=0.1)
        s = res.state
    assert s.integral == pytest.approx(0.5)
    assert res.output == pytest.approx(0.5)
    # And an output clamp tighter than the integral's.
    gains = PidGains(kp=5.0, ki=1.0, integral_limit=3.0, output_min=-1, output_max=1)
    res = pid_update(gains, PidState(), error=1.0, measurement=0.0, dt_s=0.1)
    assert res.output == 1.0
    assert res.saturation == 1


def test_anti_windup_stops_integration_while_saturated_same_direction() -> None:
    gains = PidGains(kp=10.0, ki=1.0, integral_limit=100, output_min=-1, output_max=1)
    s = PidState(integral=0.2)
    res = pid_update(gains, s, error=1.0, measurement=0.0, dt_s=0.1)
    assert res.saturation == 1
    assert res.state.integral == pytest.approx(0.2)  # not wound up
    # Saturated low with a positive error: integrating unwinds, so it is allowed.
    s = PidState(integral=-5.0)
    res = pid_update(gains, s, error=0.05, measurement=0.0, dt_s=0.1)
    assert res.saturation == -1
    assert res.state.integral == pytest.approx(-5.0 + 0.005)


def test_without_anti_windup_the_integral_winds_up_to_its_clamp() -> None:
    gains = PidGains(kp=10.0, ki=1.0, integral_limit=0.3, output_max=1, anti_windup=False)
    s = PidState()
    for _ in range(10):
        s = pid_update(gains, s, error=1.0, measurement=0.0, dt_s=0.1).state
    assert s.integral == pytest.approx(0.3)


@pytest.mark.parametrize("dt_s", [0.0, -0.05, math.nan, math.inf, -math.inf])
def test_bad_dt_means_no_integration_and_no_derivative(dt_s: float) -> None:
    gains = PidGains(kp=1.0, ki=1.0, kd=1.0)
    s = PidState(integral=0.1, prev_measurement=0.0)
    res = pid_update(gains, s, error=2.0, measurement=5.0, dt_s=dt_s)
    assert res.valid
    assert res.d == 0.0
    assert res.state.integral == 0.1
    assert res.output == pytest.approx(2.1)


@pytest.mark.parametrize("field", ["error", "measurement", "rate", "feedforward"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_input_leaves_state_unchanged_and_is_invalid(field: str, bad: float) -> None:
    gains = PidGains(kp=1.0, ki=1.0, kd=1.0)
    s = PidState(integral=0.25, prev_measurement=1.0)
    kwargs: dict[str, float] = {"error": 1.0, "measurement": 1.0, "rate": 0.0, "feedforward": 0.0}
    kwargs[field] = bad
    res = pid_update(gains, s, dt_s=0.1, **kwargs)
    assert not res.valid
    assert math.isnan(res.output)
    assert res.state is s


def test_reset() -> None:
    assert pid_reset() == PidState()
    assert pid_reset(0.4).integral == 0.4
    assert pid_reset(math.nan).integral == 0.0


@given(st.lists(st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT), max_size=30))
def test_nan_never_enters_the_state_and_output_is_clamped(
    steps: list[tuple[float, float, float]],
) -> None:
    gains = PidGains(kp=3.0, ki=2.0, kd=0.5, integral_limit=4.0, output_min=-7, output_max=9)
    s = PidState()
    for error, meas, dt_s in steps:
        res = pid_update(gains, s, error=error, measurement=meas, dt_s=dt_s)
        s = res.state
        assert math.isfinite(s.integral)
        assert abs(s.integral) <= 4.0
        assert s.prev_measurement is None or math.isfinite(s.prev_measurement)
        if res.valid:
            assert -7 <= res.output <= 9
        else:
            assert math.isnan(res.output)
