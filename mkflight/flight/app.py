"""The flight daemon: one asyncio loop flying :class:`FlightCore` on the real links (SPEC §7).

Tasks (STYLE: pure core per tick, asyncio shell per rate):

* **MK task** - driven by DebugOut arrival (SPEC §2), not by a timer: each sample runs
  the 50 ms step (:meth:`FlightCore.imu_step`) and the ExternControl goes to the port at
  once; the tables, the events and the status come after the command is written, and
  twice a second a 'p' request for the pilot's sticks (:mod:`mkflight.safety.pilot`)
  goes out right behind the command.
* **laser task** - streams scans and hands each to the scan matcher, which runs in its
  own process (:class:`~mkflight.flight.matcher_worker.MatcherWorker`) so that a 1-3 ms
  ICP never delays a command. A finished match is queued and applied by the MK task at
  the start of its next step (so a replay knows exactly where each pose entered: the
  ``scan`` event names the step). The pitch and roll at the scan's time (for the hat,
  eq 26) come from the newest DebugOut samples.
* **watchdog task** - a timer that only watches: ``--duration``, a stop that takes too
  long, the status line and systemd's STATUS.

One way out: SIGINT, SIGTERM, SIGHUP, ``--duration``, a failed log write and a crash of
the laser or watchdog task become a :class:`StopRequest` that the step turns into a soft
landing and a release (SPEC §5); before READY a stop cancels the pre-flight. When the
phase machine reaches RELEASED - or the FC is lost, the landing overruns its deadline,
or the MK task itself crashes - the shell closes everything in order: the link hands
control back (Config = 0, several frames, also after a crash), the laser gets its QT,
the matcher process ends, the recordings and logs are flushed and closed and
``flight.json`` gets the summary (:mod:`~mkflight.flight.summary`). A crash, a lost FC,
an overrun deadline or lost logs exit 1 after that, everything else 0. The ports are
opened by :mod:`~mkflight.flight.links`, the folder's files are
:mod:`~mkflight.flight.flight_logs`', the checks :mod:`~mkflight.flight.preflight`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import math
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import structlog

from mkflight.clock import NS_PER_S, Clock, MonotonicClock
from mkflight.config import Config
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.errors import FlightError, LinkError, MkflightError, PreflightError
from mkflight.eventlog import exception_text
from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.links import open_laser, open_mk
from mkflight.flight.matcher_worker import MatcherError, MatcherWorker
from mkflight.flight.monitor import GcWatch, HoldMonitor
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
from mkflight.flight.summary import flight_summary
from mkflight.flight.tasks import (
    StopDeadlineError,
    laser_task,
    mk_task,
    watchdog_task,
)
from mkflight.io.serial import open_serial
from mkflight.io.stream import ByteStream
from mkflight.logs.schema import (
    UNSET,
    Crash,
    FlightSummary,
    KnownEvent,
    PilotOverride,
    Preflight,
    PreflightFigures,
    Ready,
    Scan,
    Stop,
    StopDeadline,
    from_plain,
)
from mkflight.mk.link import MkLink
from mkflight.mk.messages import ExternControl, Ppm
from mkflight.msgs import Command, ImuSample, plausible_imu
from mkflight.safety.failsafe import StopRequest
from mkflight.safety.pilot import PPM_PERIOD_S, PilotWatch
from mkflight.urg.driver import UrgDriver

log = structlog.get_logger("mkflight.flight")

STOP_DEADLINE_S = 9.0
"""After a stop request, release regardless if the landing has not ended by then (SPEC: 10 s)."""
PPM_PERIOD_NS = round(PPM_PERIOD_S * NS_PER_S)
ATTITUDE_HISTORY = 64  # DebugOut samples kept for the attitude at a scan's time (~3 s)
HANDSHAKE_CONFIRMS = 3  # confirms of neutral frames needed before take-off
SETTLE_S = 3.0  # HOLD precision counts from this long after HOLD begins (as sim hover)
WORKER_START_TIMEOUT_S = 60.0  # spawning the matcher (numpy, scipy) on a slow board


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
    durable_logs: bool = True  # every row to the kernel at once (False: a replay's)


@dataclass(slots=True)
class FlightReport:
    """How the flight ended: exit code, why, and the ``flight.json`` summary."""

    exit_code: int
    reason: str
    summary: FlightSummary


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
        self.link: MkLink | None = None
        self.driver: UrgDriver | None = None
        self.worker = MatcherWorker(cfg, mode=cfg.scanmatch.worker)
        self.preflight: PreflightReport | None = None
        self.pending: deque[LaserResult] = deque()
        #: when each pending result came back from the matcher (scan seq -> t_ns)
        self.result_ns: dict[int, int] = {}
        self._attitude: deque[tuple[int, float, float]] = deque(maxlen=ATTITUDE_HISTORY)
        self._last_cmd_write_ns = 0
        self._handshake_confirms0: int | None = None
        self.start_ns = 0
        self.logs: FlightLogs | None = None
        self.monitor = HoldMonitor()
        self.gc_watch = GcWatch()
        self.pilot = PilotWatch(cfg.safety.pilot_stick_counts)
        self._last_ppm: Ppm | None = None
        self._next_ppm_ns = 0
        self.cpu0_s = 0.0
        self.wall0_s = 0.0
        self._last_out: ImuStepOutput | None = None
        self.matches = 0
        self._battery_v = math.nan
        self._preflight_task: asyncio.Task[PreflightReport] | None = None
        self._status_tty = opts.status_tty

    # ----- the way in ---------------------------------------------------------------------

    def _open_logs(self) -> None:
        """Create the flight folder and its files (the 'log dir writable' check)."""
        self.logs = FlightLogs(
            self.opts.log_dir,
            self.cfg,
            mk_port=self.opts.mk_port,
            laser_port=self.opts.laser_port,
            clock=self.clock,
            on_error=self._log_failed,
            durable=self.opts.durable_logs,
        )

    def _log_failed(self, err: OSError) -> None:
        """A log write failed (disk full, read-only): logging stops, the vehicle lands."""
        log.error("log write failed: landing", error=str(err))
        self.request_stop(StopRequest.CRASH, f"log write failed: {err}")

    def mark(self, which: str, kind: str, text: str) -> None:
        """An 'o' (opened) or 'c' (lost) record in a port's raw recording."""
        if self.logs is not None:
            rec = self.logs.mk_raw if which == "mk" else self.logs.laser_raw
            rec.mark(kind, self.clock.now_ns(), text)

    def _mk_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        """Record the MK port's bytes; note when an ExternControl ('#bb...') is written."""
        if self.logs is not None:
            self.logs.mk_raw(direction, t_ns, data)
        if direction == "w" and data[1:3] == b"bb":
            self._last_cmd_write_ns = t_ns
        elif direction == "w" and data[2:3] == b"d":
            self.stats.on_resubscribe()  # the FC answers at once and restarts its period

    def _laser_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        if self.logs is not None:
            self.logs.laser_raw(direction, t_ns, data)

    async def _open_links(self) -> None:
        """Both ports as links (pre-flight checks 'FC port' and 'laser port')."""
        clock = self.clock
        self.link = await open_mk(
            self.opts.mk_port,
            self.cfg,
            clock,
            self._mk_tap,
            lambda p: self.mark("mk", "o", p),
            self.open_port,
        )
        self.driver = await open_laser(
            self.opts.laser_port,
            self.cfg,
            clock,
            self._laser_tap,
            lambda p: self.mark("laser", "o", p),
            self.open_port,
        )

    async def open_port(self, path: str, baudrate: int) -> ByteStream:
        """Open one of the daemon's ports (a serial port; a replay plays one from memory).

        Raises:
            PortNotFoundError: ``path`` does not exist.
            LinkError: it cannot be opened.
        """
        return await open_serial(path, baudrate)

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
        try:
            async with asyncio.timeout(WORKER_START_TIMEOUT_S):
                await self.worker.start()
        except (MatcherError, TimeoutError) as err:
            raise PreflightError(check="scan match", detail=f"matcher process: {err!r}") from err
        last = samples[-1]
        self._attitude.append((last.t_ns, last.pitch_rad, last.roll_rad))
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
        self.pending.append(first)
        if self.logs is not None:
            self.logs.set_fc_version(version.text)
        figures = from_plain(PreflightFigures, report.as_dict())
        self.event(Preflight.of(self.clock.now_ns(), figures))
        self.preflight = report
        return report

    # ----- the flight ---------------------------------------------------------------------

    def request_stop(self, request: StopRequest, reason: str) -> None:
        """Ask for the soft landing (the first request wins; later ones are only logged).

        Before READY there is nothing to land: the pre-flight is cancelled.
        """
        now = self.clock.now_ns()
        if self.stop_request is None:  # latched before anything that could fail (a full disk)
            self.stop_request, self.stop_reason, self.stop_at_ns = request, reason, now
            if self._preflight_task is not None and not self._preflight_task.done():
                self._preflight_task.cancel()
        # ``steps``: how many steps had run; the next one sees the stop (a replay repeats
        # it there: the request's time alone does not say whether that step's DebugOut,
        # read just before, had been stepped yet).
        steps = self.core.counters.imu_steps if self.start_ns else None
        self.event(Stop(t_ns=now, request=request.value, reason=reason, steps=steps))

    def event(self, event: KnownEvent) -> None:
        """One ``events.jsonl`` line (nothing before the folder exists or after a failure)."""
        if self.logs is not None:
            self.logs.event(event)

    def attitude_at(self, t_ns: int) -> tuple[float, float]:
        """Pitch and roll of the DebugOut sample nearest ``t_ns`` (NaN if none)."""
        if not self._attitude:
            return math.nan, math.nan
        best = min(self._attitude, key=lambda a: abs(a[0] - t_ns))
        return best[1], best[2]

    async def before_ready(self) -> None:
        """Do nothing (in flight); a replay waits here until the recorded READY time."""

    async def before_subscribe(self) -> None:
        """Do nothing (in flight); a replay waits for the recorded time of the MK task's 'd'."""

    def scan_wanted(self, seq: int) -> bool:
        """Whether the laser task matches scan ``seq``: here, always.

        A replay skips what the flight never used: the driver hands out only the newest
        scan, so a busy matcher skipped one now and then.
        """
        return True

    def laser_result_due(self, result: LaserResult, step: int) -> bool:
        """Whether ``result`` may enter at step number ``step``: always (a replay pins it)."""
        return True

    def _apply_laser_results(self, now_ns: int) -> None:
        core = self.core
        step = core.counters.imu_steps + 1
        while self.pending and self.laser_result_due(self.pending[0], step):
            r = self.pending.popleft()
            row = core.laser_step(
                r.pose, r.height_m, t_ns=r.scan_t_ns, degenerate=r.degenerate, arrival_ns=now_ns
            )
            if row is not None and self.logs is not None:
                self.logs.row3(row)
            self.event(
                Scan(
                    t_ns=r.scan_t_ns,
                    index=None if row is None else row.index,
                    step=step,
                    seq=r.seq,
                    valid=r.pose is not None,
                    got_ns=self.result_ns.pop(r.seq, None),
                    x_m=None if r.pose is None else r.pose.x_m,
                    y_m=None if r.pose is None else r.pose.y_m,
                    yaw_rad=None if r.pose is None else r.pose.yaw_rad,
                    height_m=r.height_m,
                    degenerate=r.degenerate,
                    match_ms=round(r.compute_s * 1000, 3),
                )
            )

    def _handshake_ok(self) -> bool:
        assert self.link is not None
        confirms = self.link.stats.confirms
        if self.core.phase is not Phase.HANDSHAKE:
            return False
        if self._handshake_confirms0 is None:
            self._handshake_confirms0 = confirms
        return confirms - self._handshake_confirms0 >= HANDSHAKE_CONFIRMS

    def _pilot_override(self) -> bool:
        """The newest 'P' answer through the pilot watch (a moved stick: latched)."""
        ppm = self.link.last_ppm if self.link is not None else None
        if ppm is not None and ppm is not self._last_ppm:
            self._last_ppm = ppm
            was = self.pilot.override
            if self.pilot.update(ppm) and not was:
                self.event(PilotOverride(t_ns=self.clock.now_ns(), moved=dict(self.pilot.moved)))
        return self.pilot.override

    def _ask_sticks(self, t_ns: int) -> None:
        """The pilot's sticks ('p'), twice a second, right after a command.

        Sent from the step, behind the command: a request on a timer of its own could take
        the wire just before a command and delay it, and a replay (which has no processing
        time) would see it take the wire at other moments.
        """
        if self.link is not None and t_ns >= self._next_ppm_ns:
            self._next_ppm_ns = t_ns + PPM_PERIOD_NS
            with contextlib.suppress(LinkError):  # a dead port is the MK task's to report
                self.link.request_ppm()

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

    def blind_command(self) -> ExternControl | None:
        """What the link sends once if the DebugOut stops (FlightCore.blind_command)."""
        blind = self.core.blind_command(self._battery_v)
        return None if blind is None else ExternControl(gas=blind.gas_counts, config=1)

    def step(self, sample: ImuSample) -> ImuStepOutput:
        """One DebugOut: laser results in, the step, the command out, then the logs."""
        if self.sample_filter is not None:
            sample = self.sample_filter(sample)
        sample = plausible_imu(sample)  # the attitude history and the step see the same
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
            pilot_override=self._pilot_override(),
        )
        written0 = self._last_cmd_write_ns
        self._send(out.command)
        written = self._last_cmd_write_ns if self._last_cmd_write_ns != written0 else None
        self._ask_sticks(sample.t_ns)
        self.notifier.watchdog()
        self._log_step(sample, out)
        self.stats.on_step(sample.t_ns, written, self.clock.now_ns())
        self.monitor.on_step(
            sample.t_ns,
            out.phase,
            out.estimate,
            self.core.active_setpoint,
            stopping=self.stop_request is not None,
        )
        self._last_out = out
        for pe in out.phase_events:  # the journal (--log-level info) shows the flight's course
            log.info("phase", to=pe.to_phase.name, reason=pe.reason)
        if self.on_step is not None:
            self.on_step(out)
        return out

    def _log_step(self, sample: ImuSample, out: ImuStepOutput) -> None:
        if self.logs is not None:
            sp = self.core.active_setpoint
            self.logs.step(sample, out, sp, self.stats.last_latency_ms())

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

    def show_status(self) -> None:
        """The status line: to systemd's STATUS, and redrawn on the terminal if there is one."""
        line = self.status_line()
        self.notifier.status(line)
        if self._status_tty:
            try:
                sys.stderr.write("\r" + line + "\x1b[K")
                sys.stderr.flush()
            except (OSError, ValueError):  # the terminal went away (ssh dropped)
                self._status_tty = False

    async def fly(self) -> FlightReport:
        """Pre-flight, READY, the tasks, and the single way out (module docstring)."""
        loop = asyncio.get_running_loop()
        self.cpu0_s, self.wall0_s = time.process_time(), time.perf_counter()
        for sig, req in (
            (signal.SIGINT, StopRequest.SIGINT),
            (signal.SIGTERM, StopRequest.SIGTERM),
            (signal.SIGHUP, StopRequest.SIGTERM),  # the terminal or ssh went away: land
        ):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self._on_signal, req, sig.name)
        error: BaseException | None = None
        try:
            self._preflight_task = asyncio.create_task(self.run_preflight(), name="preflight")
            try:
                await self._preflight_task
            except asyncio.CancelledError:
                if self.stop_request is None:
                    raise
                error = None  # stopped before take-off: nothing flew
            else:
                gc.collect()
                gc.freeze()  # imports and pre-flight objects: never walked again in flight
                self.gc_watch.install()
                await self.before_ready()
                self.notifier.ready()
                self.start_ns = self.clock.now_ns()
                self.event(Ready(t_ns=self.start_ns))  # steps use DebugOut from here on
                error = await self._run_tasks()
        except Exception as err:  # every failure leaves through the shutdown
            error = err
        finally:
            summary = await self._shutdown(error)  # the signal handlers stay until released
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
        if isinstance(error, PreflightError | FlightError):
            return FlightReport(1, str(error), summary)
        if error is not None:
            return FlightReport(1, f"{type(error).__name__}: {error}", summary)
        if self.logs is not None and self.logs.error is not None:  # landed, but logs are lost
            return FlightReport(1, summary.end_reason, summary)
        return FlightReport(0, summary.end_reason, summary)

    def _on_signal(self, request: StopRequest, name: str) -> None:
        """SIGINT/SIGTERM/SIGHUP: land. After SIGHUP the terminal is gone: no status line."""
        if name == "SIGHUP":
            self._status_tty = False
        self.request_stop(request, name)

    async def _run_tasks(self) -> BaseException | None:
        """Run the three tasks; a crash of laser/watchdog lands; the MK task's end ends all."""
        mk = asyncio.create_task(mk_task(self), name="mk-step")
        others = {
            asyncio.create_task(laser_task(self), name="laser"),
            asyncio.create_task(watchdog_task(self), name="watchdog"),
        }
        crash: BaseException | None = None
        try:
            while not mk.done():
                done, _ = await asyncio.wait({mk, *others}, return_when=asyncio.FIRST_COMPLETED)
                for task in done - {mk}:
                    others.discard(task)
                    exc = task.exception()
                    if isinstance(exc, StopDeadlineError):  # release now: the shutdown does it
                        self.event(StopDeadline(t_ns=self.clock.now_ns(), error=str(exc)))
                        return exc
                    if exc is not None and crash is None:
                        crash = exc
                        bug = not isinstance(exc, MkflightError)  # its stack is wanted
                        self.event(
                            Crash(
                                t_ns=self.clock.now_ns(),
                                task=task.get_name(),
                                error=repr(exc),
                                exception=exception_text(exc) if bug else UNSET,
                            )
                        )
                        log.error(
                            "task crashed",
                            task=task.get_name(),
                            error=repr(exc),
                            exc_info=exc if bug else None,
                        )
                        self.request_stop(StopRequest.CRASH, f"{task.get_name()} task: {exc}")
            exc = mk.exception()
            if isinstance(exc, StopDeadlineError):
                self.event(StopDeadline(t_ns=self.clock.now_ns(), error=str(exc)))
                return exc
            if exc is not None:
                if isinstance(exc, MkflightError):  # a failure named to the operator
                    self.event(Crash(t_ns=self.clock.now_ns(), task="mk-step", error=repr(exc)))
                    return exc
                self.event(  # a bug: its stack for whoever reads the logs
                    Crash(
                        t_ns=self.clock.now_ns(),
                        task="mk-step",
                        error=repr(exc),
                        exception=exception_text(exc),
                    )
                )
                log.error("task crashed", task="mk-step", exc_info=exc)
                return exc
            return crash
        finally:
            for task in (mk, *others):
                task.cancel()
            for task in (mk, *others):
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task

    # ----- the way out --------------------------------------------------------------------

    async def _shutdown(self, error: BaseException | None) -> FlightSummary:
        """Release, close the ports and the matcher, write the summary, close the logs."""
        self.notifier.stopping()
        self.gc_watch.uninstall()
        released = False
        if self.link is not None:
            before = self.link.stats.frames_written
            with contextlib.suppress(Exception):
                await self.link.close(release=True)
            released = self.link.stats.frames_written > before  # Config = 0 frames went out
        if self._status_tty:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write("\n")
        if self.driver is not None:
            with contextlib.suppress(Exception):
                await self.driver.close()
        with contextlib.suppress(Exception):
            await self.worker.close()
        summary = flight_summary(self, error, released)
        if self.logs is not None:
            self.logs.close(self.clock.now_ns(), summary)
        return summary
