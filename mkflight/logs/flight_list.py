"""The flights of a folder (``logging.dir``): one flat record per flight folder.

:func:`list_flights` reads each flight folder's ``flight.json`` (and, for what it lacks,
a few cheap looks at the other files) into a :class:`FlightRecord`: scalar fields only,
the same keys for every flight, None where a value is not known, so a lab's flights load
straight into a table (``mkflight flights --json`` into pandas or DuckDB).

What is a flight folder: a directory (not a symlink: ``latest`` would list the newest
twice) holding at least one of the files a flight writes (``flight.json``, the two
tables, ``events.jsonl``, the raw recordings). Anything else is skipped.

Where the values come from:

* the daemon's summary (:class:`~mkflight.logs.schema.FlightSummary`, ``kind`` "fly"):
  end reason, exit code, wall duration, READY-to-end flight time, final phase, the
  hover precision it measured against its own estimate (``est_std_*``), the failsafes;
* ``sim hover``'s (:class:`~mkflight.logs.schema.HoverSummary`, ``kind`` "sim hover"):
  its ``end`` as the end reason, the simulated seconds as the duration, its precision
  against the truth (``truth_std_*``); no exit code;
* a simulator's ``truth.txt`` beside a daemon's flight: the HOLD precision against it
  (:mod:`mkflight.analysis.precision`, as ``fly`` prints it), ``truth_std_*``;
* no summary (a killed flight, or one still flying): ``status`` "no summary", the duration
  from the first and last lines of ``events.jsonl``.

Failsafes: the decisions the summary lists (``t+12.30s LAND laser_stale``), without the
planned landings (causes ``stop_*``: ``--duration``, a signal): their count, and their
``ACTION cause`` kinds in order of first appearance, joined by ``"; "``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Final

from mkflight.errors import MkflightError
from mkflight.logs import flight_json
from mkflight.logs.folders import flight_number
from mkflight.logs.schema import FlightSummary, HoverSummary

__all__ = ["FLIGHT_FILES", "FlightRecord", "flight_record", "is_flight_folder", "list_flights"]

#: The files a flight writes: a folder with one of them is a flight folder.
FLIGHT_FILES: Final = (
    "flight.json",
    "imu_50ms.log",
    "laser_100ms.log",
    "events.jsonl",
    "mk.raw",
    "laser.raw",
)
_TRUTH: Final = "truth.txt"
_EVENTS: Final = "events.jsonl"
_T_NS_RE: Final = re.compile(rb'"t_ns"\s*:\s*(-?\d+)')
_TAIL_BYTES: Final = 4096
_PLANNED: Final = "stop_"
_TRUTH_STD: Final = ("truth_std_x_m", "truth_std_y_m", "truth_std_z_m")


@dataclass(frozen=True, slots=True)
class FlightRecord:
    """One flight folder as a flat record (module docstring: where each value comes from).

    Attributes:
        number: the flight number of the folder's name (``0042-...``), None for others.
        folder: the folder's name.
        path: the folder's path as listed.
        status: "ended" (a summary), "no summary" (killed or still flying), "no
            flight.json", "unknown summary" (another version's) or "unreadable".
        kind: "fly" or "sim hover" (whose summary), None without one.
        start_utc: ``flight.json``'s start, ISO 8601 UTC.
        duration_s: the run's duration (fly: wall time; sim hover: simulated time; no
            summary: first to last event).
        flight_s: READY to the end, on the flight clock (fly only).
        end_reason: why it ended (fly: ``end_reason``; sim hover: ``end``).
        exit_code: the daemon's exit code (fly only).
        final_phase: the flight phase at the end (fly only).
        released: Config = 0 went out at the end (control is the pilot's).
        est_std_x_m: HOLD std of the estimate about the set-point (the flight's own view).
        truth_std_x_m: HOLD std of the truth about the set-point (a simulated flight).
        failsafe_count: unplanned failsafe decisions (``stop_*`` causes left out).
        failsafe_kinds: their ``ACTION cause``, first appearance order, ``"; "``-joined.
        mkflight_version: the software that flew.
        fc_version: the FlightCtrl's version text.
        error: why the folder could not be read fully, else None.
    """

    number: int | None
    folder: str
    path: str
    status: str
    kind: str | None = None
    start_utc: str | None = None
    duration_s: float | None = None
    flight_s: float | None = None
    end_reason: str | None = None
    exit_code: int | None = None
    final_phase: str | None = None
    released: bool | None = None
    est_std_x_m: float | None = None
    est_std_y_m: float | None = None
    est_std_z_m: float | None = None
    truth_std_x_m: float | None = None
    truth_std_y_m: float | None = None
    truth_std_z_m: float | None = None
    failsafe_count: int | None = None
    failsafe_kinds: str | None = None
    mkflight_version: str | None = None
    fc_version: str | None = None
    error: str | None = None

    def as_dict(self) -> dict[str, str | int | float | bool | None]:
        """The record as a JSON object's fields, in the stable order above."""
        return asdict(self)


FIELDS: Final = tuple(f.name for f in fields(FlightRecord))
"""Every record's keys, in order."""


def is_flight_folder(path: Path) -> bool:
    """A real directory (not a symlink) holding one of :data:`FLIGHT_FILES`.

    A directory that cannot be looked into counts (it is listed as unreadable).
    """
    if path.is_symlink() or not path.is_dir():
        return False
    try:
        return any((path / name).is_file() for name in FLIGHT_FILES)
    except OSError:
        return True


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def failsafe_kinds(decisions: list[str]) -> list[str]:
    """The unplanned decisions' ``ACTION cause`` (``t+12.30s LAND laser_stale``), in order."""
    out: list[str] = []
    for text in decisions:
        parts = text.split()
        words = parts[1:] if parts and parts[0].startswith("t+") else parts
        if not words or (len(words) > 1 and words[1].startswith(_PLANNED)):
            continue
        out.append(" ".join(words))
    return out


def _failsafes(decisions: list[str]) -> dict[str, Any]:
    kinds = failsafe_kinds(decisions)
    unique = list(dict.fromkeys(kinds))
    return {"failsafe_count": len(kinds), "failsafe_kinds": "; ".join(unique)}


def _from_fly(s: FlightSummary) -> dict[str, Any]:
    est = s.precision_estimate
    return {
        "kind": "fly",
        "duration_s": _finite(s.duration_s),
        "flight_s": _finite(s.flight_s),
        "end_reason": s.end_reason,
        "exit_code": s.exit_code,
        "final_phase": s.final_phase,
        "released": s.released,
        "est_std_x_m": None if est is None else _finite(est.std_x_m),
        "est_std_y_m": None if est is None else _finite(est.std_y_m),
        "est_std_z_m": None if est is None else _finite(est.std_z_m),
        **_failsafes(s.failsafes),
    }


def _from_hover(s: HoverSummary) -> dict[str, Any]:
    return {
        "kind": "sim hover",
        "duration_s": _finite(s.sim_s),
        "end_reason": s.end,
        "released": s.released,
        "truth_std_x_m": _finite(s.std_x_m),
        "truth_std_y_m": _finite(s.std_y_m),
        "truth_std_z_m": _finite(s.std_z_m),
        **_failsafes(s.failsafes),
    }


def truth_precision(folder: Path) -> tuple[float, float, float] | None:
    """The HOLD std (x, y, height) against a simulator's ``truth.txt``; None if not measurable."""
    from mkflight.analysis.precision import folder_truth_precision

    p = folder_truth_precision(folder)
    if p is None:
        return None
    return (round(p.x.std_m, 6), round(p.y.std_m, 6), round(p.z.std_m, 6))


def _event_span_s(path: Path) -> float | None:
    """Seconds from the first to the last complete line of an events file (cheap: two reads)."""
    try:
        with path.open("rb") as fh:
            head = fh.readline()
            size = fh.seek(0, os.SEEK_END)
            fh.seek(max(0, size - _TAIL_BYTES))
            tail = fh.read()
    except OSError:
        return None
    complete = tail[: tail.rfind(b"\n") + 1]
    first = _T_NS_RE.search(head)
    last = None
    for m in _T_NS_RE.finditer(complete):
        last = m
    if first is None or last is None:
        return None
    return (int(last[1]) - int(first[1])) / 1e9


def flight_record(folder: Path, *, truth: bool = True) -> FlightRecord:
    """The record of one flight folder; never raises for what the folder holds.

    ``truth``: measure the precision against a ``truth.txt`` beside a daemon's flight
    (reads ``events.jsonl`` whole). A folder that cannot be read is "unreadable", with
    the error.
    """
    try:
        return _record(folder, truth=truth)
    except OSError as err:
        return FlightRecord(
            number=flight_number(folder.name),
            folder=folder.name,
            path=str(folder),
            status="unreadable",
            error=f"{folder}: {err.strerror or err}",
        )


def _record(folder: Path, *, truth: bool) -> FlightRecord:
    base: dict[str, Any] = {
        "number": flight_number(folder.name),
        "folder": folder.name,
        "path": str(folder),
    }
    info_path = folder / flight_json.FILE_NAME
    if not info_path.is_file():
        return FlightRecord(status="no flight.json", **base, duration_s=_span(folder))
    try:
        info = flight_json.read_flight_json(info_path)
    except MkflightError as err:
        return FlightRecord(status="unreadable", **base, error=str(err))
    known: dict[str, Any] = {
        "start_utc": info.start_utc,
        "mkflight_version": info.mkflight_version,
        "fc_version": info.fc_version,
    }
    summary = info.summary
    if isinstance(summary, FlightSummary):
        known |= _from_fly(summary)
        if truth and (folder / _TRUTH).is_file():
            std = truth_precision(folder)
            if std is not None:
                known |= dict(zip(_TRUTH_STD, std, strict=True))
        return FlightRecord(status="ended", **base, **known)
    if isinstance(summary, HoverSummary):
        return FlightRecord(status="ended", **base, **known, **_from_hover(summary))
    if summary is None:
        return FlightRecord(status="no summary", **base, **known, duration_s=_span(folder))
    return FlightRecord(status="unknown summary", **base, **known, error=summary.problem)


def _span(folder: Path) -> float | None:
    path = folder / _EVENTS
    return _event_span_s(path) if path.is_file() else None


def _sort_key(r: FlightRecord) -> tuple[bool, int, str, str]:
    """Numbered flights by number after the unnumbered (older names) by start."""
    return (r.number is not None, r.number or 0, r.start_utc or "", r.folder)


def flight_folders(log_dir: Path) -> Iterator[Path]:
    """The flight folders directly in ``log_dir`` (:func:`is_flight_folder`).

    Raises:
        OSError: ``log_dir`` cannot be listed.
    """
    for entry in sorted(log_dir.iterdir()):
        if is_flight_folder(entry):
            yield entry


def list_flights(log_dir: str | Path, *, truth: bool = True) -> list[FlightRecord]:
    """Every flight folder's record in ``log_dir``, sorted by flight number.

    Raises:
        OSError: ``log_dir`` cannot be listed.
    """
    records = [flight_record(p, truth=truth) for p in flight_folders(Path(log_dir))]
    return sorted(records, key=_sort_key)
