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

The shell (daemon, simulator, replay) owns ports, time and files; it only moves values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mkflight.config import Config
from mkflight.control.controller import Controller
from mkflight.control.phases import (
    Phase,
    PhaseEvent,
    PhaseParams,
    PhaseRequests,
    PhaseState,
    phase_step,
)
from mkflight.estimation.estimator import Estimator
from mkflight.logs.table3 import Table3Row
from mkflight.logs.table4 import Table4Row
from mkflight.msgs import Command, Estimate, ImuSample, Pose2D
from mkflight.safety.failsafe import (
    Failsafe,
    FailsafeAction,
    FailsafeInputs,
    StopRequest,
    TransitionEvent,
)

NS_PER_S = 1_000_000_000


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
        self.estimator = Estimator(
            cfg.estimation, cfg.mk.g_mps2, pose_stale_s=cfg.safety.laser_stale_s
        )
        self.controller = Controller(cfg.control, cfg.mk)
        self.failsafe = Failsafe(cfg.safety)
        overrides = {} if height_m is None else {"takeoff_height_m": height_m}
        self.phase_params = PhaseParams.from_config(cfg.control, cfg.mk.handshake_s, **overrides)
        self.phase_state = PhaseState()
        self.last_command = Command(0, 0, 0, 0, 0, take_control=False)
        self.counters = _Counters()
        self._last_pose_ns: int | None = None
        self._degenerate = False
        self._index3 = 0
        self._index4 = 0

    @property
    def phase(self) -> Phase:
        """The current flight phase."""
        return self.phase_state.phase

    def laser_step(
        self, pose: Pose2D | None, height_m: float | None, *, t_ns: int, degenerate: bool = False
    ) -> Table3Row | None:
        """A scan's pose (None: the match failed) and hat height, stamped at the scan's time.

        Returns the TABLE III row, or None before the estimator has a laser velocity.
        """
        self.counters.laser_steps += 1
        self._degenerate = degenerate
        if pose is not None and not degenerate:
            self.estimator.on_pose(pose)
            self._last_pose_ns = pose.t_ns
        self.estimator.on_height(t_ns, height_m)
        ls = self.estimator.laser_step
        if ls is None:
            return None
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
        self.counters.imu_steps += 1
        t_ns = imu.t_ns
        est = self.estimator.on_imu(imu)
        flying = self.phase_state.phase in (Phase.TAKEOFF, Phase.HOLD, Phase.LAND)
        if self._last_pose_ns is None:
            laser_age_s = math.inf
        else:
            laser_age_s = (t_ns - self._last_pose_ns) / NS_PER_S
        fs = self.failsafe.update(
            FailsafeInputs(
                t_ns=t_ns,
                values_finite=_finite_estimate(est) and _finite_imu(imu),
                # Before take-off the laser's age is not a flight risk (it blocks take-off
                # through the pre-flight checks instead).
                laser_age_s=laser_age_s if flying else 0.0,
                scan_degenerate=self._degenerate and flying,
                mk_age_s=mk_age_s,
                x_m=est.x_m,
                y_m=est.y_m,
                height_m=est.height_m,
                battery_v=imu.battery_v,
                stop=stop,
                pilot_override=pilot_override,
            )
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
        if out_phase.run_controllers and out_phase.setpoint is not None:
            dt_s = _dt_s(t_ns, self.controller.last_valid_t_ns)
            control = self.controller.update(
                est,
                out_phase.setpoint,
                (imu.pitch_rad, imu.roll_rad),
                imu.battery_v,
                dt_s,
                mode=out_phase.mode,
                take_control=out_phase.take_control,
            )
            if control.valid and control.command is not None and not fs.use_last_command:
                command = control.command
            else:
                self.counters.invalid_steps += 1
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
        self.last_command = command
        self.counters.failsafe_events += [
            f"{e.t_ns / NS_PER_S:.2f}s {e.action.name} {e.cause}" for e in fs.events
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
            phase=out_phase.phase,
            estimate=est,
            row=row,
            failsafe_events=tuple(fs.events),
            phase_events=tuple(out_phase.events),
            used_last_command=used_last,
            resubscribe_mk=fs.resubscribe_mk,
        )


def _dt_s(t_ns: int, last_ns: int | None) -> float:
    return math.nan if last_ns is None else (t_ns - last_ns) / NS_PER_S


def _finite_estimate(est: Estimate) -> bool:
    return all(
        math.isfinite(v)
        for v in (est.x_m, est.y_m, est.yaw_rad, est.height_m, est.vx_mps, est.vy_mps)
    )


def _finite_imu(imu: ImuSample) -> bool:
    return all(math.isfinite(v) for v in (imu.pitch_rad, imu.roll_rad, imu.yaw_rad, imu.battery_v))
