"""The daemon's three tasks (see :mod:`mkflight.flight.app`): MK step, laser, watchdog.

* :func:`mk_task` - driven by DebugOut arrival (SPEC §2), not by a timer: one flight step
  per sample (:class:`~mkflight.flight.mk_step.MkStep`), until the phase machine
  releases; the step runs in the port's callback that read the sample
  (:meth:`~mkflight.mk.link.MkLink.serve`), not a loop turn later: the task only waits
  for the end, a failure or the timeout;
* :func:`laser_task` - streams scans to the scan matcher
  (:class:`~mkflight.flight.matcher_worker.MatcherWorker`), inline in the port's callback
  that read the scan, or in its own process so that a 1-3 ms ICP never delays a command;
  each result goes into the :class:`~mkflight.flight.laser_inbox.LaserInbox` for the
  next step;
* :func:`watchdog_task` - a timer that only watches: ``--duration``, the stop deadline,
  the status line and systemd's STATUS; it wakes when one of them is due;
* :func:`supervise` - runs them together: a crash of the laser or watchdog task lands
  the vehicle, the MK task's end ends all.

Each takes the collaborators it works with, nothing more.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable

import structlog

from mkflight.clock import Clock
from mkflight.control.phases import Phase
from mkflight.conversions import NS_PER_S
from mkflight.errors import FlightError, LinkError, MkflightError
from mkflight.eventlog import exception_text
from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.laser_inbox import AttitudeHistory, LaserInbox
from mkflight.flight.matcher_worker import MatcherError, MatcherWorker
from mkflight.flight.mk_step import MkStep, RequestStop
from mkflight.flight.stop import StopDeadlineError, StopLatch
from mkflight.flight.taps import PortTaps
from mkflight.logs.schema import (
    UNSET,
    Crash,
    LaserLost,
    LaserReopened,
    LaserSilent,
    StopDeadline,
)
from mkflight.mk.link import MkLink
from mkflight.msgs import ImuSample, Scan
from mkflight.safety.failsafe import StopRequest
from mkflight.urg.driver import UrgDriver

log = structlog.get_logger("mkflight.flight")

WATCH_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.5
FC_REOPEN_S = 3.0  # a vanished FC port: this long to come back, only to hand control back
MK_TIMEOUT_MARGIN_S = 0.3  # after the link's release for lack of DebugOut: the flight ends
LASER_REOPEN_S = 30.0  # a vanished laser port: this long to come back


async def mk_task(
    link: MkLink,
    mk_step: MkStep,
    stop: StopLatch,
    taps: PortTaps,
    *,
    clock: Clock,
    start_ns: int,
    release_s: float,
    before_subscribe: Callable[[], Awaitable[None]],
) -> None:
    """The 50 ms step, on every DebugOut from ``start_ns`` (READY), until RELEASED.

    The link hands control back after ``release_s`` without DebugOut; a little later the
    flight ends (well inside systemd's WatchdogSec = 2 s).
    """
    timeout_s = release_s + MK_TIMEOUT_MARGIN_S
    await before_subscribe()
    link.set_blind_command(mk_step.blind_command)  # asked only when the data goes stale
    link.subscribe()  # a fresh subscription: pre-flight may have outlasted the last one

    def on_sample(sample: ImuSample) -> bool:
        """One step (in the callback that read the DebugOut); True once RELEASED."""
        if sample.t_ns < start_ns:
            return False  # older than READY: the FC may have stopped streaming since
        stop.check_deadline(clock.now_ns())
        return mk_step.step(sample).phase is Phase.RELEASED  # its write may find the port gone

    try:
        await link.serve(on_sample, timeout_s)
    except LinkError as err:
        if link.error is not None:  # the port itself failed: try to hand back
            with contextlib.suppress(Exception):  # nothing may keep us from handing back
                taps.mark("mk", "c", str(err))
            with contextlib.suppress(LinkError, TimeoutError):
                async with asyncio.timeout(FC_REOPEN_S):
                    await link.reopen(max_wait_s=FC_REOPEN_S)  # releases first
        msg = f"FlightCtrl lost: {err}; it hands control to the pilot's sticks"
        raise FlightError(msg) from err
    if mk_step.core.handed_in_air:  # the last resort: say so, exit 1
        msg = "handed to the pilot in the air: the descent without height found no floor"
        raise FlightError(msg)


async def laser_task(
    driver: UrgDriver,
    worker: MatcherWorker,
    inbox: LaserInbox,
    attitude: AttitudeHistory,
    taps: PortTaps,
    logs: FlightLogs,
    *,
    clock: Clock,
    stale_s: float,
    scan_wanted: Callable[[int], bool],
    on_scan: Callable[[Scan], None],
) -> None:
    """Scans to the matcher, at the attitude of their time; results into ``inbox``.

    ``stale_s`` is the laser's staleness limit; a scan that does not come in three of
    them (at least 1 s) makes the driver restart the stream. ``scan_wanted(seq)`` may
    skip a scan; ``on_scan`` is told of each scan as it comes (the observer's).
    """
    timeout_s = max(1.0, stale_s * 3)
    # A matcher in this process has its compiled kernel loaded: the driver decodes with it.
    driver.decode_blocks_with(worker.scan_blocks)

    def match_now(scan: Scan) -> None:
        """One scan through the inline matcher, in the callback that read it."""
        on_scan(scan)
        if scan_wanted(scan.seq):
            pitch, roll = attitude.at(scan.t_ns)
            inbox.put_matched(worker.process_now(scan, pitch, roll), clock.now_ns())

    while True:
        try:
            # An inline matcher runs in the port's callback: no loop turn per scan.
            scan = await driver.next_scan(timeout_s, match_now if worker.runs_now else None)
        except LinkError as err:
            if driver.error is None:  # no scan in time: the driver keeps restarting
                logs.event(LaserSilent(t_ns=clock.now_ns(), error=str(err)))
                continue  # and the step's laser staleness check lands the vehicle
            logs.event(LaserLost(t_ns=clock.now_ns(), error=str(err)))
            taps.mark("laser", "c", str(err))
            log.warning("laser lost", error=str(err))
            await driver.reopen(max_wait_s=LASER_REOPEN_S)
            logs.event(LaserReopened(t_ns=clock.now_ns()))
            continue
        except MatcherError as err:
            msg = f"scan matcher failed: {err}"
            raise FlightError(msg) from err
        on_scan(scan)
        if not scan_wanted(scan.seq):
            continue
        pitch, roll = attitude.at(scan.t_ns)
        try:
            result = await worker.process(scan, pitch, roll)
        except MatcherError as err:
            msg = f"scan matcher failed: {err}"
            raise FlightError(msg) from err
        inbox.put_matched(result, clock.now_ns())


async def watchdog_task(
    clock: Clock,
    stop: StopLatch,
    *,
    start_ns: int,
    duration_s: float | None,
    request_stop: RequestStop,
    show_status: Callable[[], None],
) -> None:
    """``--duration``, the stop deadline, the status line: a timer that only watches.

    It wakes when something is due (:func:`watch_sleep_s`), not every 50 ms: the steps
    check the stop deadline themselves, this is for when no step comes. Its work runs in
    the timer's own callback: a sleeping task would take a second loop turn per wake-up
    (the sleep's timer, then the task). The task only waits for an error, raised here.
    """
    loop = asyncio.get_running_loop()  # its time: the lock-step clock in a replay
    ended: asyncio.Future[None] = loop.create_future()
    next_status = 0.0
    timer: asyncio.TimerHandle | None = None

    def watch() -> None:
        nonlocal next_status, timer
        try:
            now = clock.now_ns()
            elapsed_s = (now - start_ns) / NS_PER_S
            if duration_s is not None and elapsed_s >= duration_s and stop.request is None:
                request_stop(StopRequest.DURATION, f"--duration {duration_s:g} s")
            now = clock.now_ns()
            stop.check_deadline(now)
            if loop.time() >= next_status:
                next_status = loop.time() + STATUS_PERIOD_S
                show_status()
            end_ns = None if duration_s is None else start_ns + round(duration_s * NS_PER_S)
            sleep_s = watch_sleep_s(
                now, status_in_s=next_status - loop.time(), duration_end_ns=end_ns, stop=stop
            )
        except Exception as err:  # the task raises it: supervise() lands or ends
            if not ended.done():
                ended.set_exception(err)
            return
        timer = loop.call_at(loop.time() + sleep_s, watch)

    timer = loop.call_at(loop.time() + WATCH_PERIOD_S, watch)
    try:
        await ended
    finally:
        if timer is not None:
            timer.cancel()


def watch_sleep_s(
    now_ns: int, *, status_in_s: float, duration_end_ns: int | None, stop: StopLatch
) -> float:
    """How long the watchdog may sleep: until the next thing it watches is due.

    That is the status line, ``--duration`` or the stop deadline, but at least
    :data:`WATCH_PERIOD_S` (so nothing is noticed later than by a 50 ms poll) and at
    most :data:`STATUS_PERIOD_S`.
    """
    due_s = status_in_s
    if duration_end_ns is not None and stop.request is None:
        due_s = min(due_s, (duration_end_ns - now_ns) / NS_PER_S)
    if stop.at_ns is not None:
        deadline_ns = stop.at_ns + round(stop.deadline_s * NS_PER_S)
        due_s = min(due_s, (deadline_ns - now_ns) / NS_PER_S)
    return min(STATUS_PERIOD_S, max(WATCH_PERIOD_S, due_s))


async def supervise(
    mk: asyncio.Task[None],
    others: set[asyncio.Task[None]],
    *,
    logs: FlightLogs,
    clock: Clock,
    request_stop: RequestStop,
) -> BaseException | None:
    """Run the MK task and the ``others`` until the MK task ends; then cancel the rest.

    A crash of another task is logged and lands the vehicle (the first one is returned
    if the MK task ends well); a stop deadline or the MK task's own failure ends the
    flight at once. Returns the error to exit 1 with (None: released as asked).
    """
    crash: BaseException | None = None
    try:
        while not mk.done():
            done, _ = await asyncio.wait({mk, *others}, return_when=asyncio.FIRST_COMPLETED)
            for task in done - {mk}:
                others.discard(task)
                exc = task.exception()
                if isinstance(exc, StopDeadlineError):  # release now: the shutdown does it
                    logs.event(StopDeadline(t_ns=clock.now_ns(), error=str(exc)))
                    return exc
                if exc is not None and crash is None:
                    crash = exc
                    _task_crashed(task.get_name(), exc, logs, clock)
                    request_stop(StopRequest.CRASH, f"{task.get_name()} task: {exc}")
        return _mk_ended(mk.exception(), logs, clock) or crash
    finally:
        for task in (mk, *others):
            task.cancel()
        for task in (mk, *others):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task


def _task_crashed(name: str, exc: BaseException, logs: FlightLogs, clock: Clock) -> None:
    """The laser or watchdog task crashed: its event and log line."""
    bug = not isinstance(exc, MkflightError)  # its stack is wanted
    logs.event(
        Crash(
            t_ns=clock.now_ns(),
            task=name,
            error=repr(exc),
            exception=exception_text(exc) if bug else UNSET,
        )
    )
    log.error("task crashed", task=name, error=repr(exc), exc_info=exc if bug else None)


def _mk_ended(exc: BaseException | None, logs: FlightLogs, clock: Clock) -> BaseException | None:
    """Why the MK task ended (None: released as the phase machine asked), logged."""
    if isinstance(exc, StopDeadlineError):
        logs.event(StopDeadline(t_ns=clock.now_ns(), error=str(exc)))
        return exc
    if exc is not None:
        if isinstance(exc, MkflightError):  # a failure named to the operator
            logs.event(Crash(t_ns=clock.now_ns(), task="mk-step", error=repr(exc)))
            return exc
        logs.event(  # a bug: its stack for whoever reads the logs
            Crash(
                t_ns=clock.now_ns(),
                task="mk-step",
                error=repr(exc),
                exception=exception_text(exc),
            )
        )
        log.error("task crashed", task="mk-step", exc_info=exc)
        return exc
    return None
