"""What a recorded flight gives a replay: the input timeline and the recorded decisions.

Pure reading, no I/O beyond the files (SPEC §6). From a flight folder:

* ``mk.raw`` and ``laser.raw`` -> one time-ordered list of :class:`Input`: every chunk
  the daemon *read* ('r', played back to it), every port loss ('c', the pty vanishes)
  and re-open ('o', a fresh pty appears). What the daemon *wrote* is not input; the
  ExternControl frames among it are what the replay must reproduce.
* ``events.jsonl`` -> what the original daemon's environment decided and the recording
  must therefore name: the operator's stop requests (SIGINT, SIGTERM, ``--duration``: in
  flight at the step that first saw it, before READY an ``'s'`` input at its time); per
  scan, the scan matcher's result and the step it entered (:class:`RecordedScan`; the
  matcher ran in its own process, so where a pose landed depended on that process's
  timing); and the time of READY (``ready``: the pre-flight took as long as spawning the
  matcher took, and the first step is the first DebugOut after it).
* ``flight.json`` -> the configuration flown.

Bad input is a :class:`~mkflight.errors.ReplayError` naming the file and the byte offset
or line (as is a time the lock-step loop cannot run at,
:data:`~mkflight.replay.vloop.MAX_T_NS`: the replay would wait for it forever); a tail
cut short by a killed process is dropped with a warning, as are the events of a kind or
shape this version does not know (:class:`~mkflight.logs.schema.UnknownEvent`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mkflight.conversions import NS_PER_S, NS_PER_US
from mkflight.errors import ReplayError
from mkflight.logs.events import read_events
from mkflight.logs.flight import check_port_contents
from mkflight.logs.flight_json import read_flight_json
from mkflight.logs.raw import RawRecording, read_raw
from mkflight.logs.schema import UNSET, Preflight, Ready, Scan, Step, Stop
from mkflight.msgs import Pose2D
from mkflight.replay.vloop import MAX_T_NS
from mkflight.safety.failsafe import StopRequest

PORTS = ("mk", "laser")
RAW_FILES = {"mk": "mk.raw", "laser": "laser.raw"}
#: A recording whose last record comes this long before the other's (and is not a port
#: loss, 'c') was cut short: a flight ends both within a few tens of ms.
EARLY_END_NS = NS_PER_S

#: Stop requests that came from outside the daemon: the replay repeats them.
EXTERNAL_STOPS = frozenset({StopRequest.SIGINT, StopRequest.SIGTERM, StopRequest.DURATION})


@dataclass(frozen=True, slots=True)
class Input:
    """One thing that happened to the daemon from outside, at ``t_ns``.

    ``kind``: 'r' bytes arrive on ``port``; 'c' the port is lost; 'o' it is (re)opened;
    's' the operator asks for a stop (``stop``, ``reason``).
    """

    t_ns: int
    port: str
    kind: str
    data: bytes = b""
    stop: StopRequest | None = None
    reason: str = ""


@dataclass(frozen=True, slots=True)
class RecordedScan:
    """A scan matcher result as the original flight applied it (a ``scan`` event)."""

    t_ns: int
    seq: int
    step: int | None
    pose: Pose2D | None
    height_m: float | None
    degenerate: bool
    got_ns: int | None = None  # when the matcher's result came back in flight
    due_ns: int | None = None  # the DebugOut time of the step that applied it

    @property
    def back_ns(self) -> int | None:
        """When the replay hands the result over: as in flight, and before its step.

        In flight the result can come back after its step's DebugOut was read but before
        that step ran (both waiting in one loop turn); a replay runs the step as soon as
        the DebugOut is in, so the result must be back before it (1 µs: a timer lands on
        the whole nanosecond after its float time).
        """
        if self.got_ns is None:
            return None
        if self.due_ns is None:
            return self.got_ns
        return min(self.got_ns, self.due_ns - NS_PER_US)


@dataclass(slots=True)
class RecordedFlight:
    """A flight folder read for replay (see the module docstring)."""

    folder: Path
    config: dict[str, Any]
    mkflight_version: str
    inputs: list[Input]
    start_ns: int
    end_ns: int
    recordings: dict[str, RawRecording]
    scans: dict[int, RecordedScan]
    ready_ns: int | None = None
    #: when the MK task's first 'd' (DebugOut subscription) went out after READY
    subscribe_ns: int | None = None
    #: the flight ended by itself (flight.json has its summary); else it was killed
    completed: bool = True
    #: operator stops seen in flight: (steps run when it came, request, reason)
    step_stops: list[tuple[int, StopRequest, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    #: a raw file ends early (cut short): the replay is checked up to this time only
    intact_end_ns: int | None = None

    @property
    def has_poses(self) -> bool:
        """The events name each scan's pose (a scan event without its pose fields names none)."""
        return bool(self.scans)

    @property
    def duration_s(self) -> float:
        """Recorded time from the first to the last record, s."""
        return (self.end_ns - self.start_ns) / NS_PER_S


