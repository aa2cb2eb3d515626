"""The flight step's pure rules (SPEC §4-5), each on its own."""

from __future__ import annotations

import math

import msgspec
import pytest

from mkflight.config import Config
from mkflight.control.controller import ControlMode, ControlOutput, Setpoint
from mkflight.control.limits import command_within_limits
from mkflight.control.phases import Phase, PhaseOutput, PhaseRequests, PhaseState
from mkflight.estimation.records import LaserStep
from mkflight.flight.step import FlightCore
from mkflight.flight.step_rules import (
    TOUCHDOWN_HEIGHT_M,
    CommandChoice,
    CommandSource,
    PilotSticks,
    failsafe_inputs,
    hold_setpoint,
    laser_age_s,
    select_command,
    table3_row,
    table4_row,
    takeoff_gate,
)
from mkflight.msgs import Command, Estimate, ImuSample, Pose2D
from mkflight.safety.failsafe import FailsafeAction
from tests.flight.test_step import STEP_NS, fly_to_hold, level_imu

A = FailsafeAction
CFG = Config()
T_NS = 7_000_000_000
SP = Setpoint(0.0, 0.0, 0.0, 0.6)
LAST = Command(T_NS - STEP_NS, 3, -4, 5, 110, take_control=True)
GOOD = Command(T_NS, 1, 2, 3, 100, take_control=True)


BASE = Estimate(T_NS, 0.0, 0.0, 0.0, 0.6, 0.0, 0.0, 0.0)


def phase_out(phase: Phase, *, setpoint: Setpoint | None = SP) -> PhaseOutput:
    flying = phase in (Phase.TAKEOFF, Phase.HOLD, Phase.LAND)
    return PhaseOutput(
        state=PhaseState(phase),
        phase=phase,
        setpoint=setpoint if flying else None,
        run_controllers=flying,
        take_control=flying or phase is Phase.LANDED,
        gas_cut=phase is Phase.LANDED,
        mode=ControlMode.POSITION,
        events=(),
    )


def select(
    phase: Phase = Phase.HOLD,
    *,
    action: A = A.NONE,
    control: ControlOutput | None = None,
    use_last_command: bool = False,
    height_valid: bool = True,
    descending: bool = False,
    invalid_run: int = 0,
) -> CommandChoice:
    if control is None:
        control = ControlOutput(valid=True, command=GOOD, diagnostics=None)
    return select_command(
        T_NS,
        phase=phase_out(phase),
        setpoint=phase_out(phase).setpoint,
        action=action,
        control=control,
        use_last_command=use_last_command,
        height_valid=height_valid,
        descending=descending,
        invalid_run=invalid_run,
        nonfinite_land_steps=CFG.safety.nonfinite_land_steps,
        last=LAST,
    )


INVALID = ControlOutput(valid=False, command=None, diagnostics=None, invalid_inputs=("x",))


# ----------------------------------------------------------------- laser age


def test_laser_age_counts_from_the_pose_arrival_in_the_air() -> None:
    assert laser_age_s(T_NS, T_NS - 250_000_000, flying=True, height_valid=True) == 0.25


def test_laser_age_on_the_ground_is_no_risk() -> None:
    assert laser_age_s(T_NS, None, flying=False, height_valid=False) == 0.0


@pytest.mark.parametrize(("arrival_ns", "height_valid"), [(None, True), (T_NS, False)])
def test_no_pose_or_no_hat_height_in_the_air_is_a_stale_laser(
    arrival_ns: int | None, height_valid: bool
) -> None:
    assert laser_age_s(T_NS, arrival_ns, flying=True, height_valid=height_valid) == math.inf


# ----------------------------------------------------------------- failsafe inputs


@pytest.mark.parametrize(
    ("phase", "height_m", "counts"),
    [
        (Phase.HOLD, 0.6, True),
        (Phase.LAND, 0.6, True),
        (Phase.LAND, TOUCHDOWN_HEIGHT_M - 0.01, False),  # the scan plane meets the floor
        (Phase.LAND, math.nan, True),
        (Phase.PREFLIGHT, 0.6, False),  # on the ground
    ],
)
def test_a_degenerate_scan_counts_in_the_air_until_touchdown(
    phase: Phase, height_m: float, counts: bool
) -> None:
    inp = failsafe_inputs(
        level_imu(T_NS),
        msgspec.structs.replace(BASE, height_m=height_m),
        phase=phase,
        values_finite=True,
        laser_age_s=0.1,
        scan_degenerate=True,
        stop=None,
        pilot_override=False,
    )
    assert inp.scan_degenerate is counts


