"""The flight folder's writers for the daemon (SPEC §6), and what a full disk does to them.

One object owns them all: TABLE III and IV, ``events.jsonl``, ``flight.json`` and the raw
recordings of both ports (:mod:`mkflight.logs.raw`). Logging must never end a flight
badly: the first ``OSError`` (disk full, a read-only folder) stops every further write to
the tables and events and is handed to ``on_error`` once, which asks for a soft landing;
the raw recorders stop on their own (they count what they drop).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

import structlog

from mkflight.clock import Clock
from mkflight.config import Config
from mkflight.config_search import ConfigSource
from mkflight.control.controller import Setpoint
from mkflight.errors import PreflightError
from mkflight.flight.step import ImuStepOutput
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import FlightInfo, new_flight_info, with_summary, write_flight_json
from mkflight.logs.raw import RawRecorder, create_buffered, create_unbuffered
from mkflight.logs.schema import (
    End,
    Failsafe,
    FlightSummary,
    KnownEvent,
    PhaseChange,
    RawCounters,
    Step,
)
from mkflight.logs.table3 import Table3Row, Table3Writer
from mkflight.logs.table4 import Table4Writer
from mkflight.msgs import ImuSample

_C = TypeVar("_C")
TRUTH_FILE = "truth.txt"  # a simulator may have started its truth log in the folder


def folder_in_use(folder: Path) -> bool:
    """True if ``folder`` holds anything but a simulator's truth log: never overwritten."""
    return folder.exists() and any(p.name != TRUTH_FILE for p in folder.iterdir())


log = structlog.get_logger("mkflight.logs")

#: Numbers a :class:`Rounder` remembers before it starts again.
ROUNDED_MEMO_SIZE = 1024


class Rounder:
    """``round(value, ndigits)``, remembered for numbers that come back step after step.

    ``round`` with digits costs about a microsecond (a correctly rounded decimal
    conversion); the ``step`` event's set-point and battery voltage keep their values
    for seconds. Equal numbers round alike, except ``0.0`` and ``-0.0`` (equal, rounded
    to different signs) and NaN (equal to nothing): those are never remembered.
    """

    __slots__ = ("_memo", "_ndigits")

    def __init__(self, ndigits: int) -> None:
        self._ndigits = ndigits
        self._memo: dict[float, float] = {}

    def __call__(self, value: float) -> float:
        """``round(value, ndigits)``."""
        rounded = self._memo.get(value)
        if rounded is None:
            rounded = round(value, self._ndigits)
            if value and value == value:  # not +-0.0, not NaN
                if len(self._memo) >= ROUNDED_MEMO_SIZE:
                    self._memo.clear()
                self._memo[value] = rounded
        return rounded


