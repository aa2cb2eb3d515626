"""The daemon's three tasks (see :mod:`mkflight.flight.app`): MK step, laser, watchdog.

* :func:`mk_task` - one flight step per DebugOut, until the phase machine releases;
* :func:`laser_task` - scans to the matcher process, results queued for the next step;
* :func:`watchdog_task` - a timer that only watches: ``--duration``, the stop deadline,
  the status line and systemd's STATUS.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import TYPE_CHECKING

import structlog

from mkflight.clock import NS_PER_S
from mkflight.control.phases import Phase
from mkflight.errors import FlightError, LinkError
from mkflight.flight.matcher_worker import MatcherError
from mkflight.logs.schema import LaserLost, LaserReopened, LaserSilent
from mkflight.safety.failsafe import StopRequest

if TYPE_CHECKING:
    from mkflight.flight.app import FlightApp

log = structlog.get_logger("mkflight.flight")

WATCH_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.5
FC_REOPEN_S = 3.0  # a vanished FC port: this long to come back, only to hand control back


class StopDeadlineError(FlightError):
    """A stop request did not end in RELEASED in time: hand control back regardless."""


async def mk_task(app: FlightApp) -> None:
    """The 50 ms step, on every DebugOut, until the phase machine releases."""
    link = app.link
    assert link is not None
    # The link hands control back after mk_release_s without DebugOut; a little later
    # the flight ends (well inside systemd's WatchdogSec = 2 s).
    timeout_s = app.cfg.safety.mk_release_s + 0.3
    await app.before_subscribe()
    link.set_blind_command(app.blind_command)  # asked only when the data goes stale
    link.subscribe()  # a fresh subscription: pre-flight may have outlasted the last one
    while True:
        try:
            sample = await link.next_sample(timeout_s)
            if sample.t_ns < app.start_ns:
                continue  # older than READY: the FC may have stopped streaming since
            check_deadline(app)
            out = app.step(sample)  # its command's write may find the port gone
        except LinkError as err:
            if link.error is not None:  # the port itself failed: try to hand back
                with contextlib.suppress(Exception):  # nothing may keep us from handing back
                    app.mark("mk", "c", str(err))
                with contextlib.suppress(LinkError, TimeoutError):
                    async with asyncio.timeout(FC_REOPEN_S):
                        await link.reopen(max_wait_s=FC_REOPEN_S)  # releases first
            msg = f"FlightCtrl lost: {err}; it hands control to the pilot's sticks"
            raise FlightError(msg) from err
        if out.phase is Phase.RELEASED:
            if app.core.handed_in_air:  # the last resort: say so, exit 1
                msg = "handed to the pilot in the air: the descent without height found no floor"
                raise FlightError(msg)
            return


def check_deadline(app: FlightApp) -> None:
    """A stop request not landed in time: end the flight (the shutdown releases)."""
    deadline_s = app.opts.stop_deadline_s
    now = app.clock.now_ns()
    if app.stop_at_ns is not None and (now - app.stop_at_ns) / NS_PER_S > deadline_s:
        msg = f"the landing did not end within {deadline_s:g} s of the stop request"
        raise StopDeadlineError(msg)


async def laser_task(app: FlightApp) -> None:
    """Scans to the matcher process; results queued for the MK task."""
    assert app.driver is not None
    timeout_s = max(1.0, app.cfg.safety.laser_stale_s * 3)
    while True:
        try:
            scan = await app.driver.next_scan(timeout_s)
        except LinkError as err:
            if app.driver.error is None:  # no scan in time: the driver keeps restarting
                app.event(LaserSilent(t_ns=app.clock.now_ns(), error=str(err)))
                continue  # and the step's laser staleness check lands the vehicle
            app.event(LaserLost(t_ns=app.clock.now_ns(), error=str(err)))
            app.mark("laser", "c", str(err))
            log.warning("laser lost", error=str(err))
            await app.driver.reopen(max_wait_s=30.0)
            app.event(LaserReopened(t_ns=app.clock.now_ns()))
            continue
        if not app.scan_wanted(scan.seq):
            continue
        pitch, roll = app.attitude_at(scan.t_ns)
        try:
            result = await app.worker.process(scan, pitch, roll)
        except MatcherError as err:
            msg = f"scan matcher failed: {err}"
            raise FlightError(msg) from err
        app.monitor.matcher_cpu_s += result.compute_s
        app.matches += 1
        app.result_ns[result.seq] = app.clock.now_ns()  # the scan event says when
        app.pending.append(result)


async def watchdog_task(app: FlightApp) -> None:
    """Duration, stop deadline, status line and STATUS: a timer that only watches."""
    next_status = 0.0
    loop = asyncio.get_running_loop()  # its time: the lock-step clock in a replay
    while True:
        await asyncio.sleep(WATCH_PERIOD_S)
        now = app.clock.now_ns()
        elapsed_s = (now - app.start_ns) / NS_PER_S
        duration_s = app.opts.duration_s
        if duration_s is not None and elapsed_s >= duration_s and app.stop_request is None:
            app.request_stop(StopRequest.DURATION, f"--duration {duration_s:g} s")
        check_deadline(app)
        if loop.time() >= next_status:
            next_status = loop.time() + STATUS_PERIOD_S
            app.show_status()
