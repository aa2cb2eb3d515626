"""The failsafe (SPEC §5): each table row -> its action, latched, with its cause."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import SafetyConfig
from mkflight.safety import (
    Cause,
    Failsafe,
    FailsafeAction,
    FailsafeInputs,
    FailsafeOutput,
    StopRequest,
)
from mkflight.safety.failsafe import LASER_CAUSE_FLOOR_M

A = FailsafeAction
S = SafetyConfig()
MS = 1_000_000
STEP_NS = 50 * MS
OK = FailsafeInputs(t_ns=0, battery_v=12.4)


class Run:
    def __init__(self) -> None:
        self.fs = Failsafe(S)
        self.t_ns = 0
        self.events: list[tuple[A, Cause]] = []

    def step(self, **kw: object) -> FailsafeOutput:
        self.t_ns += STEP_NS
        inp = msgspec.structs.replace(OK, t_ns=self.t_ns, **kw)
        out = self.fs.update(inp)
        for e in out.events:
            assert e.t_ns == self.t_ns
            assert e.overall == out.action
            self.events.append((e.action, e.cause))
        return out

    def steps(self, n: int, **kw: object) -> FailsafeOutput:
        out = self.step(**kw)
        for _ in range(n - 1):
            out = self.step(**kw)
        return out


def test_all_healthy_is_none() -> None:
    out = Run().steps(100)
    assert out.action is A.NONE
    assert out.causes == ()
    assert out.events == ()
    assert not out.use_last_command


# Rows with a fixed action: (inputs, cause, action).
FIXED_ROWS = [
    ({"values_finite": False}, Cause.NONFINITE, A.WARN),
    ({"stop": StopRequest.SIGINT}, Cause.STOP_SIGINT, A.LAND),
    ({"stop": StopRequest.SIGTERM}, Cause.STOP_SIGTERM, A.LAND),
    ({"stop": StopRequest.DURATION}, Cause.STOP_DURATION, A.LAND),
    ({"stop": StopRequest.CRASH}, Cause.STOP_CRASH, A.LAND),
    ({"pilot_override": True}, Cause.PILOT_OVERRIDE, A.RELEASE),
]


@pytest.mark.parametrize(("bad", "cause", "action"), FIXED_ROWS)
def test_fixed_rows_act_at_once_and_latch(bad: dict[str, object], cause: Cause, action: A) -> None:
    r = Run()
    r.steps(3)
    out = r.step(**bad)
    assert out.action is action
    assert (cause, action) in out.causes
    assert (action, cause) in r.events
    out = r.steps(100)  # the condition is gone: still latched, no new events
    assert out.action is action
    assert (cause, action) in out.causes
    assert out.events == ()


# Rows that escalate: (inputs, cause, first action, delay_s, second action).
TIMED_ROWS = [
    ({"laser_age_s": 0.31}, Cause.LASER_STALE, A.LEVEL_HOLD, S.degenerate_land_s, A.LAND),
    ({"laser_age_s": math.inf}, Cause.LASER_STALE, A.LEVEL_HOLD, S.degenerate_land_s, A.LAND),
    ({"scan_degenerate": True}, Cause.SCAN_DEGENERATE, A.LEVEL_HOLD, S.degenerate_land_s, A.LAND),
    ({"x_m": S.box_m + 0.01}, Cause.OUT_OF_BOX, A.HOLD, 1.0, A.LAND),
    ({"y_m": -S.box_m - 0.01}, Cause.OUT_OF_BOX, A.HOLD, 1.0, A.LAND),
    ({"height_m": S.max_height_m + 0.01}, Cause.ABOVE_MAX_HEIGHT, A.HOLD, 1.0, A.LAND),
]


@pytest.mark.parametrize(("bad", "cause", "first", "delay_s", "second"), TIMED_ROWS)
@pytest.mark.parametrize("persists", [True, False])
def test_timed_rows_escalate_and_latch(
    bad: dict[str, object], cause: Cause, first: A, delay_s: float, second: A, persists: bool
) -> None:
    r = Run()
    r.steps(3)
    out = r.step(**bad)
    assert out.action is first
    assert out.causes == ((cause, first),)
    n = round(delay_s / 0.05)
    out = r.steps(n - 1, **(bad if persists else {}))
    assert out.action is first  # latched even if the condition cleared
    out = r.step(**(bad if persists else {}))
    assert out.action is second
    assert out.causes == ((cause, second),)
    assert r.events == [(first, cause), (second, cause)]
    assert r.steps(50).action is second


def test_box_is_centred_on_home() -> None:
    r = Run()
    r.fs.set_home(1.5, -1.0)
    assert r.step(x_m=3.0, y_m=-2.5).action is A.NONE
    assert r.step(x_m=3.6, y_m=-1.0).action is A.HOLD


def test_nonfinite_three_consecutive_steps_land() -> None:
    r = Run()
    out = r.step(values_finite=False)
    assert out.use_last_command
    assert out.action is A.WARN
    out = r.step(values_finite=False)
    assert out.use_last_command
    assert out.action is A.WARN
    out = r.step(values_finite=False)
    assert out.nonfinite_steps == S.nonfinite_land_steps
    assert out.action is A.LAND
    assert (Cause.NONFINITE_REPEATED, A.LAND) in out.causes
    assert not r.step().use_last_command
    assert r.steps(20).action is A.LAND


def test_nonfinite_must_be_consecutive() -> None:
    r = Run()
    for _ in range(10):
        r.steps(2, values_finite=False)
        out = r.step()
    assert out.action is A.WARN
    assert out.nonfinite_steps == 0


def test_battery_is_sag_filtered_then_latched() -> None:
    r = Run()
    r.steps(20, battery_v=12.0)
    out = r.steps(3, battery_v=9.0)  # a 150 ms sag under a gust: filtered out
    assert out.action is A.NONE
    out = r.steps(20, battery_v=12.0)
    assert out.battery_filtered_v > 11.5
    out = r.steps(200, battery_v=10.6)  # 10 s below warn
    assert out.action is A.WARN
    assert (Cause.BATTERY_WARN, A.WARN) in out.causes
    out = r.steps(200, battery_v=10.0)
    assert out.action is A.LAND
    assert (Cause.BATTERY_LOW, A.LAND) in out.causes
    assert r.steps(400, battery_v=12.6).action is A.LAND  # recovery does not unlatch
    assert r.events == [(A.WARN, Cause.BATTERY_WARN), (A.LAND, Cause.BATTERY_LOW)]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, 0.0])
def test_bad_battery_samples_are_ignored(bad: float) -> None:
    r = Run()
    r.steps(5, battery_v=12.0)
    out = r.steps(50, battery_v=bad)
    assert out.battery_filtered_v == pytest.approx(12.0)
    assert out.action is A.NONE


def test_filter_time_constant() -> None:
    fs = Failsafe(S)
    fs.update(FailsafeInputs(t_ns=0, battery_v=12.0))
    out = fs.update(FailsafeInputs(t_ns=round(S.voltage_filter_s * 1e9), battery_v=11.0))
    assert out.battery_filtered_v == pytest.approx(12.0 - (1 - math.exp(-1)))


def test_most_severe_wins_and_every_cause_is_listed() -> None:
    r = Run()
    r.step(laser_age_s=1.0)
    r.step(x_m=5.0)
    out = r.step(pilot_override=True, stop=StopRequest.SIGINT)
    assert out.action is A.RELEASE
    assert [c for c, _ in out.causes] == [
        Cause.PILOT_OVERRIDE,
        Cause.STOP_SIGINT,
        Cause.LASER_STALE,
        Cause.OUT_OF_BOX,
    ]


def test_landed_clears_the_latches() -> None:
    r = Run()
    r.step(stop=StopRequest.SIGTERM)
    r.step(values_finite=False)
    r.fs.landed()
    out = r.step()
    assert out.action is A.NONE
    assert out.causes == ()
    assert out.nonfinite_steps == 0


def test_nonfinite_position_skips_the_box_check() -> None:
    out = Run().step(x_m=math.nan, y_m=math.inf, height_m=math.nan)
    assert out.action is A.NONE


@given(
    st.lists(
        st.fixed_dictionaries(
            {
                "values_finite": st.booleans(),
                "laser_age_s": st.floats(allow_nan=True, allow_infinity=True),
                "scan_degenerate": st.booleans(),
                "x_m": st.floats(allow_nan=True, allow_infinity=True),
                "y_m": st.floats(allow_nan=True, allow_infinity=True),
                "height_m": st.floats(allow_nan=True, allow_infinity=True),
                "battery_v": st.floats(allow_nan=True, allow_infinity=True),
                "stop": st.one_of(st.none(), st.sampled_from(list(StopRequest))),
                "pilot_override": st.booleans(),
            }
        ),
        max_size=40,
    )
)
def test_latched_action_never_decreases(steps: list[dict[str, object]]) -> None:
    r = Run()
    prev = A.NONE
    seen: dict[Cause, A] = {}
    for kw in steps:
        out = r.step(**kw)
        assert out.action >= prev
        raised = {e.cause for e in out.events if e.action is A.LEVEL_HOLD}
        low = kw["height_m"] < LASER_CAUSE_FLOOR_M  # type: ignore[operator]
        if prev >= A.LAND and low:  # a landing near the floor keeps the laser's causes out
            assert not raised & {Cause.LASER_STALE, Cause.SCAN_DEGENERATE}
        assert out.action == max((a for _, a in out.causes), default=A.NONE)
        for cause, action in out.causes:
            assert action >= seen.get(cause, A.NONE)
            seen[cause] = action
        assert set(seen) == {c for c, _ in out.causes}
        assert math.isnan(out.battery_filtered_v) or math.isfinite(out.battery_filtered_v)
        prev = out.action


def test_a_laser_cause_in_a_landing_is_not_raised() -> None:
    """A recorded touchdown (hover, ``--duration 20``): the stop lands the vehicle, and at
    0.06-0.03 m the tilted scan plane meets the floor: the scans 1.3 s later fail (invalid,
    degenerate, invalid), the pose ages past ``laser_stale_s`` while it touches down. The
    landing goes on as it was: only the stop is in the list."""
    r = Run()
    r.steps(20, height_m=0.6)
    r.step(height_m=0.6, stop=StopRequest.DURATION)
    out = r.steps(26, height_m=0.05)  # 1.3 s of descent, poses fresh
    out = r.step(height_m=0.03, scan_degenerate=True)
    out = r.steps(3, height_m=0.0, laser_age_s=0.35)
    assert out.action is A.LAND
    assert r.events == [(A.LAND, Cause.STOP_DURATION)]
    assert [c for c, _ in out.causes] == [Cause.STOP_DURATION]


@pytest.mark.parametrize("bad", [{"laser_age_s": 1.0}, {"scan_degenerate": True}])
def test_a_laser_cause_raised_before_the_landing_stays_and_escalates(
    bad: dict[str, object],
) -> None:
    r = Run()
    r.step(**bad)
    r.step(stop=StopRequest.SIGTERM, **bad)
    out = r.steps(round(S.degenerate_land_s * 1e9 / STEP_NS), **bad)
    cause = Cause.LASER_STALE if "laser_age_s" in bad else Cause.SCAN_DEGENERATE
    assert (A.LEVEL_HOLD, cause) in r.events
    assert (A.LAND, cause) in r.events
    assert dict(out.causes)[cause] is A.LAND


@pytest.mark.parametrize("action_cause", [{"stop": StopRequest.SIGINT}, {"battery_v": 9.0}])
def test_a_laser_cause_after_any_land_is_not_raised(action_cause: dict[str, object]) -> None:
    r = Run()
    r.steps(5, **action_cause)
    assert r.fs.action is A.LAND
    out = r.steps(40, laser_age_s=math.inf, scan_degenerate=True, height_m=0.2)
    assert not {Cause.LASER_STALE, Cause.SCAN_DEGENERATE} & {c for c, _ in out.causes}
    assert out.action is A.LAND


@pytest.mark.parametrize("height_m", [LASER_CAUSE_FLOOR_M, 1.0, math.nan])
def test_a_laser_that_dies_higher_up_in_a_landing_is_in_the_record(height_m: float) -> None:
    """Above the floor (or with no height) a landing does not hide a dead laser."""
    r = Run()
    r.steps(5, stop=StopRequest.SIGINT, height_m=height_m)
    out = r.step(laser_age_s=math.inf, height_m=height_m)
    assert (A.LEVEL_HOLD, Cause.LASER_STALE) in r.events
    assert out.action is A.LAND


def test_a_laser_cause_below_land_is_raised_as_before() -> None:
    """An out-of-box HOLD (below LAND) does not keep the laser's causes out."""
    r = Run()
    r.step(x_m=5.0)
    out = r.step(x_m=5.0, laser_age_s=1.0)
    assert out.action is A.LEVEL_HOLD
    assert (A.LEVEL_HOLD, Cause.LASER_STALE) in r.events
