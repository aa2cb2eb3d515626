"""Flight phases (SPEC §4): smooth ramps, land detection, failsafe actions, release."""

from __future__ import annotations

import itertools
import math

from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import ControlConfig
from mkflight.control.controller import ControlMode
from mkflight.control.phases import (
    Phase,
    PhaseOutput,
    PhaseParams,
    PhaseRequests,
    PhaseState,
    phase_step,
)
from mkflight.msgs import Estimate
from mkflight.safety.failsafe import FailsafeAction

P = PhaseParams.from_config(ControlConfig(), handshake_s=1.0)
MS = 1_000_000
STEP_NS = 50 * MS


def est(h: float = 0.0, vz: float = 0.0, x: float = 0.1, y: float = -0.2) -> Estimate:
    return Estimate(0, x, y, 0.3, h, 0.0, 0.0, vz)


class Run:
    """Drive the machine at 20 Hz."""

    def __init__(self) -> None:
        self.state = PhaseState()
        self.t_ns = 0
        self.out: PhaseOutput | None = None

    def step(
        self,
        e: Estimate | None = None,
        req: PhaseRequests | None = None,
        fs: FailsafeAction = FailsafeAction.NONE,
        gas: int | None = None,
        dt_ns: int = STEP_NS,
    ) -> PhaseOutput:
        self.t_ns += dt_ns
        self.out = phase_step(
            P, self.state, t_ns=self.t_ns, est=e or est(), requests=req or PhaseRequests(),
            failsafe=fs, last_gas_counts=gas,
        )  # fmt: skip
        self.state = self.out.state
        return self.out

    def phase(self) -> Phase:
        return self.state.phase

    def to_hold(self) -> None:
        self.step(req=PhaseRequests(takeoff=True))
        for _ in range(25):
            self.step(req=PhaseRequests(handshake_ok=True))
        for _ in range(60):
            self.step(e=est(h=0.3))
        assert self.phase() is Phase.HOLD


def test_a_whole_flight() -> None:
    r = Run()
    out = r.step()
    assert out.phase is Phase.PREFLIGHT
    assert not out.take_control
    assert not out.run_controllers
    out = r.step(req=PhaseRequests(takeoff=True))
    assert out.phase is Phase.HANDSHAKE
    assert not out.take_control
    for _ in range(19):  # neutral frames for >= handshake_s
        assert r.step(req=PhaseRequests(handshake_ok=True)).phase is Phase.HANDSHAKE
    out = r.step(req=PhaseRequests(handshake_ok=True))
    assert out.phase is Phase.TAKEOFF
    assert out.take_control
    assert out.setpoint is not None
    assert (out.setpoint.x_m, out.setpoint.y_m, out.setpoint.yaw_rad) == (0.1, -0.2, 0.3)
    heights = [out.setpoint.height_m]
    while r.phase() is Phase.TAKEOFF:
        out = r.step()
        assert out.setpoint is not None
        heights.append(out.setpoint.height_m)
        assert len(heights) < 100
    assert out.phase is Phase.HOLD
    assert heights[-1] == P.takeoff_height_m
    steps = [b - a for a, b in itertools.pairwise(heights)]
    assert max(steps) <= P.climb_mps * 0.05 + 1e-12
    assert min(steps) >= 0.0
    # ~0.6 m at 0.3 m/s = 2 s = 40 steps.
    assert 38 <= len(steps) <= 42

    out = r.step(req=PhaseRequests(land=True), e=est(h=0.6))
    assert out.phase is Phase.LAND
    assert out.setpoint is not None
    prev = out.setpoint.height_m
    for _ in range(10):
        out = r.step(e=est(h=0.5, vz=-0.3), gas=90)
        assert out.setpoint is not None
        assert 0 < prev - out.setpoint.height_m <= P.land_mps * 0.05 + 1e-12
        assert out.setpoint.climb_ff_mps == -P.land_mps
        prev = out.setpoint.height_m
    # On the ground: height below land_detect_height_m for land_detect_s.
    for _ in range(20):
        assert r.step(e=est(h=0.01), gas=90).phase is Phase.LAND
    out = r.step(e=est(h=0.01), gas=90)
    assert out.phase is Phase.LANDED
    assert out.gas_cut
    assert out.take_control
    assert not out.run_controllers
    for _ in range(20):
        out = r.step(e=est(h=0.01))
    assert out.phase is Phase.RELEASED
    assert not out.take_control


