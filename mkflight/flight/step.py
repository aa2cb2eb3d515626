"""The flight step: the pure core the daemon, the simulator and replay all run (SPEC §3-6).

:class:`FlightCore` is PX4's ``PositionControl`` idea applied to the whole flight: values
and timestamps in, values out, no I/O and no clock reads. Two entry points, one per rate:

* :meth:`FlightCore.laser_step` (100 ms): a scan-matched pose and a hat height, stamped with
  the time the scan was TAKEN, go into the estimator (which re-propagates from then);
  returns the TABLE III row.
* :meth:`FlightCore.imu_step` (each DebugOut, ~53 ms): the IMU sample updates the
  estimate; the failsafe judges the health of every input; the flight phases give the
  set-point; the controllers give the command. Returns the command to send (always within
  its limits: a step whose inputs are not finite sends the last safe command, SPEC §5),
  the failsafe action with its causes and transitions, the phase and the TABLE IV row.

Fail-safe rules enforced here (SPEC §5, and a review of the first simulated flights):

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

The shell (daemon, simulator, replay) owns ports, time and files; it only moves values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from mkflight.config import Config
from mkflight.control.controller import Controller, ControlMode, Setpoint
from mkflight.control.phases import (
    Phase,
    PhaseEvent,
    PhaseParams,
    PhaseRequests,
    PhaseState,
    phase_step,
)
from mkflight.conversions import NS_PER_S
from mkflight.estimation.estimator import Estimator
from mkflight.flight.airframe import FlightAirframe
from mkflight.logs.table3 import Table3Row
from mkflight.logs.table4 import Table4Row
from mkflight.msgs import Command, Estimate, ImuSample, Pose2D, plausible_imu
from mkflight.safety.failsafe import (
    Failsafe,
    FailsafeAction,
    FailsafeInputs,
    StopRequest,
    TransitionEvent,
)

TOUCHDOWN_HEIGHT_M = 0.15
"""Below this height in LAND a degenerate scan no longer raises the failsafe."""
SCAN_AGE_ALLOWANCE_S = 0.1
"""The estimator judges a pose or height by its SCAN's time, the failsafe by its arrival
(SPEC §5: no pose for ``safety.laser_stale_s``). A scan is already ~0.06-0.1 s old when
its result reaches the step, so a threshold of ``laser_stale_s`` on the scan's time left
one late scan (0.1 s, a loaded CPU) between a hover and a failsafe landing; this is the
allowance for the scan's own age."""
MAX_HOLD_OFFSET_M = 1.0
"""The largest HOLD set-point offset :meth:`FlightCore.set_hold_offset` accepts."""


@dataclass(frozen=True, slots=True)
class PilotSticks:
    """The pilot's sticks as the FC reports them (logged in TABLE IV), MK counts."""

    pitch_counts: int = 0
    roll_counts: int = 0
    yaw_counts: int = 0
    thrust_counts: int = 0