def _check_time(t_ns: int, where: str) -> None:
    """A recorded time the lock-step clock can run at, else ReplayError naming ``where``."""
    if not 0 <= t_ns <= MAX_T_NS:
        msg = (
            f"{where}: time {t_ns} ns is outside the times a replay runs on "
            f"(0 to {MAX_T_NS} ns): the file is damaged"
        )
        raise ReplayError(msg)


def _check_recording(rec: RawRecording) -> None:
    _check_time(rec.header.start_t_ns, f"{rec.path}: header")
    for n, r in enumerate(rec.records, start=1):
        if not 0 <= r.t_ns <= MAX_T_NS:
            _check_time(r.t_ns, f"{rec.path}: record {n}")


def _read_info(folder: Path) -> tuple[dict[str, Any], str, bool]:
    path = folder / "flight.json"
    if not path.exists():
        msg = f"{path}: missing (the configuration flown is needed to replay)"
        raise ReplayError(msg)
    info = read_flight_json(path)  # names the file; refuses a newer log format
    return info.config, info.mkflight_version, info.summary is not None


def _pose(ev: Scan) -> Pose2D | None:
    x, y, yaw = ev.x_m, ev.y_m, ev.yaw_rad
    if isinstance(x, float) and isinstance(y, float) and isinstance(yaw, float):
        return Pose2D(ev.t_ns, x, y, yaw)
    return None


def _recorded_scan(ev: Scan, where: str) -> RecordedScan:
    """A ``scan`` event with its pose fields as the flight applied it."""
    if ev.got_ns is not None:
        _check_time(ev.got_ns, f"{where} got_ns")
    return RecordedScan(
        t_ns=ev.t_ns,
        seq=ev.seq,
        step=ev.step,
        pose=_pose(ev),
        height_m=ev.height_m,
        degenerate=ev.degenerate,
        got_ns=ev.got_ns,
    )


@dataclass(slots=True)
class _EventInputs:
    scans: dict[int, RecordedScan] = field(default_factory=dict)
    stops: list[Input] = field(default_factory=list)  # before READY: by time
    step_stops: list[tuple[int, StopRequest, str]] = field(default_factory=list)
    ready_ns: int | None = None
    #: the events file was cut short: the time up to which its records are whole (its
    #: last event's time less EARLY_END_NS: a scan's result is logged when applied)
    cut_ns: int | None = None


def _events(folder: Path, warnings: list[str]) -> _EventInputs:
    path = folder / "events.jsonl"
    out = _EventInputs()
    if not path.exists():
        warnings.append(f"{path}: missing: scans are matched again, no stop is repeated")
        return out
    data = read_events(path)
    if data.truncated:
        # a scan's result is logged when it is applied, up to a few 100 ms after the scan:
        # a scan shortly before the cut may have lost its recorded result with the cut
        out.cut_ns = data.events[-1].t_ns - EARLY_END_NS if data.events else 0
        warnings.append(
            f"{path}: last line cut short: dropped; the events end after line "
            f"{len(data.events)}: the replay is checked only up to there"
        )
    warnings.extend(w + ": the replay passes them over" for w in data.warnings)
    scans = out.scans
    step_ns: list[int] = []  # the k-th step event is step k
    for n, ev in enumerate(data.events, start=1):
        where = f"{path}: event {n} ({ev.event!r})"
        _check_time(ev.t_ns, where)
        match ev:
            case Step():
                step_ns.append(ev.t_ns)
            case Ready():
                out.ready_ns = ev.t_ns
            case Preflight() if out.ready_ns is None:
                out.ready_ns = ev.t_ns  # no 'ready' event: READY came as the pre-flight ended
            case Scan() if ev.x_m is not UNSET:  # the pose recorded (else matched again)
                scans[ev.seq] = _recorded_scan(ev, where)
            case Stop():
                _stop(ev, out)
    for seq, sc in scans.items():
        if sc.step is not None and 1 <= sc.step <= len(step_ns):
            scans[seq] = dataclasses.replace(sc, due_ns=step_ns[sc.step - 1])
    return out


