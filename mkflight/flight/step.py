"""The flight step: the pure core the daemon, the simulator and replay all run (SPEC §3-6).

:class:`FlightCore` is PX4's ``PositionControl`` idea applied to the whole flight: values
and timestamps in, values out, no I/O and no clock reads. Two entry points, one per rate:

* :meth:`FlightCore.laser_step` (100 ms): a scan-matched pose and a hat height, stamped with
  the time the scan was TAKEN, go into the estimator (which re-propagates from then);
  returns the TABLE III row (TABLE III and IV: the 2011 QUT CyPhy MikroKopter
  documentation).
* :meth:`FlightCore.imu_step` (each DebugOut, ~53 ms): the IMU sample updates the
  estimate; the failsafe judges the health of every input; the flight phases give the
  set-point; the controllers give the command. Returns the command to send (always within
  its limits: a step whose inputs are not finite sends the last safe command, SPEC §5),
  the failsafe action with its causes and transitions, the phase and the TABLE IV row.
  Its rules are pure functions of their inputs in :mod:`mkflight.flight.step_rules`; this
  class holds the state they act on.

Fail-safe rules enforced here (SPEC §5):

* a step is "non-finite" when the estimate or the IMU sample holds NaN/inf, when the
  estimator rejected the sample (its estimate is stale), or when the controller cannot
  produce a command: the last safe command is sent, and after
  ``safety.nonfinite_land_steps`` such steps the failsafe lands;
* the airframe is learned while it holds (:mod:`mkflight.flight.airframe`): the
  accelerometer biases go into the estimator, the hover gas and the vibration into the
  vertical channel without the hat, the descent and ``flight.json``;
* a landing that cannot be flown on the hat height (the laser is gone, or the FC's samples
  are unusable so the estimate stops) is a closed-loop, level descent on what is left
  (:mod:`mkflight.control.descent`: the inertial vertical velocity, or the hat height
  alone) that finds the floor and then cuts the gas; only if it finds no floor in time
  does control go to the pilot in the air, which ends the flight with exit 1;
* without a valid pose the controllers fly LEVEL (no position loop on dead reckoning);
  without a valid hat height the laser counts as stale (the height loop would fly blind);
* take-off needs a valid pose and height; the laser's age counts from when the pose
  ARRIVED (SPEC §5: "no pose for 300 ms"), not from when the scan was taken.

MK data that stops is not judged here: the step runs on each DebugOut's arrival, and the
link (:mod:`mkflight.mk.subscription`) re-subscribes and then releases while it waits.
The shell (daemon, simulator, replay) owns ports, time and files; it only moves values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgspec

from mkflight.config import Config
from mkflight.control.controller import Controller, ControlMode, Setpoint
from mkflight.control.phases import (
    FLYING_PHASES,
    Phase,
    PhaseEvent,
    PhaseOutput,
    PhaseParams,
    PhaseRequests,
    PhaseState,
    phase_step,
)
from mkflight.conversions import NS_PER_S
from mkflight.estimation.estimator import Estimator
from mkflight.flight.airframe import FlightAirframe
from mkflight.flight.step_rules import (
    CommandSource,
    PilotSticks,
    failsafe_inputs,
    finite_estimate,
    finite_imu,
    hold_setpoint,
    laser_age_s,
    select_command,
    table3_row,
    table4_row,
    takeoff_gate,
)
from mkflight.logs.table3 import Table3Row
from mkflight.logs.table4 import Table4Row
from mkflight.msgs import Command, Estimate, ImuSample, Pose2D, plausible_imu
from mkflight.safety.failsafe import (
    Failsafe,
    FailsafeAction,
    FailsafeOutput,
    StopRequest,
    TransitionEvent,
)

__all__ = [
    "MAX_HOLD_OFFSET_M",
    "SCAN_AGE_ALLOWANCE_S",
    "FlightCore",
    "ImuStepOutput",
    "PilotSticks",
]

SCAN_AGE_ALLOWANCE_S = 0.1
"""The estimator judges a pose or height by its SCAN's time, the failsafe by its arrival
(SPEC §5: no pose for ``safety.laser_stale_s``). A scan is already ~0.06-0.1 s old when
its result reaches the step, so a threshold of ``laser_stale_s`` on the scan's time would
leave one late scan (0.1 s, a loaded CPU) between a hover and a failsafe landing; this is
the allowance for the scan's own age."""
MAX_HOLD_OFFSET_M = 1.0
"""The largest HOLD set-point offset :meth:`FlightCore.set_hold_offset` accepts."""