class FlightLogs:
    """Creates a flight folder's files; writes rows and events; closes with the summary."""

    def __init__(
        self,
        folder: Path,
        cfg: Config,
        *,
        mk_port: str,
        laser_port: str,
        clock: Clock,
        on_error: Callable[[OSError], None],
        durable: bool = True,
        config_source: ConfigSource | None = None,
    ) -> None:
        """Create the folder's files (the pre-flight check 'log dir').

        ``durable``: every row, event and raw record reaches the kernel as it is written
        (SPEC §6: a killed process leaves readable logs); a replay, which can always be
        run again, passes False and writes in blocks (a third less CPU per step).

        Raises:
            PreflightError: the folder is not empty, or cannot be written.
        """
        self.folder = folder
        self.on_error = on_error
        self.error: OSError | None = None
        self.events_dropped = 0  # events with a value JSON cannot hold (a bug; logged)
        self._held_4 = Rounder(4)
        self._battery_2 = Rounder(2)
        self._closers: list[Any] = []
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if folder_in_use(folder):
                msg = f"{folder} is not empty: a flight folder is never overwritten"
                raise PreflightError(check="log dir", detail=msg)
            self.info: FlightInfo = new_flight_info(
                datetime.now(UTC), cfg, config_source=config_source
            )
            write_flight_json(folder, self.info)
            self.t3 = self._keep(Table3Writer(folder))
            self.t4 = self._keep(Table4Writer(folder))
            self.events = self._keep(EventsWriter(folder))
            opener = create_unbuffered if durable else create_buffered
            self.mk_raw = self._keep(
                RawRecorder(folder / "mk.raw", mk_port, clock=clock, opener=opener)
            )
            self.laser_raw = self._keep(
                RawRecorder(folder / "laser.raw", laser_port, clock=clock, opener=opener)
            )
            if not durable:
                for table in (self.t3, self.t4, self.events):
                    table.flush_each_line = False
        except OSError as err:
            self._close_all()
            detail = f"{folder}: {err.strerror or err}"
            raise PreflightError(check="log dir", detail=detail) from err

    def _keep(self, closer: _C) -> _C:
        self._closers.append(closer)
        return closer

    def _close_all(self) -> None:
        for closer in self._closers:
            with contextlib.suppress(OSError):
                closer.close()

    def _failed(self, err: OSError) -> None:
        if self.error is None:
            self.error = err
            self.on_error(err)

    def event(self, event: KnownEvent) -> None:
        """One ``events.jsonl`` line (nothing after a write error or after closing)."""
        if self.error is not None or self.events.closed:
            return
        try:
            self.events.write(event)
        except OSError as err:
            self._failed(err)
        except (TypeError, ValueError) as err:  # a value JSON cannot hold: a bug, not a stop
            self.events_dropped += 1
            log.error("event not written", event_name=event.event, error=str(err))

    def row3(self, row: Table3Row) -> None:
        """One TABLE III row."""
        if self.error is None:
            try:
                self.t3.write_row(row)
            except OSError as err:
                self._failed(err)

    def step(
        self, sample: ImuSample, out: ImuStepOutput, sp: Setpoint | None, latency_ms: float
    ) -> None:
        """A step's TABLE IV row, its ``step`` event, its failsafe and phase events."""
        if self.error is None:
            try:
                self.t4.write_row(out.row)
            except OSError as err:
                self._failed(err)
        est = out.estimate
        held = self._held_4  # the set-point and the battery: the same values for seconds
        self.event(
            Step(
                t_ns=sample.t_ns,
                x_m=round(est.x_m, 4),
                y_m=round(est.y_m, 4),
                sp_x_m=None if sp is None else held(sp.x_m),
                sp_y_m=None if sp is None else held(sp.y_m),
                sp_height_m=None if sp is None else held(sp.height_m),
                height_m=round(est.height_m, 4),
                vz_up_mps=round(est.vz_up_mps, 4),
                gas_counts=out.command.gas_counts,
                battery_v=self._battery_2(sample.battery_v),
                phase=out.phase.name,
                action=out.action.name,
                latency_ms=round(latency_ms, 3),
            )
        )
        for e in out.failsafe_events:
            cause = getattr(e.cause, "value", "")
            self.event(Failsafe(t_ns=e.t_ns, action=e.action.name, cause=cause))
        for pe in out.phase_events:
            self.event(PhaseChange(t_ns=pe.t_ns, to=pe.to_phase.name, reason=pe.reason))

    def set_fc_version(self, text: str) -> None:
        """Put the FC's version into ``flight.json`` (known after the pre-flight)."""
        self.info = replace(self.info, fc_version=text)
        try:
            write_flight_json(self.folder, self.info)
        except OSError as err:
            self._failed(err)

    def raw_counters(self) -> tuple[RawCounters, RawCounters]:
        """The recorders' counters for the summary: ``mk.raw``'s, ``laser.raw``'s."""
        mk, laser = (
            RawCounters(
                records=rec.records,
                bytes_read=rec.bytes_read,
                bytes_written=rec.bytes_written,
                dropped=rec.dropped,
                error=None if rec.error is None else str(rec.error),
            )
            for rec in (self.mk_raw, self.laser_raw)
        )
        return mk, laser

    def close(self, t_ns: int, summary: FlightSummary) -> None:
        """The ``end`` event, every file flushed and closed, ``flight.json``'s summary."""
        self.event(End(t_ns=t_ns, exit_reason=summary.end_reason))
        self._close_all()
        with contextlib.suppress(OSError):  # a full disk: the tables hold what was written
            write_flight_json(self.folder, with_summary(self.info, summary))