def test_land_detector_by_low_gas_and_no_descent() -> None:
    r = Run()
    r.to_hold()
    r.step(req=PhaseRequests(land=True))
    for _ in range(21):  # 0.15 m up (a box under the hat?), still, gas at the bottom
        r.step(e=est(h=0.15, vz=0.0), gas=20)
    assert r.phase() is Phase.LANDED


def test_land_detector_needs_continuous_time() -> None:
    r = Run()
    r.to_hold()
    r.step(req=PhaseRequests(land=True))
    for i in range(60):
        h = 0.01 if i % 10 else 0.3  # bounces out every 0.5 s
        r.step(e=est(h=h, vz=-0.2), gas=100)
    assert r.phase() is Phase.LAND


def test_descent_setpoint_is_floored() -> None:
    r = Run()
    r.to_hold()
    r.step(req=PhaseRequests(land=True))
    for _ in range(200):
        out = r.step(e=est(h=0.5, vz=-0.3), gas=100)
    assert out.setpoint is not None
    assert out.setpoint.height_m == P.land_floor_m
    assert out.setpoint.climb_ff_mps == 0.0


def test_failsafe_actions_drive_the_phases() -> None:
    r = Run()
    r.step(req=PhaseRequests(takeoff=True))
    for _ in range(21):
        r.step(req=PhaseRequests(handshake_ok=True))
    assert r.phase() is Phase.TAKEOFF
    assert r.state.setpoint is not None
    h0 = r.state.setpoint.height_m
    out = r.step(fs=FailsafeAction.HOLD)  # the ramp freezes
    assert out.setpoint is not None
    assert out.setpoint.height_m == h0
    assert out.setpoint.climb_ff_mps == 0.0
    out = r.step(fs=FailsafeAction.LEVEL_HOLD)
    assert out.mode is ControlMode.LEVEL
    assert out.run_controllers
    out = r.step(fs=FailsafeAction.LAND)
    assert out.phase is Phase.LAND
    assert out.events[0].reason == "failsafe land"
    out = r.step(fs=FailsafeAction.RELEASE)
    assert out.phase is Phase.RELEASED
    assert not out.take_control


def test_no_takeoff_under_failsafe_and_land_before_takeoff_releases() -> None:
    r = Run()
    r.step(req=PhaseRequests(takeoff=True), fs=FailsafeAction.HOLD)
    assert r.phase() is Phase.PREFLIGHT
    r.step(req=PhaseRequests(takeoff=True))
    for _ in range(30):
        r.step(req=PhaseRequests(handshake_ok=True), fs=FailsafeAction.WARN)
    assert r.phase() is Phase.TAKEOFF  # WARN does not block
    r2 = Run()
    r2.step(req=PhaseRequests(takeoff=True))
    assert r2.step(fs=FailsafeAction.LAND).phase is Phase.RELEASED


def test_handshake_waits_for_confirms_and_a_finite_estimate() -> None:
    r = Run()
    r.step(req=PhaseRequests(takeoff=True))
    for _ in range(40):
        r.step()
    assert r.phase() is Phase.HANDSHAKE
    for _ in range(5):
        r.step(e=est(h=math.nan), req=PhaseRequests(handshake_ok=True))
    assert r.phase() is Phase.HANDSHAKE
    r.step(req=PhaseRequests(handshake_ok=True))
    assert r.phase() is Phase.TAKEOFF


@given(
    st.lists(
        st.tuples(
            st.integers(-(10**9), 10**10),
            st.sampled_from(list(FailsafeAction)),
            st.booleans(),
            st.floats(allow_nan=True, allow_infinity=True),
        ),
        max_size=80,
    )
)
def test_setpoints_never_step(steps: list[tuple[int, FailsafeAction, bool, float]]) -> None:
    r = Run()
    r.step(req=PhaseRequests(takeoff=True))
    for _ in range(21):
        r.step(req=PhaseRequests(handshake_ok=True))
    max_rate = max(P.climb_mps, P.land_mps)
    prev = r.state.setpoint
    assert prev is not None
    for dt_ns, fs, land, h in steps:
        out = r.step(e=est(h=h), fs=fs, req=PhaseRequests(land=land), dt_ns=dt_ns, gas=50)
        sp = r.state.setpoint
        assert sp is not None
        assert (sp.x_m, sp.y_m, sp.yaw_rad) == (prev.x_m, prev.y_m, prev.yaw_rad)
        assert abs(sp.height_m - prev.height_m) <= max_rate * P.max_step_dt_s + 1e-12
        assert math.isfinite(sp.height_m)
        if out.setpoint is not None:
            assert out.run_controllers
        prev = sp
