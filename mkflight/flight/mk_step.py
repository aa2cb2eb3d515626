"""One DebugOut through the flight shell: :class:`MkStep` (the MK task's work, SPEC §2).

Per DebugOut sample, in this order: the sample is made plausible (the attitude history
and the core see the same), the matcher's results that are due enter the core, the
50 ms step runs (:meth:`FlightCore.imu_step`) and its ExternControl goes to the port at
once; then the pilot's sticks are asked for, systemd's watchdog is pinged, and the
tables, the events and the timing figures are written - after the command, so that
none of it delays it.
"""

from __future__ import annotations

from collections.abc import Callable

import structlog

from mkflight.clock import Clock
from mkflight.control.phases import PhaseRequests
from mkflight.conversions import MS_PER_S
from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.laser_inbox import AttitudeHistory, LaserInbox
from mkflight.flight.mk_commands import MkCommands
from mkflight.flight.monitor import HoldMonitor
from mkflight.flight.observer import FlightObserver
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.stats import StepStats
from mkflight.flight.status import status_line
from mkflight.flight.step import FlightCore, ImuStepOutput, PilotSticks
from mkflight.flight.stop import StopLatch
from mkflight.flight.taps import PortTaps
from mkflight.logs.schema import PilotOverride, Scan
from mkflight.mk.messages import ExternControl
from mkflight.msgs import ImuSample, plausible_imu
from mkflight.safety.failsafe import StopRequest

log = structlog.get_logger("mkflight.flight")

#: Asks for the soft landing: ``request_stop(request, reason)``.
RequestStop = Callable[[StopRequest, str], None]


class MkStep:
    """The shell around :meth:`FlightCore.imu_step` (see the module docstring).

    ``observer`` is told of every step, last (the live view); ``on_step`` sees every
    step's output; ``sample_filter`` may change each DebugOut sample before the step (the
    fault-injection seam of the tests: NaN, a crash).
    """

    def __init__(
        self,
        core: FlightCore,
        commands: MkCommands,
        logs: FlightLogs,
        taps: PortTaps,
        *,
        clock: Clock,
        stop: StopLatch,
        request_stop: RequestStop,
        inbox: LaserInbox,
        attitude: AttitudeHistory,
        stats: StepStats,
        monitor: HoldMonitor,
        notifier: Notifier,
        policy: FlightPolicy,
        observer: FlightObserver | None = None,
        on_step: Callable[[ImuStepOutput], None] | None = None,
        sample_filter: Callable[[ImuSample], ImuSample] | None = None,
    ) -> None:
        self.core = core
        self._commands = commands
        self._logs = logs
        self._taps = taps
        self._clock = clock
        self._stop = stop
        self._request_stop = request_stop
        self._inbox = inbox
        self._attitude = attitude
        self._stats = stats
        self._monitor = monitor
        self._notifier = notifier
        self._policy = policy
        self._observer = observer or FlightObserver()
        self._on_step = on_step
        self._sample_filter = sample_filter
        self._last_out: ImuStepOutput | None = None
        self._battery_v = float("nan")

    def step(self, sample: ImuSample) -> ImuStepOutput:
        """One DebugOut: laser results in, the step, the command out, then the logs."""
        for request, reason in self._policy.stops_due(self.core.counters.imu_steps):
            self._request_stop(request, reason)
        if self._sample_filter is not None:
            sample = self._sample_filter(sample)
        sample = plausible_imu(sample)  # the attitude history and the step see the same
        self._attitude.add(sample.t_ns, sample.pitch_rad, sample.roll_rad)
        self._battery_v = sample.battery_v
        self._apply_laser_results(sample.t_ns)
        stop = self._stop.request
        out = self.core.imu_step(
            sample,
            PhaseRequests(
                takeoff=True,
                land=stop is not None,
                handshake_ok=self._commands.handshake_ok(self.core.phase),
            ),
            sticks=PilotSticks(thrust_counts=sample.gas_counts),
            stop=stop,
            pilot_override=self._pilot_override(),
        )
        written0 = self._taps.command_written_ns
        self._commands.send(out.command)
        written = self._taps.command_written_ns
        self._commands.ask_sticks(sample.t_ns)
        self._notifier.watchdog()
        self._logs.step(sample, out, self.core.active_setpoint, self._stats.last_latency_ms())
        self._stats.on_step(
            sample.t_ns, written if written != written0 else None, self._clock.now_ns()
        )
        self._monitor.on_step(
            sample.t_ns,
            out.phase,
            out.estimate,
            self.core.active_setpoint,
            stopping=self._stop.request is not None,
            matcher_cpu_s=self._inbox.matcher_cpu_s,
        )
        self._last_out = out
        for pe in out.phase_events:  # the journal (--log-level info) shows the flight's course
            log.info("phase", to=pe.to_phase.name, reason=pe.reason)
        if self._on_step is not None:
            self._on_step(out)
        self._policy.after_step(self._logs)
        self._observer.on_step(sample, out, self.core.active_setpoint)
        return out

    def _apply_laser_results(self, now_ns: int) -> None:
        """The matcher's results due at this step into the core (TABLE III), each an event."""
        core = self.core
        step = core.counters.imu_steps + 1
        while (r := self._inbox.peek()) is not None and self._policy.laser_result_due(r, step):
            r, got_ns = self._inbox.pop()
            row = core.laser_step(
                r.pose, r.height_m, t_ns=r.scan_t_ns, degenerate=r.degenerate, arrival_ns=now_ns
            )
            if row is not None:
                self._logs.row3(row)
            self._logs.event(
                Scan(
                    t_ns=r.scan_t_ns,
                    index=None if row is None else row.index,
                    step=step,
                    seq=r.seq,
                    valid=r.pose is not None,
                    got_ns=got_ns,
                    x_m=None if r.pose is None else r.pose.x_m,
                    y_m=None if r.pose is None else r.pose.y_m,
                    yaw_rad=None if r.pose is None else r.pose.yaw_rad,
                    height_m=r.height_m,
                    degenerate=r.degenerate,
                    match_ms=round(r.compute_s * MS_PER_S, 3),
                )
            )

    def _pilot_override(self) -> bool:
        """The newest 'P' answer through the pilot watch (a moved stick: latched)."""
        if self._commands.override_now():
            pilot = self._commands.pilot
            self._logs.event(PilotOverride(t_ns=self._clock.now_ns(), moved=dict(pilot.moved)))
        return self._commands.pilot.override

    def blind_command(self) -> ExternControl | None:
        """What the link sends once if the DebugOut stops (FlightCore.blind_command)."""
        blind = self.core.blind_command(self._battery_v)
        return None if blind is None else ExternControl(gas=blind.gas_counts, config=1)

    def status_line(self) -> str:
        """Phase, height, position error, battery, step latency (SPEC §7)."""
        return status_line(
            self._last_out,
            self.core.active_setpoint,
            self._battery_v,
            self._stats.last_latency_ms(),
        )