def test_failsafe_inputs_carry_the_step_values() -> None:
    imu = level_imu(T_NS, battery_v=11.1)
    inp = failsafe_inputs(
        imu,
        msgspec.structs.replace(BASE, x_m=1.5, y_m=-0.5, height_m=0.7),
        phase=Phase.HOLD,
        values_finite=False,
        laser_age_s=0.2,
        scan_degenerate=False,
        stop=None,
        pilot_override=True,
    )
    assert (inp.t_ns, inp.values_finite, inp.laser_age_s, inp.battery_v) == (
        T_NS,
        False,
        0.2,
        11.1,
    )
    assert (inp.x_m, inp.y_m, inp.height_m, inp.pilot_override) == (1.5, -0.5, 0.7, True)


# ----------------------------------------------------------------- gates and set-points


@pytest.mark.parametrize(("pose_valid", "height_valid"), [(False, True), (True, False)])
def test_no_takeoff_without_a_valid_pose_and_height(pose_valid: bool, height_valid: bool) -> None:
    requests = PhaseRequests(takeoff=True, land=True, release=False, handshake_ok=True)
    gated = takeoff_gate(
        requests, msgspec.structs.replace(BASE, pose_valid=pose_valid, height_valid=height_valid)
    )
    assert gated == PhaseRequests(takeoff=False, land=True, release=False, handshake_ok=True)
    assert takeoff_gate(requests, BASE) == requests


def test_the_hold_offset_moves_only_the_hold_setpoint() -> None:
    moved = hold_setpoint(SP, Phase.HOLD, (0.3, -0.2))
    assert moved is not None
    assert (moved.x_m, moved.y_m, moved.height_m) == (0.3, -0.2, 0.6)
    assert hold_setpoint(SP, Phase.TAKEOFF, (0.3, -0.2)) is SP
    assert hold_setpoint(SP, Phase.HOLD, (0.0, 0.0)) is SP
    assert hold_setpoint(None, Phase.HOLD, (0.3, -0.2)) is None


# ----------------------------------------------------------------- command selection


def test_a_valid_controller_command_is_sent() -> None:
    assert select() == CommandChoice(CommandSource.CONTROLLER, GOOD)


def test_the_failsafe_release_hands_back_whatever_the_phase() -> None:
    for phase in Phase:
        choice = select(phase, action=A.RELEASE)
        assert choice == CommandChoice(
            CommandSource.RELEASE, Command(T_NS, 0, 0, 0, 0, take_control=False)
        )


@pytest.mark.parametrize(
    ("phase", "take_control"),
    [
        (Phase.PREFLIGHT, False),
        (Phase.HANDSHAKE, False),
        (Phase.LANDED, True),  # the gas cut: control kept, gas 0
        (Phase.RELEASED, False),
    ],
)
def test_phases_without_controllers_send_neutral_and_gas_zero(
    phase: Phase, take_control: bool
) -> None:
    choice = select(phase)
    assert choice == CommandChoice(
        CommandSource.IDLE, Command(T_NS, 0, 0, 0, 0, take_control=take_control)
    )


@pytest.mark.parametrize("kw", [{"control": INVALID}, {"use_last_command": True}])
def test_no_valid_command_sends_the_last_one_restamped(kw: dict[str, object]) -> None:
    choice = select(**kw)  # type: ignore[arg-type]
    assert choice == CommandChoice(
        CommandSource.LAST_SAFE, Command(T_NS, 3, -4, 5, 110, take_control=True)
    )


@pytest.mark.parametrize(
    "kw",
    [
        {"height_valid": False},  # the laser is stale: no hat height to land on
        {"descending": True},  # a descent under way goes on
        {"control": INVALID, "invalid_run": CFG.safety.nonfinite_land_steps},  # cannot fly
    ],
)
def test_a_failsafe_landing_that_cannot_fly_on_the_hat_descends(kw: dict[str, object]) -> None:
    choice = select(Phase.LAND, action=A.LAND, **kw)  # type: ignore[arg-type]
    assert choice == CommandChoice(CommandSource.DESCENT, None)