class ImuStepOutput(msgspec.Struct, frozen=True, gc=False):
    """What one 50 ms step decided.

    Attributes:
        command: the command to send (within its limits; stamped with the step's time).
        action: the failsafe's action.
        phase: the phase after the step.
        estimate: the estimate the step flew on.
        row: the step's TABLE IV row.
        failsafe_events: the failsafe's transitions of this step.
        phase_events: the phase changes of this step.
    """

    command: Command
    action: FailsafeAction
    phase: Phase
    estimate: Estimate
    row: Table4Row
    failsafe_events: tuple[TransitionEvent, ...] = ()
    phase_events: tuple[PhaseEvent, ...] = ()


@dataclass(slots=True)
class _Counters:
    imu_steps: int = 0
    laser_steps: int = 0
    invalid_steps: int = 0
    failsafe_events: list[str] = field(default_factory=list)


class FlightCore:
    """Estimator + failsafe + phases + controllers for one flight (see the module docstring)."""

    def __init__(self, cfg: Config, *, height_m: float | None = None) -> None:
        self.cfg = cfg
        stale_s = cfg.safety.laser_stale_s + SCAN_AGE_ALLOWANCE_S
        self.estimator = Estimator(
            cfg.estimation, cfg.mk.g_mps2, pose_stale_s=stale_s, height_stale_s=stale_s
        )
        self.controller = Controller(cfg.control, cfg.mk)
        self.failsafe = Failsafe(cfg.safety)
        overrides = {} if height_m is None else {"takeoff_height_m": height_m}
        self.phase_params = PhaseParams.from_config(cfg.control, cfg.mk.handshake_s, **overrides)
        self.phase_state = PhaseState()
        self.last_command = Command(0, 0, 0, 0, 0, take_control=False)
        self.counters = _Counters()
        self._last_pose_arrival_ns: int | None = None
        self._now_ns = 0
        self._degenerate = False
        self._invalid_run = 0
        self.airframe = FlightAirframe(cfg, self.estimator)
        """What the flight learns of its airframe; the descent without the hat."""
        self.handed_in_air = False
        """Control went to the pilot in the air (no floor found): the flight ends with exit 1."""
        self._pending_phase_events: list[PhaseEvent] = []
        self._index3 = 0
        self._index4 = 0
        self._first_ns: int | None = None  # the first step's time: failsafe times count from it
        self._hold_offset_m = (0.0, 0.0)
        self.active_setpoint: Setpoint | None = None
        """The set-point the controller was given on the last step (HOLD: with the offset)."""

    def set_hold_offset(self, dx_m: float, dy_m: float) -> None:
        """Move the HOLD set-point by (dx, dy) in W (``sim hover --excite``, ``analyze latency``).

        Clamped to ±:data:`MAX_HOLD_OFFSET_M`, non-finite = 0; take-off and landing ignore it.
        """

        def safe(v: float) -> float:
            return min(MAX_HOLD_OFFSET_M, max(-MAX_HOLD_OFFSET_M, v)) if math.isfinite(v) else 0.0

        self._hold_offset_m = (safe(dx_m), safe(dy_m))

    def learned(self) -> dict[str, object]:
        """What the flight learned of its airframe and how it used it (``flight.json``)."""
        out = self.airframe.learned()
        out["handed_in_air"] = self.handed_in_air
        return out

    def blind_command(self, battery_v: float) -> Command | None:
        """What the FC should fly if its data stops after the last command (None: nothing).

        The FC holds the last command it got until we release (``safety.mk_release_s``);
        a hover's last gas can be 20 counts off the hover gas (the loop's answer to one
        noisy sample), which drops the vehicle to the floor within that second. This
        is level, no yaw, and the hover gas (0 if the last gas was 0).
        """
        last = self.last_command
        if not last.take_control:
            return None
        flying = self.phase_state.phase in (Phase.TAKEOFF, Phase.HOLD, Phase.LAND)
        gas = 0
        if flying and last.gas_counts > 0:
            integral = self.controller.state.altitude.climb.integral
            gas = self.airframe.blind_gas(battery_v, integral)
        return Command(last.t_ns, 0, 0, 0, gas, take_control=True)

    def _descend(
        self, t_ns: int, imu: ImuSample, est: Estimate, *, inertial: bool, take_control: bool
    ) -> Command:
        """A landing without a usable hat height or estimate (:mod:`mkflight.control.descent`).

        ``inertial``: the FC's samples are good (the estimate's height and vertical
        velocity are the model-aided channel's); otherwise the hat height alone, if
        fresh, else nothing.
        """
        if self.airframe.descent is None:
            self.counters.failsafe_events.append(f"{self._since_s(t_ns)} descent without height")
        out = self.airframe.descend(
            t_ns,
            imu,
            est,
            inertial=inertial,
            integral_gas=self.controller.state.altitude.climb.integral,
            gas_counts=self.last_command.gas_counts,
            since=self._since_s(t_ns),
        )
        if out.give_up:
            self.handed_in_air = True
            self.counters.failsafe_events.append(f"{self._since_s(t_ns)} {out.note}")
            return Command(t_ns, 0, 0, 0, 0, take_control=False)  # the pilot's sticks rule
        if out.on_floor and self.phase_state.phase is Phase.LAND:
            event = PhaseEvent(t_ns, Phase.LAND, Phase.LANDED, out.note or "floor found")
            self.phase_state = msgspec.structs.replace(
                self.phase_state, phase=Phase.LANDED, phase_start_ns=t_ns, setpoint=None
            )
            self._pending_phase_events.append(event)
        return Command(t_ns, 0, 0, 0, out.gas_counts, take_control=take_control)

    @property
    def phase(self) -> Phase:
        """The current flight phase."""
        return self.phase_state.phase

    def laser_step(
        self,
        pose: Pose2D | None,
        height_m: float | None,
        *,
        t_ns: int,
        degenerate: bool = False,
        arrival_ns: int | None = None,
    ) -> Table3Row | None:
        """A scan's pose (None: the match failed) and hat height, stamped at the scan's time.

        ``arrival_ns``: when the pose reached the flight step (the laser's staleness counts
        from it); default the last step's time. The daemon passes the time of the DebugOut
        whose step applies it: after a gap in DebugOut the last step's time is old, and a
        fresh pose must not look stale.

        Returns the TABLE III row, or None before the estimator has a laser velocity.
        """
        if arrival_ns is not None:
            self._now_ns = arrival_ns if arrival_ns > self._now_ns else self._now_ns
        self.counters.laser_steps += 1
        self._degenerate = degenerate
        used = False
        if pose is not None and not degenerate:
            before = self.estimator.poses_rejected
            self.estimator.on_scan(pose, t_ns, height_m)  # = on_pose, then on_height
            used = self.estimator.poses_rejected == before
            if used:
                self._last_pose_arrival_ns = self._now_ns
        else:
            self.estimator.on_height(t_ns, height_m)
        self.airframe.hat_height(self._now_ns, t_ns, height_m)
        ls = self.estimator.laser_step
        if ls is None or not used:
            return None  # no new pose: no new TABLE III row
        self._index3 += 1
        return table3_row(ls, self._index3)

    def _since_s(self, t_ns: int) -> str:
        """``t+12.35s``: seconds since the first step, for the failsafe lines.

        Not the host's monotonic seconds, which mean nothing to a reader.
        """
        return f"t+{(t_ns - (self._first_ns or t_ns)) / NS_PER_S:.2f}s"

    def imu_step(
        self,
        imu: ImuSample,
        requests: PhaseRequests,
        *,
        sticks: PilotSticks | None = None,
        stop: StopRequest | None = None,
        pilot_override: bool = False,
    ) -> ImuStepOutput:
        """One DebugOut: estimate, failsafe, phase, command (see the module docstring).

        A composition of the rules in :mod:`mkflight.flight.step_rules` around this
        object's state, in this order: the estimate, the failsafe, the airframe learner,
        the phases, the command, the phase hand-back, the TABLE IV row.
        """
        imu = plausible_imu(imu)
        t_ns = imu.t_ns
        self._start_step(t_ns)
        phase_before = self.phase_state.phase
        flying = phase_before in FLYING_PHASES
        est, fresh = self._estimate(imu, flying=flying)
        finite = fresh and finite_estimate(est) and finite_imu(imu) and self._invalid_run == 0
        age_s = laser_age_s(
            t_ns, self._last_pose_arrival_ns, flying=flying, height_valid=est.height_valid
        )
        fs = self.failsafe.update(
            failsafe_inputs(
                imu,
                est,
                phase=phase_before,
                values_finite=finite,
                laser_age_s=age_s,
                scan_degenerate=self._degenerate,
                stop=stop,
                pilot_override=pilot_override,
            )
        )
        if fresh and finite:
            self._learn(imu, est, fs.action)
        out_phase = phase_step(
            self.phase_params,
            self.phase_state,
            t_ns=t_ns,
            est=est,
            requests=takeoff_gate(requests, est),
            failsafe=fs.action,
            last_gas_counts=self.last_command.gas_counts,
        )
        self.phase_state = out_phase.state
        command = self._command(imu, est, out_phase, fs, fresh=fresh)
        phase, phase_events = self._settle_phase(t_ns, out_phase, command)
        self.last_command = command
        self.counters.failsafe_events += [
            f"{self._since_s(e.t_ns)} {e.action.name} {e.cause.value}" for e in fs.events
        ]
        self._index4 += 1
        return ImuStepOutput(
            command=command,
            action=fs.action,
            phase=phase,
            estimate=est,
            row=table4_row(imu, command, sticks or PilotSticks(), self._index4),
            failsafe_events=tuple(fs.events),
            phase_events=phase_events,
        )

    def _start_step(self, t_ns: int) -> None:
        """Count the step; the first step's time starts the flight's clock for the log."""
        self.counters.imu_steps += 1
        if self._first_ns is None:
            self._first_ns = t_ns
        self._now_ns = t_ns if t_ns > self._now_ns else self._now_ns

    def _estimate(self, imu: ImuSample, *, flying: bool) -> tuple[Estimate, bool]:
        """The estimate after ``imu``, and whether the estimator took it (fresh).

        The thrust model aids the vertical channel while flying with control; without the
        hat height the airframe's model-aided channel gives height and vertical speed.
        """
        last = self.last_command
        integral_gas = self.controller.state.altitude.climb.integral
        thrust_up = self.airframe.thrust_up(
            imu,
            flying=flying and last.take_control,
            gas_counts=last.gas_counts,
            integral_gas=integral_gas,
        )
        est = self.estimator.on_imu(imu, thrust_up_mps2=thrust_up)
        fresh = est.t_ns == imu.t_ns  # else the estimator rejected it: a stale estimate
        est = self.airframe.without_hat(
            imu,
            est,
            fresh=fresh,
            flying=flying,
            gas_counts=last.gas_counts,
            integral_gas=integral_gas,
        )
        return est, fresh

    def _learn(self, imu: ImuSample, est: Estimate, action: FailsafeAction) -> None:
        """Let the airframe learner see a fresh, finite sample (:mod:`.airframe`)."""
        st = self.phase_state
        self.airframe.observe(
            imu,
            est,
            hold_s=(imu.t_ns - st.phase_start_ns) / NS_PER_S if st.phase is Phase.HOLD else None,
            quiet=action <= FailsafeAction.WARN and self.last_command.take_control,
            gas_counts=self.last_command.gas_counts,
            on_floor=st.phase in (Phase.PREFLIGHT, Phase.HANDSHAKE),
        )

    def _command(
        self,
        imu: ImuSample,
        est: Estimate,
        out_phase: PhaseOutput,
        fs: FailsafeOutput,
        *,
        fresh: bool,
    ) -> Command:
        """Run the controller on a fresh sample, then send what :func:`select_command` picks."""
        t_ns = imu.t_ns
        setpoint = hold_setpoint(out_phase.setpoint, out_phase.phase, self._hold_offset_m)
        self.active_setpoint = setpoint
        control = None
        if out_phase.run_controllers and setpoint is not None and fresh:
            control = self.controller.update(
                est,
                setpoint,
                (imu.pitch_rad, imu.roll_rad),
                imu.battery_v,
                _dt_s(t_ns, self.controller.last_valid_t_ns),
                mode=out_phase.mode if est.pose_valid else ControlMode.LEVEL,
                take_control=out_phase.take_control,
            )
        choice = select_command(
            t_ns,
            phase=out_phase,
            setpoint=setpoint,
            action=fs.action,
            control=control,
            use_last_command=fs.use_last_command,
            height_valid=est.height_valid,
            descending=self.airframe.descent is not None,
            invalid_run=self._invalid_run,
            nonfinite_land_steps=self.cfg.safety.nonfinite_land_steps,
            last=self.last_command,
        )
        if choice.source is CommandSource.CONTROLLER:
            self._invalid_run = 0
        elif choice.source is CommandSource.LAST_SAFE:
            self.counters.invalid_steps += 1
            self._invalid_run += 1
        if choice.command is not None:
            return choice.command
        inertial = fresh and finite_imu(imu) and math.isfinite(est.vz_up_mps)
        return self._descend(t_ns, imu, est, inertial=inertial, take_control=out_phase.take_control)

    def _settle_phase(
        self, t_ns: int, out_phase: PhaseOutput, command: Command
    ) -> tuple[Phase, tuple[PhaseEvent, ...]]:
        """The phase after the command, with this step's phase events.

        The descent may have found the floor (LANDED). A command that hands control to
        the pilot in the air (a descent that found no floor) makes the phase RELEASED for
        good: a pose or height coming back later never takes control again (SPEC §5).
        """
        phase, phase_events = out_phase.phase, tuple(out_phase.events)
        if self._pending_phase_events:
            phase = self.phase_state.phase
            phase_events = (*phase_events, *self._pending_phase_events)
            self._pending_phase_events.clear()
        if not command.take_control and phase in FLYING_PHASES:
            event = PhaseEvent(t_ns, phase, Phase.RELEASED, "handed to the pilot in the air")
            self.phase_state = msgspec.structs.replace(
                self.phase_state, phase=Phase.RELEASED, setpoint=None
            )
            phase, phase_events = Phase.RELEASED, (*phase_events, event)
        return phase, phase_events


def _dt_s(t_ns: int, last_ns: int | None) -> float:
    return math.nan if last_ns is None else (t_ns - last_ns) / NS_PER_S
