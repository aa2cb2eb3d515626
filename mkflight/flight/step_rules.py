"""The pure rules of one flight step: what :meth:`FlightCore.imu_step` composes (SPEC §4-6).

Each is a function of its inputs only (no state, no clock), so each rule of SPEC §5 that
the step applies can be read and tested on its own:

* :func:`laser_age_s`: how old the laser is, as the failsafe judges it;
* :func:`failsafe_inputs`: the step's values as the failsafe's :class:`FailsafeInputs`;
* :func:`takeoff_gate`: no take-off request without a valid pose and height;
* :func:`hold_setpoint`: the HOLD set-point moved by the operator's offset;
* :func:`select_command`: which command the step sends (the failsafe's release, idle,
  the descent without the hat, the controller's, or the last safe one);
* :func:`table4_row`: the TABLE IV row of the 2011 QUT CyPhy MikroKopter documentation
  (attitude, accelerations, command and the pilot's sticks); :func:`table3_row` is
  :meth:`FlightCore.laser_step`'s TABLE III row (velocities and pose).

:class:`~mkflight.flight.step.FlightCore` keeps the state (estimator, failsafe, phases,
controller, airframe) and moves values between these rules.
"""

from __future__ import annotations

import enum
import math

import msgspec

from mkflight.control.controller import ControlOutput, Setpoint
from mkflight.control.limits import all_finite
from mkflight.control.phases import FLYING_PHASES, Phase, PhaseOutput, PhaseRequests
from mkflight.conversions import NS_PER_S
from mkflight.estimation.records import LaserStep
from mkflight.logs.table3 import Table3Row
from mkflight.logs.table4 import Table4Row
from mkflight.msgs import Command, Estimate, ImuSample
from mkflight.safety.failsafe import FailsafeAction, FailsafeInputs, StopRequest

TOUCHDOWN_HEIGHT_M = 0.15
"""Below this height in LAND a degenerate scan does not raise the failsafe (touchdown)."""


class PilotSticks(msgspec.Struct, frozen=True, gc=False):
    """The pilot's sticks as the FC reports them (logged in TABLE IV), MK counts."""

    pitch_counts: int = 0
    roll_counts: int = 0
    yaw_counts: int = 0
    thrust_counts: int = 0


def finite_estimate(est: Estimate) -> bool:
    """Every float the controllers may use of ``est`` is finite (SPEC §5 row 1)."""
    return all_finite(
        est.x_m, est.y_m, est.yaw_rad, est.height_m, est.vx_mps, est.vy_mps, est.vz_up_mps
    )


def finite_imu(imu: ImuSample) -> bool:
    """Every value of the FC's sample is finite and the battery reading is positive."""
    return (
        all_finite(
            imu.pitch_rad,
            imu.roll_rad,
            imu.yaw_rad,
            imu.acc_x_mps2,
            imu.acc_y_mps2,
            imu.acc_z_mps2,
            imu.battery_v,
        )
        and imu.battery_v > 0
    )


def laser_age_s(
    t_ns: int, last_pose_arrival_ns: int | None, *, flying: bool, height_valid: bool
) -> float:
    """Seconds since the last pose ARRIVED at the step, as the failsafe judges it (s).

    SPEC §5 counts "no pose for 300 ms" from the pose's arrival, not from its scan's time.
    On the ground the laser's age is no flight risk (0: it blocks take-off through the
    pre-flight checks instead). In the air, no pose yet or no valid hat height is a stale
    laser (inf): the height loop would fly blind.
    """
    if not flying:
        return 0.0
    if last_pose_arrival_ns is None or not height_valid:
        return math.inf
    return (t_ns - last_pose_arrival_ns) / NS_PER_S


def failsafe_inputs(
    imu: ImuSample,
    est: Estimate,
    *,
    phase: Phase,
    values_finite: bool,
    laser_age_s: float,
    scan_degenerate: bool,
    stop: StopRequest | None,
    pilot_override: bool,
) -> FailsafeInputs:
    """The failsafe's view of one step (SPEC §5).

    Args:
        imu: the step's sample (its time and battery voltage).
        est: the estimate after the sample (position and height for the box).
        phase: the phase the step starts in.
        values_finite: the estimator took the sample, the sample and the estimate are
            finite, and the step is not sending the last safe command again (no LAST_SAFE
            of :func:`select_command` since the controller's last valid command).
        laser_age_s: from :func:`laser_age_s`.
        scan_degenerate: the last scan match was degenerate. It counts only in the air,
            and not in LAND below :data:`TOUCHDOWN_HEIGHT_M`: at touchdown the scan plane
            meets the floor.
        stop: the operator's stop request, if any.
        pilot_override: the pilot moved the sticks or the RC switch.
    """
    touching_down = (
        phase is Phase.LAND and math.isfinite(est.height_m) and est.height_m < TOUCHDOWN_HEIGHT_M
    )
    return FailsafeInputs(
        t_ns=imu.t_ns,
        values_finite=values_finite,
        laser_age_s=laser_age_s,
        scan_degenerate=scan_degenerate and phase in FLYING_PHASES and not touching_down,
        x_m=est.x_m,
        y_m=est.y_m,
        height_m=est.height_m,
        battery_v=imu.battery_v,
        stop=stop,
        pilot_override=pilot_override,
    )


