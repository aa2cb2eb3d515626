"""PP parameters and the conversions to SI (``protocols/scip2.md`` §3.3, §5; SPEC §1-2)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.errors import ProtocolError
from mkflight.urg.replies import InfoReply, ReplyParser
from mkflight.urg.units import (
    URG_04LX,
    TimestampUnwrapper,
    parse_params,
    ranges_m,
    step_body_angle_rad,
    unwrap_timestamp_ms,
    value_steps,
)
from tests.urg.vectors import ALL_VECTORS, ExchangeVector

WRAP = 1 << 24


def pp_info() -> dict[str, str]:
    vector = ALL_VECTORS["SC-04"]
    assert isinstance(vector, ExchangeVector)
    (reply,) = ReplyParser().feed(vector.reply)
    assert isinstance(reply, InfoReply)
    return reply.info


def test_pp_of_a_urg_04lx() -> None:
    params = parse_params(pp_info())
    assert params == URG_04LX
    assert params.scan_period_ns == 100_000_000
    assert params.step_angle_rad == pytest.approx(0.0061359, abs=1e-7)
    assert params.step_offset_ns(44) == 4_296_875
    assert params.step_offset_ns(725) == pytest.approx(70.8e6, rel=1e-3)


@pytest.mark.parametrize("key", ["DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN"])
def test_pp_requires_every_numeric_key(key: str) -> None:
    info = pp_info()
    del info[key]
    with pytest.raises(ProtocolError, match=f"PP reply lacks {key}"):
        parse_params(info)
    info[key] = "many"
    with pytest.raises(ProtocolError, match=f"PP {key} = 'many' is not an integer"):
        parse_params(info)


def test_pp_rejects_contradictions() -> None:
    with pytest.raises(ProtocolError, match="DMIN = 6000 is not below"):
        parse_params(pp_info() | {"DMIN": "6000"})
    with pytest.raises(ProtocolError, match="AFRT = 800 outside"):
        parse_params(pp_info() | {"AFRT": "800"})
    with pytest.raises(ProtocolError, match="must be positive"):
        parse_params(pp_info() | {"SCAN": "0"})


def test_error_codes_and_out_of_range_are_nan() -> None:
    out = ranges_m([0, 1, 7, 19, 20, 1234, 5600, 5601, 60000])
    assert out[4:7] == [0.02, 1.234, 5.6]
    assert all(math.isnan(v) for v in out[:4] + out[7:])


def test_step_angles_in_the_body_frame() -> None:
    assert step_body_angle_rad(44) == pytest.approx(2.086214, abs=1e-6)
    assert step_body_angle_rad(384) == 0.0
    assert step_body_angle_rad(725) == pytest.approx(-2.092350, abs=1e-6)
    assert step_body_angle_rad(127) > math.pi / 2  # the hat looks right and a bit back


def test_value_steps_are_cluster_centres() -> None:
    assert value_steps(380, 383, 1) == [380, 381, 382, 383]
    assert value_steps(380, 383, 0) == [380, 381, 382, 383]
    assert value_steps(380, 403, 3)[:2] == [381.0, 384.0]
    assert value_steps(380, 384, 3) == [381.0, 383.5]


def test_unwrap_over_the_24_bit_wrap() -> None:
    clock = TimestampUnwrapper()
    stamps = [WRAP - 150, WRAP - 50, 50, 150, 100, 250]
    assert [clock.unwrap(s) for s in stamps] == [
        WRAP - 150,
        WRAP - 50,
        WRAP + 50,
        WRAP + 150,
        WRAP + 100,  # a late, older stamp stays in the new epoch
        WRAP + 250,
    ]
    assert clock.wraps == 1
    clock.reset()  # RS: the timer restarts at 0
    assert clock.unwrap(3) == 3
    assert unwrap_timestamp_ms(WRAP - 10, 5) == -10


@given(st.integers(0, 10 * WRAP), st.integers(-(WRAP // 2) + 1, WRAP // 2 - 1))
def test_unwrap_recovers_any_step_below_half_a_wrap(previous: int, step: int) -> None:
    assert unwrap_timestamp_ms((previous + step) % WRAP, previous) == previous + step
