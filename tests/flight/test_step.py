"""FlightCore: whatever comes in, every command goes out within its limits (SPEC §4-5)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.config import Config
from mkflight.control.descent import DescentParams
from mkflight.control.limits import command_within_limits
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.flight.step import MAX_HOLD_OFFSET_M, FlightCore
from mkflight.msgs import ImuSample, Pose2D
from mkflight.safety.failsafe import FailsafeAction

#: How long a landing without the hat may last before control goes to the pilot.
DESCENT_MAX_S = DescentParams.from_config(Config().control, Config().mk.g_mps2).max_s

CFG = Config()
STEP_NS = 53_248_000
ANY = st.floats(allow_nan=True, allow_infinity=True, width=64)
NEAR = st.floats(-2.0, 2.0)


def level_imu(t_ns: int, **overrides: float) -> ImuSample:
    values = dict(
        pitch_rad=0.0,
        roll_rad=0.0,
        yaw_rad=0.0,
        acc_x_mps2=0.0,
        acc_y_mps2=0.0,
        acc_z_mps2=-9.81,
        battery_v=12.0,
    )
    values.update(overrides)
    return ImuSample(t_ns=t_ns, gas_counts=100, receiver_level=200, **values)


def fly_to_hold(core: FlightCore) -> int:
    """Feed a vehicle that rises as commanded (just enough for the phases to reach HOLD)."""
    t_ns, height = 0, 0.0
    for _ in range(200):
        t_ns += STEP_NS
        if t_ns % (2 * STEP_NS) == 0:
            core.laser_step(Pose2D(t_ns, 0.0, 0.0, 0.0), height, t_ns=t_ns)
        out = core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=t_ns > 1e9))
        if out.phase is Phase.TAKEOFF:
            height = min(0.6, height + 0.3 * STEP_NS * 1e-9)
        if out.phase is Phase.HOLD:
            return t_ns
    raise AssertionError("never reached HOLD")


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            ANY, ANY, ANY, ANY, ANY, ANY, ANY, st.one_of(st.none(), st.tuples(ANY, ANY, ANY)), ANY
        ),
        min_size=1,
        max_size=30,
    )
)
def test_every_command_is_within_limits_whatever_the_inputs(
    steps: list[
        tuple[
            float,
            float,
            float,
            float,
            float,
            float,
            float,
            tuple[float, float, float] | None,
            float,
        ]
    ],
) -> None:
    core = FlightCore(CFG)
    t_ns = fly_to_hold(core)
    for pitch, roll, yaw, ax, ay, az, volts, pose, height in steps:
        t_ns += STEP_NS
        if pose is not None:
            core.laser_step(Pose2D(t_ns - 100_000_000, *pose), height, t_ns=t_ns - 100_000_000)
        imu = level_imu(
            t_ns, pitch_rad=pitch, roll_rad=roll, yaw_rad=yaw, acc_x_mps2=ax,
            acc_y_mps2=ay, acc_z_mps2=az, battery_v=volts,
        )  # fmt: skip
        out = core.imu_step(imu, PhaseRequests(takeoff=True, handshake_ok=True))
        assert command_within_limits(
            out.command, CFG.control, counts_per_rad=CFG.mk.counts_per_rad
        ), out.command
        assert 0 <= out.command.gas_counts <= CFG.control.gas_max
        assert math.isfinite(out.estimate.x_m)


def test_nonfinite_steps_send_the_last_safe_command_then_land() -> None:
    core = FlightCore(CFG)
    t_ns = fly_to_hold(core)
    last = core.last_command
    invalid_before = core.counters.invalid_steps
    actions = []
    for k in range(1, CFG.safety.nonfinite_land_steps + 1):
        t_ns += STEP_NS
        out = core.imu_step(
            level_imu(t_ns, pitch_rad=math.nan), PhaseRequests(takeoff=True, handshake_ok=True)
        )
        actions.append(out.action)
        assert core.counters.invalid_steps == invalid_before + k  # the last safe command
        assert (out.command.nick_counts, out.command.gas_counts) == (
            last.nick_counts,
            last.gas_counts,
        )
    assert actions[-1] is FailsafeAction.LAND


@given(NEAR, NEAR)
@settings(max_examples=30, deadline=None)
def test_tilt_commands_stay_within_max_tilt(x_err: float, y_err: float) -> None:
    core = FlightCore(CFG)
    t_ns = fly_to_hold(core)
    for _ in range(5):
        t_ns += STEP_NS
        core.laser_step(Pose2D(t_ns, x_err, y_err, 0.0), 0.6, t_ns=t_ns)
        out = core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True))
        tilt_rad = math.hypot(out.command.nick_counts, out.command.roll_counts) / 120.0
        assert tilt_rad <= CFG.control.max_tilt_rad + 1.5 / 120.0  # + rounding to counts


def test_hold_offset_moves_only_the_hold_setpoint_and_is_bounded() -> None:
    """The excitation offset (sim hover --excite) shifts HOLD's set-point, clamped to
    ±MAX_HOLD_OFFSET_M, a NaN counts as 0; the commanded tilt follows its direction."""
    core = FlightCore(Config())
    core.set_hold_offset(0.3, -0.2)  # before HOLD: take-off ignores it
    t_ns = fly_to_hold(core)
    assert core.active_setpoint is not None
    base_x, base_y = core.phase_state.setpoint.x_m, core.phase_state.setpoint.y_m  # type: ignore[union-attr]
    t_ns += STEP_NS
    core.laser_step(Pose2D(t_ns, 0.0, 0.0, 0.0), 0.6, t_ns=t_ns)
    out = core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True))
    assert out.phase is Phase.HOLD
    assert core.active_setpoint.x_m == base_x + 0.3
    assert core.active_setpoint.y_m == base_y - 0.2
    # Forward (+x) set-point: nose down = + nick; right (-y here: left) = + roll (SPEC §1).
    assert out.command.nick_counts > 0
    assert out.command.roll_counts > 0
    core.set_hold_offset(5.0, math.nan)
    t_ns += STEP_NS
    core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True))
    assert core.active_setpoint.x_m == base_x + MAX_HOLD_OFFSET_M
    assert core.active_setpoint.y_m == base_y


def test_a_pose_applied_after_a_debugout_gap_is_fresh() -> None:
    """After 0.5 s without DebugOut (a garbage burst on the FC's line), the poses that
    queued up are applied with the new step's time: the laser is not stale."""
    core = FlightCore(Config())
    t_ns = fly_to_hold(core)
    gap_ns = 500_000_000
    for k in range(1, 6):  # scans taken during the gap, applied when the step resumes
        core.laser_step(
            Pose2D(t_ns + k * 100_000_000, 0.0, 0.0, 0.0),
            0.6,
            t_ns=t_ns + k * 100_000_000,
            arrival_ns=t_ns + gap_ns,
        )
    out = core.imu_step(level_imu(t_ns + gap_ns), PhaseRequests(takeoff=True, handshake_ok=True))
    assert out.action is FailsafeAction.NONE
    assert out.phase is Phase.HOLD


def test_a_descent_that_finds_no_floor_hands_to_the_pilot_for_good() -> None:
    """No pose and no height while flying, and an IMU that shows the vehicle sinking
    whatever the gas (1 m/s² down): the descent finds no floor and hands control to the
    pilot in the air after DescentParams.max_s; when the laser comes back, control is NOT
    taken again."""
    core = FlightCore(Config())
    t_ns = fly_to_hold(core)
    outs = []
    for _ in range(int((DESCENT_MAX_S + 3.0) * 1e9 / STEP_NS)):  # the laser is gone
        t_ns += STEP_NS
        sinking = level_imu(t_ns, acc_z_mps2=-8.81)
        outs.append(core.imu_step(sinking, PhaseRequests(takeoff=True, handshake_ok=True)))
    assert any(o.command.take_control and o.command.gas_counts > 0 for o in outs[:20])
    assert not outs[-1].command.take_control
    assert outs[-1].phase is Phase.RELEASED
    assert any(e.reason == "handed to the pilot in the air" for o in outs for e in o.phase_events)
    assert core.handed_in_air
    assert "no floor found" in " ".join(core.counters.failsafe_events)
    for _ in range(100):  # the laser is back: still the pilot's
        t_ns += STEP_NS
        if t_ns % (2 * STEP_NS) == 0:
            core.laser_step(Pose2D(t_ns, 0.0, 0.0, 0.0), 0.6, t_ns=t_ns)
        out = core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True))
        assert not out.command.take_control
        assert out.phase is Phase.RELEASED


def test_a_vehicle_that_does_not_move_when_the_gas_falls_rests_on_the_floor() -> None:
    """No laser, and an IMU that never shows motion: the descent's probe lowers the gas,
    nothing falls, so the vehicle rests on something: LANDED, gas cut, then released."""
    core = FlightCore(Config())
    t_ns = fly_to_hold(core)
    outs = []
    for _ in range(int(DESCENT_MAX_S * 1e9 / STEP_NS)):
        t_ns += STEP_NS
        outs.append(core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True)))
    events = [e for o in outs for e in o.phase_events]
    assert any(e.to_phase is Phase.LANDED and "floor" in e.reason for e in events)
    assert outs[-1].phase is Phase.RELEASED
    assert not core.handed_in_air


def test_no_blind_command_before_control_is_taken() -> None:
    """What the link sends if the data stops: nothing while the pilot flies."""
    assert FlightCore(Config()).blind_command(12.0) is None
