"""Run ``mkflight`` with a fault injected inside the daemon (the fault campaign's harness).

``python -m tests.faults.inject FAULT [--after-hold-s S] -- ARGS...`` runs
``mkflight ARGS...`` (the real CLI: argument parsing, exit codes, error lines) in this
process, with :class:`~mkflight.flight.app.FlightApp` built with the fault's seams (its
policy, notifier, ``on_step`` and ``sample_filter``). The fault is armed once the flight
has held for ``--after-hold-s`` seconds (counted in 50 ms steps), so it always hits a
vehicle in the air. Faults (``FAULTS``):

* ``crash-mk-step``, ``crash-laser``, ``crash-watchdog``: an exception inside that task
  (the step; the laser task's per-scan check; the watchdog's status refresh);
* ``crash-mk-reader``, ``crash-laser-reader``: an exception inside the MK link's or the
  URG driver's reader task (their byte taps run there);
* ``kill-matcher``: SIGKILL to the scan-matcher process;
* ``nan-estimate``, ``inf-estimate``, ``huge-estimate``: every DebugOut sample from then on
  has NaN / inf / 1e300 in its accelerations and attitude, the values the estimate is made of;
* ``wall-clock-jump``: the process's wall clock steps an hour ahead (an NTP or RTC step on
  a board without a clock), as Python code reads it: ``time.time``, ``time.time_ns`` and
  ``datetime.now``/``utcnow``/``today`` (:func:`shift_wall_clock`; structlog's stamps
  read the latter, so the daemon's log lines show the jump). The flight runs on monotonic
  clocks only (``tests/faults/test_wall_clock.py`` checks the source), so it must fly on
  as a plain hover;
* ``disk-full``: every file the daemon has open in the flight folder now fails with ENOSPC
  (``/dev/full`` put behind its descriptors with ``dup2``: the kernel's own error on the
  real write path);

This module replaces the ``FlightApp`` name in :mod:`mkflight.flight.app` by a builder of
the faulty one before the CLI imports it: a test harness, never part of the product.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import multiprocessing
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any, Final, Self

import mkflight.flight.app as app_module
from mkflight.cli import main as mkflight_main
from mkflight.config import Config
from mkflight.control.phases import Phase
from mkflight.flight.app import FlightApp, FlightOptions
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.step import ImuStepOutput
from mkflight.msgs import ImuSample

FAULTS: Final = (
    "crash-mk-step",
    "crash-laser",
    "crash-watchdog",
    "crash-mk-reader",
    "crash-laser-reader",
    "kill-matcher",
    "nan-estimate",
    "inf-estimate",
    "huge-estimate",
    "wall-clock-jump",
    "disk-full",
)
STEPS_PER_S: Final = 20
BAD_VALUES: Final = {"nan-estimate": float("nan"), "inf-estimate": float("inf")}
WALL_JUMP_S: Final = 3600.0


class _Injector:
    """Arms after the hold has lasted long enough, then applies the fault once or on."""

    def __init__(self, fault: str, after_hold_s: float) -> None:
        self.fault = fault
        self.after_steps = round(after_hold_s * STEPS_PER_S)
        self.hold_steps = 0
        self.armed = False
        self.fired = False
        self.folder: Path | None = None

    def on_step(self, out: ImuStepOutput) -> None:
        if out.phase is Phase.HOLD:
            self.hold_steps += 1
        if not self.armed and self.hold_steps >= self.after_steps:
            self.armed = True
            sys.stderr.write(f"inject: {self.fault} armed at {time.monotonic():.3f}\n")
            self._fire_once()

    def _fire_once(self) -> None:
        """The faults that happen once, from outside the tasks."""
        if self.fault == "kill-matcher":
            for child in multiprocessing.active_children():
                os.kill(child.pid or 0, signal.SIGKILL)
        elif self.fault == "wall-clock-jump":
            shift_wall_clock(WALL_JUMP_S)
        elif self.fault == "disk-full":
            self._redirect_folder_fds()
        self.fired = True

    def _redirect_folder_fds(self) -> None:
        """Put /dev/full behind every descriptor open on a file in the flight folder."""
        assert self.folder is not None
        folder = str(self.folder.resolve())
        full = os.open("/dev/full", os.O_WRONLY)
        for fd_name in os.listdir("/proc/self/fd"):
            try:
                target = os.readlink(f"/proc/self/fd/{fd_name}")
            except OSError:
                continue
            if target.startswith(folder + "/"):
                os.dup2(full, int(fd_name))
        os.close(full)

    def crash(self, where: str) -> None:
        if self.armed and self.fault == f"crash-{where}":
            self.fired = True
            msg = f"injected crash in the {where} task"
            raise RuntimeError(msg)

    def sample(self, sample: ImuSample) -> ImuSample:
        self.crash("mk-step")  # the step's first act
        if not self.armed:
            return sample
        if self.fault in ("nan-estimate", "inf-estimate", "huge-estimate"):
            bad = BAD_VALUES.get(self.fault, 1e300)
            return dataclasses.replace(
                sample, acc_x_mps2=bad, acc_y_mps2=-bad, pitch_rad=bad, roll_rad=bad
            )
        return sample


def shift_wall_clock(offset_s: float) -> None:
    """Step this process's wall clock ``offset_s`` ahead, for every reader from now on.

    ``time.time``/``time.time_ns`` are replaced in :mod:`time`; ``datetime.datetime`` by a
    subclass whose ``now``/``utcnow``/``today`` add the offset, in :mod:`datetime` (read
    there at call time, as structlog does) and in every loaded ``mkflight`` module that
    imported the class by name. The monotonic clocks are untouched, as in an NTP step.
    """
    real_time, real_time_ns = time.time, time.time_ns
    offset = datetime.timedelta(seconds=offset_s)
    real = datetime.datetime

    class ShiftedDatetime(datetime.datetime):
        @classmethod
        def now(cls, tz: datetime.tzinfo | None = None) -> Self:
            t = real.now(tz) + offset
            return cls.combine(t.date(), t.timetz())

        @classmethod
        def utcnow(cls) -> Self:
            return cls.now(datetime.UTC).replace(tzinfo=None)

        @classmethod
        def today(cls) -> Self:
            return cls.now()

    time.time = lambda: real_time() + offset_s
    time.time_ns = lambda: real_time_ns() + round(offset_s * 1e9)
    datetime.datetime = ShiftedDatetime  # type: ignore[misc]
    for name, module in list(sys.modules.items()):
        if name.startswith("mkflight") and getattr(module, "datetime", None) is real:
            module.datetime = ShiftedDatetime  # type: ignore[attr-defined]


class _FaultyPolicy(FlightPolicy):
    """The live policy, plus crashes in the laser task and in the ports' reader tasks."""

    def __init__(self, injector: _Injector) -> None:
        self._injector = injector

    def scan_wanted(self, seq: int) -> bool:
        self._injector.crash("laser")  # the laser task's per-scan check
        return super().scan_wanted(seq)

    def on_bytes(self, port: str, direction: str, n_bytes: int) -> None:
        if direction == "r":  # the byte taps run in the link's and the driver's readers
            self._injector.crash("mk-reader" if port == "mk" else "laser-reader")