def _stop(ev: Stop, out: _EventInputs) -> None:
    """An operator's stop: at the step that saw it in flight, else at its time."""
    try:
        request = StopRequest(ev.request)
    except ValueError:
        return
    if request not in EXTERNAL_STOPS:
        return
    if ev.steps is not None:
        out.step_stops.append((ev.steps, request, ev.reason))
    else:  # before READY, or no 'steps' in the event
        out.stops.append(Input(ev.t_ns, "", "s", stop=request, reason=ev.reason))


def _intact_end(recordings: dict[str, RawRecording], warnings: list[str]) -> int | None:
    """The time up to which both recordings hold the flight, if one ends early, else None.

    A recording cut short (a power cut between two writes, a torn copy) stops while the
    other goes on; a port lost in flight ends with its 'c' record instead and is played.
    """
    ends = {p: r.records[-1] for p, r in recordings.items() if r.records}
    if len(ends) < len(PORTS):
        return None
    last_ns = max(r.t_ns for r in ends.values())
    start_ns = min(r.header.start_t_ns for r in recordings.values())
    early: int | None = None
    for port, rec in recordings.items():
        end = ends[port]
        if last_ns - end.t_ns <= EARLY_END_NS or end.kind == "c":
            continue
        where = f"byte {rec.truncated_at}" if rec.truncated_at is not None else "its last record"
        warnings.append(
            f"{rec.path}: ends early, at {(end.t_ns - start_ns) / NS_PER_S:.2f} s of "
            f"{(last_ns - start_ns) / NS_PER_S:.2f} s ({where}): the replay plays what "
            "follows without it and checks commands and tables only up to there"
        )
        early = end.t_ns if early is None else min(early, end.t_ns)
    return early


def _first_subscribe(mk: RawRecording, ready_ns: int | None) -> int | None:
    """The first 'd' request written at or after READY (within 1 s), if recorded."""
    if ready_ns is None:
        return None
    for r in mk.records:
        if r.kind == "w" and ready_ns <= r.t_ns <= ready_ns + NS_PER_S:
            if r.data[2:3] == b"d":
                return r.t_ns
        elif r.t_ns > ready_ns + NS_PER_S:
            break
    return None


def _port_inputs(port: str, rec: RawRecording) -> list[Input]:
    out: list[Input] = []
    for r in rec.records:
        if r.kind == "r":
            out.append(Input(r.t_ns, port, "r", r.data))
        elif r.kind in "oc":
            out.append(Input(r.t_ns, port, r.kind, r.data))
    return out


def read_recorded_flight(folder: str | Path) -> RecordedFlight:
    """Read a flight folder for :func:`mkflight.replay.run.replay_flight`.

    Raises:
        ReplayError: not a folder, a file missing or unreadable, another format version;
            the message names the file (and byte offset or line).
    """
    folder = Path(folder)
    if not folder.is_dir():
        what = "not a directory" if folder.exists() else "no such directory"
        msg = f"{folder}: not a flight folder ({what})"
        raise ReplayError(msg)
    config, version, completed = _read_info(folder)
    warnings: list[str] = []
    recordings: dict[str, RawRecording] = {}
    for port in PORTS:
        path = folder / RAW_FILES[port]
        if not path.exists():
            msg = f"{path}: missing (a flight recorded by mkflight has mk.raw and laser.raw)"
            raise ReplayError(msg)
        rec = read_raw(path)
        _check_recording(rec)
        if not any(r.kind == "r" for r in rec.records):
            msg = f"{path}: no bytes read from the port are recorded ({rec.size_bytes} bytes)"
            raise ReplayError(msg)
        if rec.warning is not None:
            warnings.append(rec.warning + ": replaying what is readable")
        recordings[port] = rec
    check_port_contents(recordings, strict=True)
    intact_end_ns = _intact_end(recordings, warnings)
    ev = _events(folder, warnings)
    if ev.cut_ns is not None:
        intact_end_ns = ev.cut_ns if intact_end_ns is None else min(ev.cut_ns, intact_end_ns)
    merged = [i for port in PORTS for i in _port_inputs(port, recordings[port])] + ev.stops
    merged.sort(key=lambda i: i.t_ns)  # stable: one port's records keep their order
    starts = [r.header.start_t_ns for r in recordings.values()]
    ends = [r.records[-1].t_ns for r in recordings.values() if r.records]
    start_ns = min(starts)
    return RecordedFlight(
        folder=folder,
        config=config,
        mkflight_version=version,
        inputs=merged,
        start_ns=start_ns,
        end_ns=max(ends, default=start_ns),
        recordings=recordings,
        scans=ev.scans,
        ready_ns=ev.ready_ns,
        subscribe_ns=_first_subscribe(recordings["mk"], ev.ready_ns),
        completed=completed,
        step_stops=ev.step_stops,
        warnings=warnings,
        intact_end_ns=intact_end_ns,
    )