@dataclass(frozen=True, slots=True)
class ImuStepOutput:
    """What one 50 ms step decided."""

    command: Command
    action: FailsafeAction
    phase: Phase
    estimate: Estimate
    row: Table4Row
    failsafe_events: tuple[TransitionEvent, ...] = ()
    phase_events: tuple[PhaseEvent, ...] = ()
    used_last_command: bool = False
    resubscribe_mk: bool = False


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
            self.phase_state = replace(
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
            self._now_ns = max(self._now_ns, arrival_ns)
        self.counters.laser_steps += 1
        self._degenerate = degenerate
        used = False
        if pose is not None and not degenerate:
            before = self.estimator.counters.pose_rejected
            self.estimator.on_pose(pose)
            used = self.estimator.counters.pose_rejected == before
            if used:
                self._last_pose_arrival_ns = self._now_ns
        self.estimator.on_height(t_ns, height_m)
        self.airframe.hat_height(self._now_ns, t_ns, height_m)
        ls = self.estimator.laser_step
        if ls is None or not used:
            return None  # no new pose: no new TABLE III row
        self._index3 += 1
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
            self._index3,
        )

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
        mk_age_s: float = 0.0,
    ) -> ImuStepOutput:
        """One DebugOut: estimate, failsafe, phase, command (see the module docstring)."""
        imu = plausible_imu(imu)
        self.counters.imu_steps += 1
        t_ns = imu.t_ns
        if self._first_ns is None:
            self._first_ns = t_ns
        self._now_ns = max(self._now_ns, t_ns)
        flying = self.phase_state.phase in (Phase.TAKEOFF, Phase.HOLD, Phase.LAND)
        thrust_up = self.airframe.thrust_up(
            imu,
            flying=flying and self.last_command.take_control,
            gas_counts=self.last_command.gas_counts,
            integral_gas=self.controller.state.altitude.climb.integral,
        )
        est = self.estimator.on_imu(imu, thrust_up_mps2=thrust_up)
        fresh = est.t_ns == t_ns  # the estimator took this sample (else: stale estimate)
        est = self.airframe.without_hat(
            imu,
            est,
            fresh=fresh,
            flying=flying,
            gas_counts=self.last_command.gas_counts,
            integral_gas=self.controller.state.altitude.climb.integral,
        )
        if self._last_pose_arrival_ns is None or (flying and not est.height_valid):
            laser_age_s = math.inf  # no pose yet, or no hat height: the laser is stale
        else:
            laser_age_s = (t_ns - self._last_pose_arrival_ns) / NS_PER_S
        finite = fresh and _finite_estimate(est) and _finite_imu(imu) and self._invalid_run == 0
        fs = self.failsafe.update(
            FailsafeInputs(
                t_ns=t_ns,
                values_finite=finite,
                # Before take-off the laser's age is not a flight risk (it blocks take-off
                # through the pre-flight checks instead).
                laser_age_s=laser_age_s if flying else 0.0,
                # At touchdown the scan plane meets the floor: degenerate, and irrelevant.
                scan_degenerate=self._degenerate
                and flying
                and not (
                    self.phase is Phase.LAND
                    and math.isfinite(est.height_m)
                    and est.height_m < TOUCHDOWN_HEIGHT_M
                ),
                mk_age_s=mk_age_s,
                x_m=est.x_m,
                y_m=est.y_m,
                height_m=est.height_m,
                battery_v=imu.battery_v,
                stop=stop,
                pilot_override=pilot_override,
            )
        )
        if fresh and finite:
            st = self.phase_state
            self.airframe.observe(
                imu,
                est,
                hold_s=(t_ns - st.phase_start_ns) / NS_PER_S if st.phase is Phase.HOLD else None,
                quiet=fs.action <= FailsafeAction.WARN and self.last_command.take_control,
                gas_counts=self.last_command.gas_counts,
                on_floor=st.phase in (Phase.PREFLIGHT, Phase.HANDSHAKE),
            )
        if not (est.pose_valid and est.height_valid):
            requests = PhaseRequests(
                takeoff=False,  # never take off without a valid pose and height
                land=requests.land,
                release=requests.release,
                handshake_ok=requests.handshake_ok,
            )
        out_phase = phase_step(
            self.phase_params,
            self.phase_state,
            t_ns=t_ns,
            est=est,
            requests=requests,
            failsafe=fs.action,
            last_gas_counts=self.last_command.gas_counts,
        )
        self.phase_state = out_phase.state
        command = Command(t_ns, 0, 0, 0, 0, take_control=out_phase.take_control)
        used_last = False
        setpoint = out_phase.setpoint
        if setpoint is not None and out_phase.phase is Phase.HOLD and self._hold_offset_m != (0, 0):
            dx, dy = self._hold_offset_m
            setpoint = replace(setpoint, x_m=setpoint.x_m + dx, y_m=setpoint.y_m + dy)
        self.active_setpoint = setpoint
        if out_phase.run_controllers and setpoint is not None:
            mode = out_phase.mode if est.pose_valid else ControlMode.LEVEL
            dt_s = _dt_s(t_ns, self.controller.last_valid_t_ns)
            control = None
            if fresh:
                control = self.controller.update(
                    est,
                    setpoint,
                    (imu.pitch_rad, imu.roll_rad),
                    imu.battery_v,
                    dt_s,
                    mode=mode,
                    take_control=out_phase.take_control,
                )
            ok = (
                control is not None
                and control.valid
                and control.command is not None
                and not fs.use_last_command
            )
            landing = fs.action >= FailsafeAction.LAND and out_phase.phase is Phase.LAND
            cannot_fly = not ok and self._invalid_run >= self.cfg.safety.nonfinite_land_steps
            descending = self.airframe.descent is not None
            if landing and (descending or not est.height_valid or cannot_fly):
                inertial = fresh and _finite_imu(imu) and math.isfinite(est.vz_up_mps)
                command = self._descend(
                    t_ns, imu, est, inertial=inertial, take_control=out_phase.take_control
                )
            elif ok and control is not None and control.command is not None:
                command = control.command
                self._invalid_run = 0
            else:
                self.counters.invalid_steps += 1
                self._invalid_run += 1
                used_last = True
                last = self.last_command
                command = Command(
                    t_ns,
                    last.nick_counts,
                    last.roll_counts,
                    last.yaw_counts,
                    last.gas_counts,
                    take_control=out_phase.take_control,
                )
        if out_phase.gas_cut:
            command = Command(t_ns, 0, 0, 0, 0, take_control=command.take_control)
        if fs.action is FailsafeAction.RELEASE:
            command = Command(t_ns, 0, 0, 0, 0, take_control=False)
        phase, phase_events = out_phase.phase, tuple(out_phase.events)
        if self._pending_phase_events:  # the descent found the floor: LANDED now
            phase = self.phase_state.phase
            phase_events = (*phase_events, *self._pending_phase_events)
            self._pending_phase_events.clear()
        if not command.take_control and phase in (Phase.TAKEOFF, Phase.HOLD, Phase.LAND):
            # Handed to the pilot in the air (a descent that found no floor): final. A pose
            # or height coming back later must never take control again (sticky, SPEC §5).
            event = PhaseEvent(t_ns, phase, Phase.RELEASED, "handed to the pilot in the air")
            self.phase_state = replace(self.phase_state, phase=Phase.RELEASED, setpoint=None)
            phase, phase_events = Phase.RELEASED, (*phase_events, event)
        self.last_command = command
        self.counters.failsafe_events += [
            f"{self._since_s(e.t_ns)} {e.action.name} {_cause(e.cause)}" for e in fs.events
        ]
        s = sticks or PilotSticks()
        self._index4 += 1
        row = Table4Row(
            imu.pitch_rad,
            imu.roll_rad,
            imu.yaw_rad,
            imu.acc_x_mps2,
            imu.acc_y_mps2,
            imu.acc_z_mps2,
            command.nick_counts,
            command.roll_counts,
            command.yaw_counts,
            s.pitch_counts,
            s.roll_counts,
            s.yaw_counts,
            s.thrust_counts,
            self._index4,
        )
        return ImuStepOutput(
            command=command,
            action=fs.action,
            phase=phase,
            estimate=est,
            row=row,
            failsafe_events=tuple(fs.events),
            phase_events=phase_events,
            used_last_command=used_last,
            resubscribe_mk=fs.resubscribe_mk,
        )


def _cause(cause: object) -> str:
    return str(getattr(cause, "value", cause))


def _dt_s(t_ns: int, last_ns: int | None) -> float:
    return math.nan if last_ns is None else (t_ns - last_ns) / NS_PER_S


def _finite_estimate(est: Estimate) -> bool:
    return all(
        math.isfinite(v)
        for v in (
            est.x_m,
            est.y_m,
            est.yaw_rad,
            est.height_m,
            est.vx_mps,
            est.vy_mps,
            est.vz_up_mps,
        )
    )


def _finite_imu(imu: ImuSample) -> bool:
    return (
        all(
            math.isfinite(v)
            for v in (
                imu.pitch_rad,
                imu.roll_rad,
                imu.yaw_rad,
                imu.acc_x_mps2,
                imu.acc_y_mps2,
                imu.acc_z_mps2,
                imu.battery_v,
            )
        )
        and imu.battery_v > 0
    )