def install(fault: str, after_hold_s: float) -> _Injector:
    """Make :mod:`mkflight.flight.app`'s ``FlightApp`` build the faulty one; return its injector."""
    injector = _Injector(fault, after_hold_s)
    base = app_module.FlightApp

    class FaultyNotifier(Notifier):
        def status(self, text: str) -> bool:
            injector.crash("watchdog")  # the watchdog's status refresh
            return super().status(text)

    def faulty_app(cfg: Config, opts: FlightOptions, **kwargs: Any) -> FlightApp:
        injector.folder = Path(opts.log_dir)
        return base(
            cfg,
            opts,
            notifier=FaultyNotifier.from_env(),
            policy=_FaultyPolicy(injector),
            on_step=injector.on_step,
            sample_filter=injector.sample,
            **kwargs,
        )

    app_module.FlightApp = faulty_app  # type: ignore[assignment,misc]
    return injector


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.faults.inject")
    parser.add_argument("fault", choices=FAULTS)
    parser.add_argument("--after-hold-s", type=float, default=2.0)
    parser.add_argument("args", nargs=argparse.REMAINDER, help="-- then mkflight's arguments")
    ns = parser.parse_args(argv)
    args = ns.args[1:] if ns.args[:1] == ["--"] else ns.args
    injector = install(ns.fault, ns.after_hold_s)
    code = mkflight_main(args)
    sys.stderr.write(f"inject: {ns.fault} fired={injector.fired}\n")
    return code


if __name__ == "__main__":
    sys.exit(main())