def takeoff_gate(requests: PhaseRequests, est: Estimate) -> PhaseRequests:
    """``requests`` without the take-off request unless the pose and height are valid."""
    if est.pose_valid and est.height_valid:
        return requests
    return msgspec.structs.replace(requests, takeoff=False)


def hold_setpoint(
    setpoint: Setpoint | None, phase: Phase, offset_m: tuple[float, float]
) -> Setpoint | None:
    """The phases' set-point, moved by ``offset_m`` (dx, dy in W) in HOLD only."""
    if setpoint is None or phase is not Phase.HOLD or offset_m == (0, 0):
        return setpoint
    dx, dy = offset_m
    return msgspec.structs.replace(setpoint, x_m=setpoint.x_m + dx, y_m=setpoint.y_m + dy)


class CommandSource(enum.Enum):
    """Where a step's command comes from (:func:`select_command`)."""

    RELEASE = "release"
    """The failsafe releases: neutral sticks, gas 0, Config = 0 (the pilot's sticks rule)."""
    IDLE = "idle"
    """No controllers in this phase: neutral sticks, gas 0 (LANDED: the gas cut)."""
    DESCENT = "descent"
    """A landing without a usable hat height or controller: the descent's command."""
    CONTROLLER = "controller"
    """The controller's valid command."""
    LAST_SAFE = "last_safe"
    """No valid command this step: the last one sent again (SPEC §5 row 1)."""


class CommandChoice(msgspec.Struct, frozen=True, gc=False):
    """A step's command source and, except for the descent, the command itself.

    ``command`` is None exactly when ``source`` is DESCENT: the descent
    (:mod:`mkflight.control.descent`) has state and runs only when chosen.
    """

    source: CommandSource
    command: Command | None


def select_command(
    t_ns: int,
    *,
    phase: PhaseOutput,
    setpoint: Setpoint | None,
    action: FailsafeAction,
    control: ControlOutput | None,
    use_last_command: bool,
    height_valid: bool,
    descending: bool,
    invalid_run: int,
    nonfinite_land_steps: int,
    last: Command,
) -> CommandChoice:
    """Which command the step sends (SPEC §4-5), first match wins.

    1. The failsafe's RELEASE: :attr:`CommandSource.RELEASE`.
    2. No controllers in this phase (or no set-point, or LANDED's gas cut): IDLE.
    3. A failsafe landing (action LAND or above, phase LAND) that cannot fly on the hat
       height: a descent is already under way, or the height is not valid, or the
       controller has failed ``nonfinite_land_steps`` times in a row: DESCENT.
    4. A valid controller output that the failsafe lets through: CONTROLLER.
    5. Otherwise the last command again, restamped: LAST_SAFE.

    Args:
        t_ns: the step's time (the commands' stamp).
        phase: the phase machine's output of this step.
        setpoint: the controllers' set-point (None: nothing to fly to).
        action: the failsafe's action of this step.
        control: the controller's output (None: it did not run, the sample was stale).
        use_last_command: the failsafe asks for the last safe command (non-finite values).
        height_valid: the estimate's height is the hat's.
        descending: a descent without the hat is under way.
        invalid_run: consecutive steps before this one without a valid command.
        nonfinite_land_steps: ``safety.nonfinite_land_steps``.
        last: the command sent on the step before.
    """
    if action is FailsafeAction.RELEASE:
        return CommandChoice(CommandSource.RELEASE, Command(t_ns, 0, 0, 0, 0, take_control=False))
    take_control = phase.take_control
    if phase.gas_cut or not phase.run_controllers or setpoint is None:
        return CommandChoice(
            CommandSource.IDLE, Command(t_ns, 0, 0, 0, 0, take_control=take_control)
        )
    command = None
    if control is not None and control.valid and not use_last_command:
        command = control.command
    landing = action >= FailsafeAction.LAND and phase.phase is Phase.LAND
    cannot_fly = command is None and invalid_run >= nonfinite_land_steps
    if landing and (descending or not height_valid or cannot_fly):
        return CommandChoice(CommandSource.DESCENT, None)
    if command is not None:
        return CommandChoice(CommandSource.CONTROLLER, command)
    again = Command(
        t_ns,
        last.nick_counts,
        last.roll_counts,
        last.yaw_counts,
        last.gas_counts,
        take_control=take_control,
    )
    return CommandChoice(CommandSource.LAST_SAFE, again)


def table4_row(imu: ImuSample, command: Command, sticks: PilotSticks, index: int) -> Table4Row:
    """TABLE IV's row of one step: attitude, accelerations, command, the pilot's sticks."""
    return Table4Row(
        imu.pitch_rad,
        imu.roll_rad,
        imu.yaw_rad,
        imu.acc_x_mps2,
        imu.acc_y_mps2,
        imu.acc_z_mps2,
        command.nick_counts,
        command.roll_counts,
        command.yaw_counts,
        sticks.pitch_counts,
        sticks.roll_counts,
        sticks.yaw_counts,
        sticks.thrust_counts,
        index,
    )


def table3_row(ls: LaserStep, index: int) -> Table3Row:
    """TABLE III's row of one laser step: velocities in W and B, and the pose."""
    return Table3Row(
        ls.w_vel_x_mps,
        ls.b_vel_x_mps,
        ls.b_esti_vel_x_mps,
        ls.w_vel_y_mps,
        ls.b_vel_y_mps,
        ls.b_esti_vel_y_mps,
        ls.x_m,
        ls.y_m,
        ls.yaw_rad,
        index,
    )