def test_a_landing_on_the_hat_height_flies_the_controller() -> None:
    assert select(Phase.LAND, action=A.LAND).source is CommandSource.CONTROLLER
    assert select(Phase.LAND, height_valid=False).source is CommandSource.CONTROLLER  # asked
    assert select(Phase.HOLD, action=A.LAND, height_valid=False).source is CommandSource.CONTROLLER


def test_a_controller_failure_before_the_limit_sends_the_last_command_while_landing() -> None:
    choice = select(
        Phase.LAND,
        action=A.LAND,
        control=INVALID,
        invalid_run=CFG.safety.nonfinite_land_steps - 1,
    )
    assert choice.source is CommandSource.LAST_SAFE


# ----------------------------------------------------------------- TABLE IV


def test_table4_row_is_attitude_accelerations_command_sticks_index() -> None:
    imu = ImuSample(
        t_ns=T_NS, pitch_rad=0.1, roll_rad=0.2, yaw_rad=0.3, acc_x_mps2=0.4, acc_y_mps2=0.5,
        acc_z_mps2=-9.8, battery_v=12.0, gas_counts=100, receiver_level=200,
    )  # fmt: skip
    row = table4_row(imu, GOOD, PilotSticks(4, 5, 6, 7), 42)
    assert (row.pitch_rad, row.roll_rad, row.yaw_rad) == (0.1, 0.2, 0.3)
    assert (row.acc_x_mps2, row.acc_y_mps2, row.acc_z_mps2) == (0.4, 0.5, -9.8)
    assert (row.control_pitch_counts, row.control_roll_counts, row.control_yaw_counts) == (1, 2, 3)
    assert (
        row.stick_pitch_counts,
        row.stick_roll_counts,
        row.stick_yaw_counts,
        row.stick_thrust_counts,
    ) == (4, 5, 6, 7)
    assert row.index == 42


def test_table3_row_is_velocities_per_axis_then_pose_and_index() -> None:
    ls = LaserStep(
        t_ns=T_NS, w_vel_x_mps=1.0, w_vel_y_mps=2.0, b_vel_x_mps=3.0, b_vel_y_mps=4.0,
        b_esti_vel_x_mps=5.0, b_esti_vel_y_mps=6.0, x_m=7.0, y_m=8.0, yaw_rad=9.0,
        compensated=True,
    )  # fmt: skip
    row = table3_row(ls, 11)
    assert (row.w_vel_x_mps, row.b_vel_x_mps, row.b_esti_vel_x_mps) == (1.0, 3.0, 5.0)
    assert (row.w_vel_y_mps, row.b_vel_y_mps, row.b_esti_vel_y_mps) == (2.0, 4.0, 6.0)
    assert (row.x_m, row.y_m, row.theta_rad, row.index) == (7.0, 8.0, 9.0, 11)


# ----------------------------------------------------------------- composed in FlightCore


def test_a_stale_laser_levels_then_lands_within_limits() -> None:
    """The laser stops in HOLD: LEVEL_HOLD (tilt 0) at once, LAND after degenerate_land_s,
    flown as the descent without the hat; every command within its limits."""
    core = FlightCore(CFG)
    t_ns = fly_to_hold(core)
    core.laser_step(Pose2D(t_ns, 0.0, 0.0, 0.0), 0.6, t_ns=t_ns)
    actions = []
    for _ in range(round((CFG.safety.laser_stale_s + CFG.safety.degenerate_land_s + 1.0) * 20)):
        t_ns += STEP_NS
        out = core.imu_step(level_imu(t_ns), PhaseRequests(takeoff=True, handshake_ok=True))
        assert command_within_limits(
            out.command, CFG.control, counts_per_rad=CFG.mk.counts_per_rad
        ), out.command
        if out.action is A.LEVEL_HOLD:
            assert (out.command.nick_counts, out.command.roll_counts) == (0, 0)
        actions.append(out.action)
    assert A.LEVEL_HOLD in actions
    assert actions[-1] is A.LAND
    assert core.phase is Phase.LAND
    assert core.airframe.descent is not None  # no hat height: the descent flies it
    assert out.command.take_control
