"""The flight daemon: one asyncio loop flying :class:`FlightCore` on the real links (SPEC §7).

Tasks (STYLE: pure core per tick, asyncio shell per rate):

* **MK task** - driven by DebugOut arrival (SPEC §2), not by a timer: each sample runs
  the 50 ms step (:meth:`FlightCore.imu_step`) and the ExternControl goes to the port at
  once; the tables, the events and the status come after the command is written.
* **laser task** - streams scans and hands each to the scan matcher, which runs in its
  own process (:class:`~mkflight.flight.matcher_worker.MatcherWorker`) so that a 1-3 ms
  ICP never delays a command. A finished match is queued and applied by the MK task at
  the start of its next step (so a replay knows exactly where each pose entered: the
  ``scan`` event names the step). The pitch and roll at the scan's time (for the hat,
  eq 26) come from the newest DebugOut samples.
* **watchdog task** - a timer that only watches: ``--duration``, a stop that takes too
  long, the status line and systemd's STATUS.

One way out: SIGINT, SIGTERM, ``--duration`` and a crash of the laser or watchdog task
become a :class:`StopRequest` that the step turns into a soft landing and a release
(SPEC §5). When the phase machine reaches RELEASED - or the FC is lost, or the MK task
itself crashes - the shell closes everything in order: the link hands control back
(Config = 0, several frames, also after a crash), the laser gets its QT, the matcher
process ends, the recordings and logs are flushed and closed and ``flight.json`` gets
the summary. A crash or a lost FC exits 1 after that, everything else 0.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import structlog

from mkflight.clock import NS_PER_S, Clock, MonotonicClock
from mkflight.config import Config
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.errors import FlightError, LinkError, PreflightError
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.matcher_worker import MatcherError, MatcherWorker
from mkflight.flight.preflight import (
    PreflightReport,
    check_fc,
    check_hat_and_match,
    check_laser,
    period_ms,
)
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.stats import StepStats
from mkflight.flight.step import FlightCore, ImuStepOutput, PilotSticks
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import FlightInfo, new_flight_info, with_summary, write_flight_json
from mkflight.logs.raw import RawRecorder
from mkflight.logs.table3 import Table3Writer
from mkflight.logs.table4 import Table4Writer
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import ExternControl
from mkflight.mk.units import MkCalibration
from mkflight.msgs import Command, ImuSample
from mkflight.safety.failsafe import StopRequest
from mkflight.urg.driver import UrgDriver
from mkflight.urg.driver_types import settings_from_config

URG_BAUDRATE = 115200  # USB CDC-ACM ignores it (scip2.md §1)

log = structlog.get_logger("mkflight.flight")

STOP_DEADLINE_S = 9.0
"""After a stop request, release regardless if the landing has not ended by then (SPEC: 10 s)."""
WATCH_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.5
ATTITUDE_HISTORY = 64  # DebugOut samples kept for the attitude at a scan's time (~3 s)
HANDSHAKE_CONFIRMS = 3  # confirms of neutral frames needed before take-off


class StopDeadlineError(FlightError):
    """A stop request did not end in RELEASED in time: hand control back regardless."""


@dataclass(frozen=True, slots=True)
class FlightOptions:
    """What ``mkflight fly --hover`` was asked for (SPEC §7)."""

    mk_port: str
    laser_port: str
    log_dir: Path
    height_m: float | None = None
    duration_s: float | None = None
    status_tty: bool = False
    stop_deadline_s: float = STOP_DEADLINE_S


@dataclass(slots=True)
class FlightReport:
    """How the flight ended: exit code, why, and the ``flight.json`` summary."""

    exit_code: int
    reason: str
    summary: dict[str, Any]


class FlightApp:
    """One flight: pre-flight checks, the tasks, the single way out (module docstring)."""

    def __init__(
        self,
        cfg: Config,
        opts: FlightOptions,
        *,
        clock: Clock | None = None,
        notifier: Notifier | None = None,
        on_step: Callable[[ImuStepOutput], None] | None = None,
        sample_filter: Callable[[ImuSample], ImuSample] | None = None,
    ) -> None:
        """Prepare a flight; nothing opens before :meth:`fly`.

        ``on_step`` sees every step's output; ``sample_filter`` may change each DebugOut
        sample before the step (the fault-injection seam of the tests: NaN, a crash).
        """
        self.cfg = cfg
        self.opts = opts
        self.clock: Clock = clock or MonotonicClock()
        self.notifier = notifier or Notifier.from_env()
        self.on_step = on_step
        self.sample_filter = sample_filter
        self.core = FlightCore(cfg, height_m=opts.height_m)
        self.stats = StepStats()
        self.stop_request: StopRequest | None = None
        self.stop_reason = ""
        self.stop_at_ns: int | None = None
        self.crash: BaseException | None = None
        self.link: MkLink | None = None
        self.driver: UrgDriver | None = None
        self.worker = MatcherWorker(cfg, mode=cfg.scanmatch.worker)
        self.preflight: PreflightReport | None = None
        self._pending: deque[LaserResult] = deque()
        self._attitude: deque[tuple[int, float, float]] = deque(maxlen=ATTITUDE_HISTORY)
        self._last_cmd_write_ns = 0
        self._handshake_confirms0: int | None = None
        self._start_ns = 0
        self._info: FlightInfo | None = None
        self._files: list[Any] = []
        self._t3: Table3Writer | None = None
        self._t4: Table4Writer | None = None
        self._events: EventsWriter | None = None
        self._mk_raw: RawRecorder | None = None
        self._laser_raw: RawRecorder | None = None
        self._cpu0_s = 0.0
        self._wall0_s = 0.0
        self._last_out: ImuStepOutput | None = None
        self._matcher_cpu_s = 0.0
        self._matches = 0
        self._battery_v = math.nan
        self._hold_cpu: tuple[float, float, float] | None = None
        self._hold_end: tuple[float, float, float] | None = None

    # ----- the way in ---------------------------------------------------------------------

    def _open_logs(self) -> None:
        """Create the flight folder and its files (the 'log dir writable' check)."""
        folder = self.opts.log_dir
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if any(p for p in folder.iterdir() if p.name != "truth.txt"):
                msg = f"{folder} is not empty: a flight folder is never overwritten"
                raise PreflightError(check="log dir", detail=msg)
            self._info = new_flight_info(datetime.now(UTC), self.cfg)
            write_flight_json(folder, self._info)
            self._t3, self._t4 = Table3Writer(folder), Table4Writer(folder)
            self._events = EventsWriter(folder)
            self._mk_raw = RawRecorder(folder / "mk.raw", self.opts.mk_port, clock=self.clock)
            self._laser_raw = RawRecorder(
                folder / "laser.raw", self.opts.laser_port, clock=self.clock
            )
        except OSError as err:
            raise PreflightError(
                check="log dir", detail=f"{folder}: {err.strerror or err}"
            ) from err

    def _mk_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        """Record the MK port's bytes; note when an ExternControl ('#bb...') is written."""
        if self._mk_raw is not None:
            self._mk_raw(direction, t_ns, data)
        if direction == "w" and data[1:3] == b"bb":
            self._last_cmd_write_ns = t_ns
        elif direction == "w" and data[2:3] == b"d":
            self.stats.on_resubscribe()  # the FC answers at once and restarts its period

    def _laser_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        if self._laser_raw is not None:
            self._laser_raw(direction, t_ns, data)

    async def _open_links(self) -> None:
        cfg = self.cfg
        try:
            mk_stream = await open_serial(self.opts.mk_port, cfg.mk.baudrate)
        except LinkError as err:
            raise PreflightError(check="FC port", detail=str(err)) from err
        if self._mk_raw is not None:
            self._mk_raw.mark("o", self.clock.now_ns(), self.opts.mk_port)
        self.link = MkLink(
            mk_stream,
            LinkSettings.from_config(cfg),
            MkCalibration.from_config(cfg.mk),
            self.clock,
            tap=self._mk_tap,
        )
        self.link.start()
        try:
            laser_stream = await open_serial(self.opts.laser_port, URG_BAUDRATE)
        except LinkError as err:
            raise PreflightError(check="laser port", detail=str(err)) from err
        if self._laser_raw is not None:
            self._laser_raw.mark("o", self.clock.now_ns(), self.opts.laser_port)
        laser_port = self.opts.laser_port

        async def reopen_laser() -> ByteStream:
            return await open_serial(laser_port, URG_BAUDRATE)

        self.driver = UrgDriver(
            laser_stream,
            settings_from_config(cfg.laser),
            self.clock,
            reopen=reopen_laser,
            tap=self._laser_tap,
        )
        self.driver.start()

    async def run_preflight(self) -> PreflightReport:
        """Open the logs and the links, start the matcher and run every check.

        Raises:
            PreflightError: the check that failed, by name.
        """
        self._open_logs()
        await self._open_links()
        assert self.link is not None
        assert self.driver is not None
        version, samples = await check_fc(self.link, self.cfg.safety.warn_voltage_v)
        info, scans = await check_laser(self.driver)
        await self.worker.start()
        last = samples[-1]
        first = await check_hat_and_match(self.worker, scans, last.pitch_rad, last.roll_rad)
        report = PreflightReport(
            fc_version=version.text,
            debug_period_ms=period_ms([x.t_ns for x in samples]),
            battery_v=last.battery_v,
            pitch_rad=last.pitch_rad,
            roll_rad=last.roll_rad,
            laser=info.version.get("PROD", "URG"),
            scan_period_ms=period_ms([x.t_ns for x in scans]),
            ground_height_m=first.height_m if first.height_m is not None else math.nan,
            last_sample=last,
            last_scan=scans[-1],
            first_result=first,
        )
        self._pending.append(first)
        if self._info is not None:
            self._info = replace(self._info, fc_version=version.text)
            write_flight_json(self.opts.log_dir, self._info)
        self._event(self.clock.now_ns(), "preflight", **report.as_dict())
        self.preflight = report
        return report

    # ----- the flight ---------------------------------------------------------------------

    def request_stop(self, request: StopRequest, reason: str) -> None:
        """Ask for the soft landing (the first request wins; later ones are only logged)."""
        now = self.clock.now_ns()
        self._event(now, "stop", request=request.value, reason=reason)
        if self.stop_request is None:
            self.stop_request, self.stop_reason, self.stop_at_ns = request, reason, now

    def _event(self, t_ns: int, event: str, **fields: Any) -> None:
        if self._events is not None and not self._events.closed:
            self._events.write(t_ns, event, **fields)

    def _attitude_at(self, t_ns: int) -> tuple[float, float]:
        """Pitch and roll of the DebugOut sample nearest ``t_ns`` (NaN if none)."""
        if not self._attitude:
            return math.nan, math.nan
        best = min(self._attitude, key=lambda a: abs(a[0] - t_ns))
        return best[1], best[2]

    def _apply_laser_results(self, now_ns: int) -> None:
        core, t3 = self.core, self._t3
        while self._pending:
            r = self._pending.popleft()
            row = core.laser_step(
                r.pose, r.height_m, t_ns=r.scan_t_ns, degenerate=r.degenerate, arrival_ns=now_ns
            )
            if row is not None and t3 is not None:
                t3.write_row(row)
            self._event(
                r.scan_t_ns,
                "scan",
                index=None if row is None else row.index,
                step=core.counters.imu_steps + 1,
                seq=r.seq,
                valid=r.pose is not None,
                height_m=r.height_m,
                degenerate=r.degenerate,
                match_ms=round(r.compute_s * 1000, 3),
            )

    def _handshake_ok(self) -> bool:
        assert self.link is not None
        confirms = self.link.stats.confirms
        if self.core.phase is not Phase.HANDSHAKE:
            return False
        if self._handshake_confirms0 is None:
            self._handshake_confirms0 = confirms
        return confirms - self._handshake_confirms0 >= HANDSHAKE_CONFIRMS

    def _send(self, command: Command) -> None:
        assert self.link is not None
        if command.take_control and self.link.control_blocked is not None:
            msg = f"control was handed back to the pilot ({self.link.control_blocked})"
            raise FlightError(msg)
        self.link.send_extern_control(
            ExternControl(
                nick=command.nick_counts,
                roll=command.roll_counts,
                yaw=command.yaw_counts,
                gas=command.gas_counts,
                config=1 if command.take_control else 0,
            )
        )

    def _step(self, sample: ImuSample) -> ImuStepOutput:
        """One DebugOut: laser results in, the step, the command out, then the logs."""
        if self.sample_filter is not None:
            sample = self.sample_filter(sample)
        self._attitude.append((sample.t_ns, sample.pitch_rad, sample.roll_rad))
        self._battery_v = sample.battery_v
        self._apply_laser_results(sample.t_ns)
        stop = self.stop_request
        out = self.core.imu_step(
            sample,
            PhaseRequests(
                takeoff=True,
                land=stop is not None,
                handshake_ok=self._handshake_ok(),
            ),
            sticks=PilotSticks(thrust_counts=sample.gas_counts),
            stop=stop,
        )
        written0 = self._last_cmd_write_ns
        self._send(out.command)
        written = self._last_cmd_write_ns if self._last_cmd_write_ns != written0 else None
        self.notifier.watchdog()
        self._log_step(sample, out)
        self.stats.on_step(sample.t_ns, written, self.clock.now_ns())
        self._note_hold(out.phase)
        self._last_out = out
        if self.on_step is not None:
            self.on_step(out)
        return out

    def _note_hold(self, phase: Phase) -> None:
        """CPU clocks at the start and end of HOLD: the steady-hover CPU (SPEC §9)."""
        if phase is Phase.HOLD and self._hold_cpu is None:
            self._hold_cpu = (time.process_time(), time.perf_counter(), self._matcher_cpu_s)
        elif phase is not Phase.HOLD and self._hold_cpu is not None and self._hold_end is None:
            self._hold_end = (time.process_time(), time.perf_counter(), self._matcher_cpu_s)

    def _hold_cpu_percent(self) -> dict[str, float] | None:
        """Daemon and matcher CPU during HOLD, % of one core (None without a HOLD)."""
        if self._hold_cpu is None:
            return None
        end = self._hold_end or (time.process_time(), time.perf_counter(), self._matcher_cpu_s)
        wall_s = end[1] - self._hold_cpu[1]
        if wall_s <= 0:
            return None
        return {
            "daemon": round(100.0 * (end[0] - self._hold_cpu[0]) / wall_s, 2),
            "matcher": round(100.0 * (end[2] - self._hold_cpu[2]) / wall_s, 2),
            "hold_s": round(wall_s, 1),
        }

    def _log_step(self, sample: ImuSample, out: ImuStepOutput) -> None:
        if self._t4 is not None:
            self._t4.write_row(out.row)
        sp = self.core.active_setpoint
        est = out.estimate
        self._event(
            sample.t_ns,
            "step",
            x_m=round(est.x_m, 4),
            y_m=round(est.y_m, 4),
            sp_x_m=None if sp is None else round(sp.x_m, 4),
            sp_y_m=None if sp is None else round(sp.y_m, 4),
            sp_height_m=None if sp is None else round(sp.height_m, 4),
            height_m=round(est.height_m, 4),
            vz_up_mps=round(est.vz_up_mps, 4),
            gas_counts=out.command.gas_counts,
            battery_v=round(sample.battery_v, 2),
            phase=out.phase.name,
            action=out.action.name,
            latency_ms=round(self.stats.last_latency_ms(), 3),
        )
        for e in out.failsafe_events:
            self._event(
                e.t_ns, "failsafe", action=e.action.name, cause=getattr(e.cause, "value", "")
            )
        for pe in out.phase_events:
            self._event(pe.t_ns, "phase", to=pe.to_phase.name, reason=pe.reason)

    async def _mk_task(self) -> None:
        """The 50 ms step, on every DebugOut, until the phase machine releases."""
        assert self.link is not None
        timeout_s = self.cfg.safety.mk_release_s + 1.0
        while True:
            try:
                sample = await self.link.next_sample(timeout_s)
            except LinkError as err:
                msg = f"FlightCtrl lost: {err}; it hands control to the pilot's sticks"
                raise FlightError(msg) from err
            out = self._step(sample)
            if out.phase is Phase.RELEASED:
                return

    async def _laser_task(self) -> None:
        """Scans to the matcher process; results queued for the MK task."""
        assert self.driver is not None
        timeout_s = max(1.0, self.cfg.safety.laser_stale_s * 3)
        while True:
            try:
                scan = await self.driver.next_scan(timeout_s)
            except LinkError as err:
                if self.driver.error is None:  # no scan in time: the driver keeps restarting
                    self._event(self.clock.now_ns(), "laser_silent", error=str(err))
                    continue  # and the step's laser staleness check lands the vehicle
                self._event(self.clock.now_ns(), "laser_lost", error=str(err))
                if self._laser_raw is not None:
                    self._laser_raw.mark("c", self.clock.now_ns(), str(err))
                log.warning("laser lost", error=str(err))
                await self.driver.reopen(max_wait_s=30.0)
                self._event(self.clock.now_ns(), "laser_reopened")
                if self._laser_raw is not None:
                    self._laser_raw.mark("o", self.clock.now_ns(), self.opts.laser_port)
                continue
            pitch, roll = self._attitude_at(scan.t_ns)
            try:
                result = await self.worker.process(scan, pitch, roll)
            except MatcherError as err:
                msg = f"scan matcher failed: {err}"
                raise FlightError(msg) from err
            self._matcher_cpu_s += result.compute_s
            self._matches += 1
            self._pending.append(result)

    async def _watchdog_task(self) -> None:
        """Duration, stop deadline, status line and STATUS: a timer that only watches."""
        next_status = 0.0
        while True:
            await asyncio.sleep(WATCH_PERIOD_S)
            now = self.clock.now_ns()
            elapsed_s = (now - self._start_ns) / NS_PER_S
            duration_s = self.opts.duration_s
            if duration_s is not None and elapsed_s >= duration_s and self.stop_request is None:
                self.request_stop(StopRequest.DURATION, f"--duration {duration_s:g} s")
            deadline_s = self.opts.stop_deadline_s
            if self.stop_at_ns is not None and (now - self.stop_at_ns) / NS_PER_S > deadline_s:
                msg = f"the landing did not end within {deadline_s:g} s of the stop request"
                raise StopDeadlineError(msg)
            if time.monotonic() >= next_status:
                next_status = time.monotonic() + STATUS_PERIOD_S
                self._status()

    def status_line(self) -> str:
        """Phase, height, position error, battery, step latency (SPEC §7)."""
        out = self._last_out
        if out is None:
            return "waiting for the FlightCtrl"
        est, sp = out.estimate, self.core.active_setpoint
        err = math.hypot(est.x_m - sp.x_m, est.y_m - sp.y_m) if sp is not None else math.nan
        return (
            f"{out.phase.name:<9} h {est.height_m:5.2f} m  err {err:5.3f} m  "
            f"bat {self._battery_v:5.2f} V  "
            f"step {self.stats.last_latency_ms():5.2f} ms  {out.action.name}"
        )

    def _status(self) -> None:
        line = self.status_line()
        self.notifier.status(line)
        if self.opts.status_tty:
            sys.stderr.write("\r" + line + "\x1b[K")
            sys.stderr.flush()

    async def fly(self) -> FlightReport:
        """Pre-flight, READY, the tasks, and the single way out (module docstring)."""
        loop = asyncio.get_running_loop()
        self._cpu0_s, self._wall0_s = time.process_time(), time.perf_counter()
        for sig, req in (
            (signal.SIGINT, StopRequest.SIGINT),
            (signal.SIGTERM, StopRequest.SIGTERM),
        ):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.request_stop, req, sig.name)
        error: BaseException | None = None
        try:
            await self.run_preflight()
            self.notifier.ready()
            self._start_ns = self.clock.now_ns()
            error = await self._run_tasks()
        except PreflightError as err:
            error = err
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
            summary = await self._shutdown(error)
        if isinstance(error, PreflightError | FlightError):
            return FlightReport(1, str(error), summary)
        if error is not None:
            return FlightReport(1, f"{type(error).__name__}: {error}", summary)
        return FlightReport(0, summary["end_reason"], summary)

    async def _run_tasks(self) -> BaseException | None:
        """Run the three tasks; a crash of laser/watchdog lands; the MK task's end ends all."""
        mk = asyncio.create_task(self._mk_task(), name="mk-step")
        others = {
            asyncio.create_task(self._laser_task(), name="laser"),
            asyncio.create_task(self._watchdog_task(), name="watchdog"),
        }
        crash: BaseException | None = None
        try:
            while not mk.done():
                done, _ = await asyncio.wait({mk, *others}, return_when=asyncio.FIRST_COMPLETED)
                for task in done - {mk}:
                    others.discard(task)
                    exc = task.exception()
                    if isinstance(exc, StopDeadlineError):  # release now: the shutdown does it
                        self._event(self.clock.now_ns(), "stop_deadline", error=str(exc))
                        return exc
                    if exc is not None and crash is None:
                        crash = exc
                        self._event(
                            self.clock.now_ns(), "crash", task=task.get_name(), error=repr(exc)
                        )
                        log.error("task crashed", task=task.get_name(), error=repr(exc))
                        self.request_stop(StopRequest.CRASH, f"{task.get_name()} task: {exc}")
            exc = mk.exception()
            if exc is not None:
                self._event(self.clock.now_ns(), "crash", task="mk-step", error=repr(exc))
                return exc
            return crash
        finally:
            for task in (mk, *others):
                task.cancel()
            for task in (mk, *others):
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task

    # ----- the way out --------------------------------------------------------------------

    async def _shutdown(self, error: BaseException | None) -> dict[str, Any]:
        """Release, close the ports and the matcher, write the summary, close the logs."""
        self.notifier.stopping()
        if self.opts.status_tty:
            sys.stderr.write("\n")
        released = False
        if self.link is not None:
            with contextlib.suppress(Exception):
                await self.link.close(release=True)
            released = True
        if self.driver is not None:
            with contextlib.suppress(Exception):
                await self.driver.close()
        with contextlib.suppress(Exception):
            await self.worker.close()
        summary = self._summary(error, released)
        self._event(self.clock.now_ns(), "end", exit_reason=summary["end_reason"])
        for closer in (self._t3, self._t4, self._events, self._mk_raw, self._laser_raw):
            if closer is not None:
                with contextlib.suppress(Exception):
                    closer.close()
        if self._info is not None:
            with contextlib.suppress(OSError):
                write_flight_json(self.opts.log_dir, with_summary(self._info, summary))
        return summary

    def _end_reason(self) -> str:
        """Why a flight without error ended: the stop request, else the failsafe that landed."""
        if self.stop_reason:
            return self.stop_reason
        events = self.core.counters.failsafe_events
        return f"failsafe: {events[0]}" if events else f"phase {self.core.phase.name}"

    def _summary(self, error: BaseException | None, released: bool) -> dict[str, Any]:
        wall_s = time.perf_counter() - self._wall0_s
        cpu_s = time.process_time() - self._cpu0_s
        counters = self.core.counters
        out: dict[str, Any] = {
            "end_reason": str(error) if error is not None else self._end_reason(),
            "exit_code": 0 if error is None else 1,
            "duration_s": round(wall_s, 3),
            "flight_s": round((self.clock.now_ns() - self._start_ns) / NS_PER_S, 3)
            if self._start_ns
            else 0.0,
            "final_phase": self.core.phase.name,
            "released": released,
            "failsafes": list(counters.failsafe_events),
            "timing": self.stats.summary(),
            "cpu_percent_of_one_core": round(100.0 * cpu_s / wall_s, 2) if wall_s > 0 else None,
            "cpu_percent_in_hold": self._hold_cpu_percent(),
            "matcher": {
                "scans": self._matches,
                "cpu_ms_per_scan": round(1000 * self._matcher_cpu_s / self._matches, 3)
                if self._matches
                else None,
            },
        }
        if self.preflight is not None:
            out["preflight"] = self.preflight.as_dict()
        if self.link is not None:
            out["mk_link"] = self.link.stats.summary()
        if self.driver is not None:
            out["laser_link"] = _plain(self.driver.stats)
        for name, rec in (("mk_raw", self._mk_raw), ("laser_raw", self._laser_raw)):
            if rec is not None:
                out[name] = {
                    "records": rec.records,
                    "bytes_read": rec.bytes_read,
                    "bytes_written": rec.bytes_written,
                    "dropped": rec.dropped,
                    "error": rec.error and str(rec.error),
                }
        return out


def _plain(stats: object) -> dict[str, Any]:
    """A stats dataclass's plain counters (ints and floats, nested one level)."""
    result: dict[str, Any] = {}
    for name in getattr(stats, "__slots__", ()) or vars(stats):
        value = getattr(stats, name)
        if isinstance(value, int | float | str):
            result[name] = value
        elif hasattr(value, "__slots__") or hasattr(value, "__dict__"):
            for sub in getattr(value, "__slots__", ()) or vars(value):
                v = getattr(value, sub)
                if isinstance(v, int | float):
                    result[f"{name}_{sub}"] = v
    return result
