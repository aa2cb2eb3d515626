"""The flight daemon: one asyncio loop flying :class:`FlightCore` on the real links (SPEC §7).

:class:`FlightApp` is the shell's way in and way out. In: the pre-flight opens the flight
folder (:mod:`~mkflight.flight.flight_logs`) and both ports
(:mod:`~mkflight.flight.links`, every byte recorded by :mod:`~mkflight.flight.taps`),
starts the scan matcher and runs the checks (:mod:`~mkflight.flight.preflight`); then
READY, and the three tasks (:mod:`~mkflight.flight.tasks`): the MK task steps on every
DebugOut (:class:`~mkflight.flight.mk_step.MkStep`), the laser task feeds the matcher
process, the watchdog watches the time.

One way out (:class:`~mkflight.flight.stop.StopLatch`): SIGINT, SIGTERM, SIGHUP,
``--duration``, a failed log write and a crash of the laser or watchdog task become a
:class:`StopRequest` that the step turns into a soft landing and a release (SPEC §5);
before READY a stop cancels the pre-flight. When the phase machine reaches RELEASED - or
the FC is lost, the landing overruns its deadline, or the MK task itself crashes - the
shell closes everything in order: the link hands control back (Config = 0, several
frames, also after a crash), the laser gets its QT, the matcher process ends, the
recordings and logs are flushed and closed and ``flight.json`` gets the summary
(:mod:`~mkflight.flight.summary`). A crash, a lost FC, an overrun deadline or lost logs
exit 1 after that, everything else 0. A replay runs this same shell with its own
:class:`~mkflight.flight.policy.FlightPolicy`.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import structlog

from mkflight.clock import Clock, MonotonicClock
from mkflight.config import Config
from mkflight.config_search import ConfigSource
from mkflight.conversions import NS_PER_S
from mkflight.errors import FlightError, PreflightError
from mkflight.flight.laser_inbox import AttitudeHistory, LaserInbox
from mkflight.flight.matcher_worker import MatcherError, MatcherWorker
from mkflight.flight.mk_commands import MkCommands
from mkflight.flight.mk_step import MkStep
from mkflight.flight.monitor import GcWatch, HoldMonitor
from mkflight.flight.observer import FlightObserver
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.ports import FlightPorts, OpenPorts
from mkflight.flight.preflight import (
    PreflightReport,
    check_fc,
    check_hat_and_match,
    check_laser,
    period_ms,
)
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.stats import StepStats
from mkflight.flight.status import StatusDisplay
from mkflight.flight.step import FlightCore, ImuStepOutput
from mkflight.flight.stop import StopLatch, stop_signals
from mkflight.flight.summary import MatcherFigures, ProcessTimes, flight_summary
from mkflight.flight.tasks import laser_task, mk_task, supervise, watchdog_task
from mkflight.logs.schema import (
    FlightSummary,
    KnownEvent,
    Preflight,
    PreflightFigures,
    Ready,
    Stop,
    from_plain,
)
from mkflight.msgs import ImuSample
from mkflight.safety.failsafe import StopRequest
from mkflight.safety.pilot import PilotWatch

log = structlog.get_logger("mkflight.flight")

STOP_DEADLINE_S = 9.0
"""After a stop request, release regardless if the landing has not ended by then (SPEC: 10 s)."""
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
    config_source: ConfigSource | None = None  # for flight.json: where the config came from


@dataclass(slots=True)
class FlightReport:
    """How the flight ended: exit code, why, and the ``flight.json`` summary."""

    exit_code: int
    reason: str
    summary: FlightSummary


class FlightApp:
    """One flight: pre-flight checks, the tasks, the single way out (module docstring).

    The collaborators: ``core`` (the pure step), ``stop`` (the latched stop request),
    ``inbox`` and ``attitude`` (what the MK step and the laser task hand each other),
    ``stats``, ``monitor`` and ``gc_watch`` (what the daemon measures of itself),
    ``status`` (the status line); opened by the pre-flight: the ``ports`` (folder, MK
    link, URG driver) and the matcher ``worker``.
    """

    def __init__(
        self,
        cfg: Config,
        opts: FlightOptions,
        *,
        clock: Clock | None = None,
        notifier: Notifier | None = None,
        policy: FlightPolicy | None = None,
        worker: MatcherWorker | None = None,
        observer: FlightObserver | None = None,
        on_step: Callable[[ImuStepOutput], None] | None = None,
        sample_filter: Callable[[ImuSample], ImuSample] | None = None,
    ) -> None:
        """Prepare a flight; nothing opens before :meth:`fly`.

        ``policy``: what a replay or a test changes (default: a live flight's, which
        changes nothing); ``worker``: the scan matcher (default: as ``cfg`` says);
        ``observer`` is told of every step and scan (the live view; default: nobody).
        ``on_step`` sees every step's output; ``sample_filter`` may change each DebugOut
        sample before the step (the fault-injection seam of the tests: NaN, a crash).
        """
        self.cfg = cfg
        self.opts = opts
        self.clock: Clock = clock or MonotonicClock()
        self.notifier = notifier or Notifier.from_env()
        self.policy = policy or FlightPolicy()
        self.worker = worker or MatcherWorker(cfg, mode=cfg.scanmatch.worker)
        self.observer = observer or FlightObserver()
        self._on_step = on_step
        self._sample_filter = sample_filter
        self.core = FlightCore(cfg, height_m=opts.height_m)
        self.stop = StopLatch(opts.stop_deadline_s)
        self.inbox = LaserInbox()
        self.attitude = AttitudeHistory()
        self.stats = StepStats()
        self.monitor = HoldMonitor()
        self.gc_watch = GcWatch()
        self.status = StatusDisplay(self.notifier, tty=opts.status_tty)
        self.ports = FlightPorts(clock=self.clock, policy=self.policy, stats=self.stats)
        self.preflight: PreflightReport | None = None
        self.start_ns = 0  # READY on the flight's clock (0: not yet)
        self._preflight_task: asyncio.Task[PreflightReport] | None = None

    # ----- the way in ---------------------------------------------------------------------

    def _log_failed(self, err: OSError) -> None:
        """A log write failed (disk full, read-only): logging stops, the vehicle lands."""
        log.error("log write failed: landing", error=str(err))
        self.request_stop(StopRequest.CRASH, f"log write failed: {err}")

    async def run_preflight(self) -> PreflightReport:
        """Open the logs and the links, start the matcher and run every check.

        Raises:
            PreflightError: the check that failed, by name.
        """
        opts = self.opts
        # The matcher first: inline, its warm-up (the compiled kernel's import and load)
        # holds the loop for a second, which must not happen while the ports stream.
        try:
            async with asyncio.timeout(WORKER_START_TIMEOUT_S):
                await self.worker.start()
        except (MatcherError, TimeoutError) as err:
            raise PreflightError(check="scan match", detail=f"matcher process: {err!r}") from err
        logs, _, link, driver = await self.ports.open(
            self.cfg,
            opts.log_dir,
            mk_port=opts.mk_port,
            laser_port=opts.laser_port,
            durable=opts.durable_logs,
            on_log_error=self._log_failed,
            config_source=opts.config_source,
        )
        version, samples = await check_fc(link, self.cfg.safety.warn_voltage_v)
        info, scans = await check_laser(driver)
        last = samples[-1]
        self.attitude.add(last.t_ns, last.pitch_rad, last.roll_rad)
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
        self.inbox.put(first)
        logs.set_fc_version(version.text)
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
        # latched before anything that could fail (a full disk)
        first = self.stop.latch(request, reason, now)
        if first and self._preflight_task is not None and not self._preflight_task.done():
            self._preflight_task.cancel()
        # ``steps``: how many steps had run; the next one sees the stop (a replay repeats
        # it there: the request's time alone does not say whether that step's DebugOut,
        # read just before, had been stepped yet).
        steps = self.core.counters.imu_steps if self.start_ns else None
        self.event(Stop(t_ns=now, request=request.value, reason=reason, steps=steps))

    def event(self, event: KnownEvent) -> None:
        """One ``events.jsonl`` line (nothing before the folder exists or after a failure)."""
        if self.ports.logs is not None:
            self.ports.logs.event(event)

    async def fly(self) -> FlightReport:
        """Pre-flight, READY, the tasks, and the single way out (module docstring)."""
        started = ProcessTimes.now()
        error: BaseException | None = None
        collecting = gc.isenabled()
        # No collections during the pre-flight: the matcher's warm-up and the links'
        # start-up allocate ~100k long-lived objects, and every young collection that
        # spills into the older generations walks them all again; the one gc.collect()
        # at READY finds whatever garbage they left.
        gc.disable()
        with stop_signals(asyncio.get_running_loop(), self._on_signal):  # until released
            try:
                self._preflight_task = asyncio.create_task(self.run_preflight(), name="preflight")
                try:
                    await self._preflight_task
                except asyncio.CancelledError:
                    if self.stop.request is None:
                        raise
                    error = None  # stopped before take-off: nothing flew
                else:
                    gc.collect()
                    # Imports and pre-flight objects: never walked again in flight ("the
                    # permanent generation", CPython's gc.freeze() documentation).
                    gc.freeze()
                    if collecting:
                        gc.enable()
                    self.gc_watch.install()
                    await self.policy.before_ready()
                    self.notifier.ready()
                    self.start_ns = self.clock.now_ns()
                    self.event(Ready(t_ns=self.start_ns))  # steps use DebugOut from here on
                    error = await self._run_tasks()
            except Exception as err:  # every failure leaves through the shutdown
                error = err
            finally:
                if collecting:
                    gc.enable()  # also after a failed or stopped pre-flight
                summary = await self._shutdown(error, started)
        if isinstance(error, PreflightError | FlightError):
            return FlightReport(1, str(error), summary)
        if error is not None:
            return FlightReport(1, f"{type(error).__name__}: {error}", summary)
        if self.ports.logs is not None and self.ports.logs.error is not None:  # logs lost
            return FlightReport(1, summary.end_reason, summary)
        return FlightReport(0, summary.end_reason, summary)

    def _on_signal(self, request: StopRequest, name: str) -> None:
        """SIGINT/SIGTERM/SIGHUP: land. After SIGHUP the terminal is gone: no status line."""
        self.policy.on_signal(name)
        if name == "SIGHUP":
            self.status.terminal_gone()
        self.request_stop(request, name)

    def _mk_step(self, ports: OpenPorts) -> MkStep:
        """The MK task's step, on the links and logs the pre-flight opened."""
        return MkStep(
            self.core,
            MkCommands(ports.link, PilotWatch(self.cfg.safety.pilot_stick_counts)),
            ports.logs,
            ports.taps,
            clock=self.clock,
            stop=self.stop,
            request_stop=self.request_stop,
            inbox=self.inbox,
            attitude=self.attitude,
            stats=self.stats,
            monitor=self.monitor,
            notifier=self.notifier,
            policy=self.policy,
            observer=self.observer,
            on_step=self._on_step,
            sample_filter=self._sample_filter,
        )

    def _start_tasks(self, ports: OpenPorts) -> tuple[asyncio.Task[None], set[asyncio.Task[None]]]:
        """The MK task, and the laser and watchdog tasks beside it (in this order)."""
        mk_step, clock = self._mk_step(ports), self.clock
        mk = asyncio.create_task(
            mk_task(
                ports.link,
                mk_step,
                self.stop,
                ports.taps,
                clock=clock,
                start_ns=self.start_ns,
                release_s=self.cfg.safety.mk_release_s,
                before_subscribe=self.policy.before_subscribe,
            ),
            name="mk-step",
        )
        laser = laser_task(
            ports.driver,
            self.worker,
            self.inbox,
            self.attitude,
            ports.taps,
            ports.logs,
            clock=clock,
            stale_s=self.cfg.safety.laser_stale_s,
            scan_wanted=self.policy.scan_wanted,
            on_scan=self.observer.on_scan,
        )
        watchdog = watchdog_task(
            clock,
            self.stop,
            start_ns=self.start_ns,
            duration_s=self.opts.duration_s,
            request_stop=self.request_stop,
            show_status=lambda: self.status.show(mk_step.status_line()),
        )
        others = {
            asyncio.create_task(laser, name="laser"),
            asyncio.create_task(watchdog, name="watchdog"),
        }
        return mk, others

    async def _run_tasks(self) -> BaseException | None:
        """Run the three tasks until the MK task ends (:func:`supervise`)."""
        ports = self.ports.opened()
        mk, others = self._start_tasks(ports)
        return await supervise(
            mk, others, logs=ports.logs, clock=self.clock, request_stop=self.request_stop
        )

    # ----- the way out --------------------------------------------------------------------

    async def _shutdown(self, error: BaseException | None, started: ProcessTimes) -> FlightSummary:
        """Release, close the ports and the matcher, write the summary, close the logs."""
        self.notifier.stopping()
        self.gc_watch.uninstall()
        released = await self.ports.hand_back()
        self.status.end()
        await self.ports.close_laser()
        with contextlib.suppress(Exception):
            await self.worker.close()
        summary = self._summary(error, released, started)
        self.ports.close_logs(summary)
        return summary

    def _summary(
        self, error: BaseException | None, released: bool, started: ProcessTimes
    ) -> FlightSummary:
        """The ``flight.json`` summary, from what each collaborator measured."""
        end = ProcessTimes.now()
        now_ns = self.clock.now_ns()
        logs, link, driver = self.ports.logs, self.ports.link, self.ports.driver
        return flight_summary(
            error,
            stop_reason=self.stop.reason,
            phase=self.core.phase,
            failsafes=self.core.counters.failsafe_events,
            learned=self.core.learned(),
            released=released,
            wall_s=end.wall_s - started.wall_s,
            cpu_s=end.cpu_s - started.cpu_s,
            flight_s=(now_ns - self.start_ns) / NS_PER_S if self.start_ns else 0.0,
            timing=self.stats.summary(),
            hold_cpu=self.monitor.cpu_percent(self.inbox.matcher_cpu_s),
            precision=self.monitor.precision(),
            gc=self.gc_watch.summary(),
            matcher=MatcherFigures(self.inbox.matches, self.inbox.matcher_cpu_s),
            preflight=self.preflight,
            mk_link=None if link is None else link.stats.summary(),
            laser_link=None if driver is None else driver.stats,
            raw=None if logs is None else logs.raw_counters(),
            log_error=None if logs is None else logs.error,
        )
