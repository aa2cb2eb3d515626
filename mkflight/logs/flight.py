"""One flight folder as numpy arrays with named columns, for your own analysis (SPEC §6).

:func:`load_flight` reads what a folder holds with the format readers of this package
(TABLE III/IV, ``events.jsonl``, ``flight.json``, ``mk.raw``, ``laser.raw``) plus the
simulator's ``truth.txt``, and decodes the MK port's bytes as the link does: every
ExternControl written and every DebugOut read, the latter in SI with the flight's own
calibration (``config.mk`` in ``flight.json``; :func:`mkflight.mk.units.imu_from_debug`);
and the URG's as the driver does: every scan (:mod:`mkflight.logs.scans`).

Time base: every ``t_s`` (and :attr:`FlightData.imu_t_s`, :attr:`FlightData.laser_t_s`)
is seconds since :attr:`FlightData.t0_ns` on the flight's clock (host monotonic on the
vehicle, the simulator's clock in ``sim hover``), which stamps the events, the raw
records and the truth rows alike, so all arrays plot on one axis. ``t0_ns`` is the
``start_t_ns`` of the ``mk.raw`` header (the recorders start as the folder is created,
before the links open), else of ``laser.raw``, else the first event's ``t_ns``, else None.
The table rows carry no time: a row's time is its event's (``step`` for TABLE IV,
``scan`` for TABLE III), NaN if it has none; a folder without ``events.jsonl`` (the system
system wrote only the two tables) gets the nominal ``index`` times the step period
(0.05 s, 0.1 s) instead.

A missing optional file gives an empty array of the same dtype (``truth``, ``info``:
None); a malformed one the readers' :class:`~mkflight.errors.ReplayError` naming the file
and the line or byte; a tail cut short by a killed process is dropped and reported in
:attr:`FlightData.warnings`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import msgspec
import msgspec.inspect as mi
import numpy as np
import numpy.typing as npt

from mkflight.config import MkConfig
from mkflight.conversions import NS_PER_S
from mkflight.errors import ProtocolError, ReplayError
from mkflight.logs import events as events_log
from mkflight.logs import flight_json, table3, table4
from mkflight.logs._file import read_lines
from mkflight.logs._table import TableData
from mkflight.logs.events import Event, read_events
from mkflight.logs.raw import RawRecording, read_raw
from mkflight.logs.scans import ScanLog, laser_config, scan_log
from mkflight.logs.schema import KINDS, KnownEvent, Scan, Step, UnknownSummary
from mkflight.mk.codec import ADDR_FC, Frame, FrameParser, encode_frame
from mkflight.mk.messages import CMD_DEBUG_ANSWER, CMD_EXTERN, DebugOut, ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION, MkCalibration, imu_from_debug

__all__ = [
    "COMMAND_DTYPE",
    "SAMPLE_DTYPE",
    "TRUTH_DTYPE",
    "FlightData",
    "check_port_contents",
    "event_table",
    "extern_control_frames",
    "extern_controls",
    "load_flight",
]

#: What each port's device sends, to tell a recording from the other port's: every
#: FlightCtrl frame starts with '#', which no SCIP 2.0 reply contains (its data characters
#: are 0x30-0x6F), and every SCIP reply ends with LF LF (mk-serial.md §2, scip2.md §2).
_SIGNATURE: Final = {"mk": b"#", "laser": b"\n\n"}
_SIGNATURE_TEXT: Final = {"mk": "FlightCtrl frames ('#')", "laser": "SCIP replies (LF LF)"}
_RAW_NAME: Final = {"mk": "mk.raw", "laser": "laser.raw"}

MK_RAW: Final = "mk.raw"
LASER_RAW: Final = "laser.raw"
TRUTH: Final = "truth.txt"  # as mkflight.flight.flight_logs.TRUTH_FILE
IMU_PERIOD_S: Final = 0.05  # TABLE IV: one row per 50 ms step (the documented rate)
LASER_PERIOD_S: Final = 0.1  # TABLE III: one row per 100 ms laser step
MIN_TEXT: Final = 16  # string columns are at least 'U16'

Array = npt.NDArray[Any]

_COMMAND_FIELDS: Final = ("nick", "roll", "yaw", "gas", "config")
#: ``commands``: every ExternControl written to the FC, in MK counts as on the wire.
COMMAND_DTYPE: Final = np.dtype([("t_s", np.float64)] + [(k, np.int64) for k in _COMMAND_FIELDS])
#: ``samples``: every DebugOut read from the FC, as the link converts it (SPEC §1).
SAMPLE_DTYPE: Final = np.dtype(
    [(k, np.float64) for k in ("t_s", "pitch_rad", "roll_rad", "yaw_rad", "acc_x_mps2")]
    + [(k, np.float64) for k in ("acc_y_mps2", "acc_z_mps2", "battery_v")]
    + [("gas_counts", np.int64)]
)
#: ``truth``: the simulator's vehicle position, world x and y and height up (m).
TRUTH_DTYPE: Final = np.dtype([(k, np.float64) for k in ("t_s", "x_m", "y_m", "height_m")])

_COLUMN_KIND: Final = {mi.IntType: "f", mi.FloatType: "f", mi.BoolType: "f", mi.StrType: "U"}


def _columns_of(cls: type[KnownEvent]) -> tuple[tuple[str, str], ...]:
    """A kind's scalar fields after ``t_ns``, in order: 'f' numbers and booleans, 'U' text.

    Lists and objects (``pilot_override``'s ``moved``) stay in the event records only.
    """
    info = mi.type_info(cls)
    assert isinstance(info, mi.StructType)
    out: list[tuple[str, str]] = []
    for f in info.fields[1:]:
        t = f.type.type if isinstance(f.type, mi.Metadata) else f.type
        members = t.types if isinstance(t, mi.UnionType) else (t,)
        kinds = {_COLUMN_KIND.get(type(m)) for m in members if not isinstance(m, mi.NoneType)}
        if len(kinds) == 1 and None not in kinds:
            out.append((f.encode_name, kinds.pop() or ""))
    return tuple(out)


#: Each kind's columns: always there, in the Struct's order, whatever the events hold.
_SCHEMAS: Final = {name: _columns_of(cls) for name, cls in KINDS.items()}
_CAL_KEYS: Final = (  # config.mk keys that MkCalibration.from_config uses
    *("angle_unit_deg", "acc_nick_counts_per_g", "acc_roll_counts_per_g"),
    *("acc_z_counts_per_mps2", "acc_z_offset_mps2", "voltage_unit_v", "g_mps2"),
)


@dataclass(frozen=True, slots=True, eq=False)
class FlightData:
    """One flight folder's logs (module docstring: the time base, missing files).

    Attributes:
        path: the folder.
        t0_ns: the flight clock's ``t_ns`` at ``t_s`` = 0; None for a tables-only folder.
        imu: TABLE IV rows, fields named as its header (``"AccX"``, ``"index"``...).
        imu_t_s: each ``imu`` row's time: its ``step`` event's (the k-th step event is
            the row of index k), NaN if none; nominal ``index * 0.05`` without events.
        laser: TABLE III rows, fields named as its header (``"W_Vel.x"``...).
        laser_t_s: each ``laser`` row's scan time (the ``scan`` event with its index),
            NaN if none; nominal ``index * 0.1`` without events.
        steps: the :class:`~mkflight.logs.schema.Step` events: ``t_s``, the numeric
            fields (NaN: null), ``phase`` and ``action`` as strings.
        scans: the :class:`~mkflight.logs.schema.Scan` events: ``t_s`` and the
            numeric fields.
        commands: every ExternControl written to the FC (:data:`COMMAND_DTYPE`).
        samples: every DebugOut read from the FC in SI (:data:`SAMPLE_DTYPE`).
        truth: the simulator's ``truth.txt`` (:data:`TRUTH_DTYPE`), None if absent.
        laser_scans: every scan of ``laser.raw``, decoded as the driver decoded it, with
            the pose and height of its ``scan`` event (:class:`~mkflight.logs.scans.ScanLog`,
            times on ``t0_ns``); None if the folder has no ``laser.raw``.
        info: ``flight.json`` (``log_format``, ``config``, the typed ``summary``).
        events: every event, as :func:`mkflight.logs.events.read_events` gives them
            (typed; an unknown kind or a line that does not fit its kind is an
            :class:`~mkflight.logs.schema.UnknownEvent`, counted in ``warnings``).
        warnings: what was dropped, assumed or kept unknown (a cut-short tail, with
            file and offset; unknown events and summaries).
    """

    path: Path
    t0_ns: int | None
    imu: Array
    imu_t_s: npt.NDArray[np.float64]
    laser: Array
    laser_t_s: npt.NDArray[np.float64]
    steps: Array
    scans: Array
    commands: Array
    samples: Array
    truth: Array | None
    laser_scans: ScanLog | None
    info: flight_json.FlightInfo | None
    events: list[Event]
    warnings: tuple[str, ...]

    def event_table(self, kind: str | type[KnownEvent]) -> Array:
        """The events of one kind as a structured array (see :func:`event_table`)."""
        return event_table(self.events, kind, self.t0_ns or 0, self.path / events_log.FILE_NAME)


def load_flight(folder: str | Path) -> FlightData:
    """Read one flight folder into arrays with named columns (module docstring).

    Raises:
        ReplayError: not a folder, a folder with neither table nor ``flight.json``, a
            ``flight.json`` of a newer log format, or a malformed file; the message names
            the file and the line or byte offset.
    """
    path = Path(folder)
    if not path.is_dir():
        msg = f"{path}: not a flight folder (no such directory)"
        raise ReplayError(msg)
    names = (table4.FILE_NAME, table3.FILE_NAME, flight_json.FILE_NAME)
    if not any((path / n).is_file() for n in names):
        msg = f"{path}: not a flight folder (none of {', '.join(names)})"
        raise ReplayError(msg)
    warnings: list[str] = []
    info = None
    if (path / flight_json.FILE_NAME).is_file():  # first: a newer format is refused first
        info = flight_json.read_flight_json(path / flight_json.FILE_NAME)
        if info.summary is None:
            warnings.append(f"{path / flight_json.FILE_NAME}: no summary (flight not ended)")
        elif isinstance(info.summary, UnknownSummary):
            warnings.append(
                f"{path / flight_json.FILE_NAME}: summary kept as read ({info.summary.problem})"
            )
    imu = _table(path / table4.FILE_NAME, table4.read_table4, table4.FORMAT.dtype, warnings)
    laser = _table(path / table3.FILE_NAME, table3.read_table3, table3.FORMAT.dtype, warnings)
    events, events_found = _events(path / events_log.FILE_NAME, warnings)
    mk = _raw(path / MK_RAW, warnings)
    laser_raw = _raw(path / LASER_RAW, warnings)
    if mk is not None and laser_raw is not None:
        check_port_contents({"mk": mk, "laser": laser_raw}, strict=False)
    t0_ns: int | None = None
    for rec in (mk, laser_raw):
        if t0_ns is None and rec is not None:
            t0_ns = rec.header.start_t_ns
    if t0_ns is None and events:
        t0_ns = events[0].t_ns
    t0 = t0_ns or 0
    events_path = path / events_log.FILE_NAME
    steps = event_table(events, Step, t0, events_path)
    scans = event_table(events, Scan, t0, events_path)
    if events_found:
        imu_t_s = _by_index(imu["index"], dict(enumerate(steps["t_s"].tolist(), start=1)))
        laser_t_s = _by_index(laser["index"], _scan_times(scans))
    else:
        imu_t_s = imu["index"] * IMU_PERIOD_S
        laser_t_s = laser["index"] * LASER_PERIOD_S
    commands = np.zeros(0, COMMAND_DTYPE)
    samples = np.zeros(0, SAMPLE_DTYPE)
    if mk is not None:
        commands = _commands(mk, t0, warnings)
        cal = _calibration(info, path / flight_json.FILE_NAME)
        samples = _samples(mk, t0, cal, warnings)
        if info is None and len(samples):
            warnings.append(f"{path}: no flight.json: DebugOut converted with the defaults")
    truth = _read_truth(path / TRUTH, t0_ns, warnings) if (path / TRUTH).is_file() else None
    laser_scans = _laser_scans(laser_raw, events, info, path, t0, warnings)
    return FlightData(
        path=path,
        t0_ns=t0_ns,
        imu=imu,
        imu_t_s=np.asarray(imu_t_s, dtype=np.float64),
        laser=laser,
        laser_t_s=np.asarray(laser_t_s, dtype=np.float64),
        steps=steps,
        scans=scans,
        commands=commands,
        samples=samples,
        truth=truth,
        laser_scans=laser_scans,
        info=info,
        events=events,
        warnings=tuple(warnings),
    )


def _line_count(path: Path) -> int:
    """The number of the file's last line (the one a killed writer cut short)."""
    with path.open("rb") as f:
        return sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 16), b"")) + 1


def _table(
    path: Path, read: Callable[[Path], TableData], dtype: np.dtype[Any], warnings: list[str]
) -> Array:
    if not path.is_file():
        return np.zeros(0, dtype)
    data = read(path)
    if data.truncated:
        warnings.append(f"{path}:{_line_count(path)}: incomplete last row dropped")
    rows: Array = data.rows
    return rows


def _events(path: Path, warnings: list[str]) -> tuple[list[Event], bool]:
    if not path.is_file():
        return [], False
    data = read_events(path)
    if data.truncated:
        warnings.append(f"{path}:{_line_count(path)}: incomplete last event dropped")
    warnings.extend(data.warnings)
    return data.events, True


def check_port_contents(recordings: Mapping[str, RawRecording], *, strict: bool) -> None:
    """Each recording ("mk", "laser") holds its own device's bytes, not the other's.

    Raises:
        ReplayError: the two look swapped (each holds the other device's bytes), or, if
            ``strict``, one holds nothing of its device's; naming the file.
    """
    seen = {
        port: {dev: sig in rec.payload("r")[:65536] for dev, sig in _SIGNATURE.items()}
        for port, rec in recordings.items()
    }
    for port, rec in recordings.items():
        if seen[port][port]:
            continue
        other = "laser" if port == "mk" else "mk"
        if seen[port][other] and other in seen and not seen[other][other]:
            msg = (
                f"{rec.path}: holds {_SIGNATURE_TEXT[other]}, the other port's bytes: "
                f"{_RAW_NAME[port]} and {_RAW_NAME[other]} look swapped"
            )
            raise ReplayError(msg)
        if strict:
            msg = f"{rec.path}: no {_SIGNATURE_TEXT[port]} among the bytes read"
            raise ReplayError(msg)


def _raw(path: Path, warnings: list[str]) -> RawRecording | None:
    if not path.is_file():
        return None
    rec = read_raw(path)
    if rec.warning is not None:
        warnings.append(rec.warning)
    return rec


def _laser_scans(
    rec: RawRecording | None,
    events: list[Event],
    info: flight_json.FlightInfo | None,
    path: Path,
    t0_ns: int,
    warnings: list[str],
) -> ScanLog | None:
    """The scans of ``laser.raw`` with their events' poses, stamped with the laser config flown."""
    if rec is None:
        return None
    laser = None
    if info is not None:
        laser, problem = laser_config(info.config, path / flight_json.FILE_NAME)
        warnings.extend([problem] if problem else [])
    scans = scan_log(rec, events, laser, t0_ns)
    warnings.extend(scans.warnings)
    return scans


def _by_index(index: Array, times: dict[int, float]) -> npt.NDArray[np.float64]:
    return np.array([times.get(int(i), math.nan) for i in index], dtype=np.float64)


def _scan_times(scans: Array) -> dict[int, float]:
    return {
        int(i): float(t)
        for i, t in zip(scans["index"].tolist(), scans["t_s"].tolist(), strict=True)
        if math.isfinite(i)
    }


def _kind(value: Any) -> str | None:
    """A JSON value's column kind: 'f' number or boolean, 'U' string, '' null, None other."""
    if value is None:
        return ""
    if isinstance(value, bool | float) or (isinstance(value, int) and abs(value) < 2**1023):
        return "f"
    if isinstance(value, str):
        return "U"
    return None


def event_table(
    events: Sequence[Event], kind: str | type[KnownEvent], t0_ns: int, path: Path | str
) -> Array:
    """The events of one kind as a structured array: ``t_s`` and one field per key.

    ``kind``: a Struct of :mod:`mkflight.logs.schema` (``Step``) or a kind's name
    (``"step"``, or one this version does not know). ``t_s`` is ``(t_ns - t0_ns)`` in
    seconds. A known kind's scalar fields are always columns, in its Struct's order
    (absent: null); an unknown kind's keys whose values are all numbers (booleans too) or
    all strings are. Numbers are float64 (null: NaN, booleans 1.0/0.0), strings at least
    'U16' (null: ""); lists, objects and keys of mixed types stay in the event records
    only. Lines of a known kind that did not fit its Struct are rows too, read by name.

    Raises:
        ReplayError: a known kind's field of the wrong type (names ``path``, the event's
            ``t_ns`` and the field).
    """
    name = kind if isinstance(kind, str) else str(kind.__struct_config__.tag)
    chosen = [e for e in events if e.event == name]
    schema = dict(_SCHEMAS.get(name, ()))
    found: dict[str, set[str]] = {}
    for e in chosen:
        for key, value in e.fields.items():
            kind_found = _kind(value)
            if key in schema and kind_found not in ("", schema[key]):
                want = "number" if schema[key] == "f" else "string"
                msg = f"{path}: {name} event at t_ns {e.t_ns}: {key} = {value!r} is not a {want}"
                raise ReplayError(msg)
            if name not in KINDS and key not in ("", "t_s"):
                found.setdefault(key, set()).add("?" if kind_found is None else kind_found)
    columns = dict(schema)
    for key, kinds in found.items():
        kinds.discard("")
        if len(kinds) <= 1 and "?" not in kinds:
            columns[key] = kinds.pop() if kinds else "f"
    return _table_of(chosen, columns, t0_ns, path)


def _table_of(chosen: list[Event], columns: dict[str, str], t0_ns: int, path: Path | str) -> Array:
    """The structured array of ``chosen`` with ``columns`` ('f' float64, 'U' text)."""
    values = [e.fields for e in chosen]
    dtype: list[tuple[str, Any]] = [("t_s", np.float64)]
    for key, kind in columns.items():
        if kind == "f":
            dtype.append((key, np.float64))
        else:
            texts = [v for f in values if isinstance(v := f.get(key), str)]
            width = max([MIN_TEXT, *map(len, texts)])
            dtype.append((key, f"U{width}"))
    out = np.zeros(len(chosen), dtype)
    out["t_s"] = [_since(e.t_ns, t0_ns, path) for e in chosen]
    for key, kind in columns.items():
        column = [f.get(key) for f in values]
        if kind == "f":
            out[key] = [math.nan if v is None else float(v) for v in column]
        else:
            out[key] = ["" if v is None else v for v in column]
    return out


def _since(t_ns: int, t0_ns: int, path: Path | str) -> float:
    """Seconds from ``t0_ns`` to ``t_ns``, or ReplayError for a time beyond any clock."""
    try:
        return (t_ns - t0_ns) / NS_PER_S
    except OverflowError as err:
        msg = f"{path}: time {t_ns} ns is out of range"
        raise ReplayError(msg) from err


def _frames(recording: RawRecording, kind: str) -> Iterator[tuple[int, Frame]]:
    """The good frames of one direction, each with the ``t_ns`` of the record ending it.

    A port (re)opened or lost drops a frame left incomplete, as the link's parser does.
    """
    parser = FrameParser()
    for rec in recording.records:
        if rec.kind == kind:
            for frame in parser.feed(rec.data):
                yield rec.t_ns, frame
        elif rec.kind in "oc":
            parser.reset()


def extern_control_frames(recording: RawRecording) -> list[tuple[int, bytes]]:
    r"""Every ExternControl written to the FC in an ``mk.raw``: ``(t_ns, frame bytes)``.

    The frames are the ``'#' 'b' 'b' ... '\r'`` ones (address FC, command 'b') of the
    write ('w') records, in order; a frame split over several records carries the
    ``t_ns`` of the one that completes it. The bytes are the frame as on the wire: the
    parser keeps only the decoded payload, and re-encoding it is exact (4 payload
    characters are 3 bytes and back, the checksum is summed over the characters).
    """
    return [
        (t_ns, encode_frame(f.addr, f.cmd, f.payload))
        for t_ns, f in _frames(recording, "w")
        if f.addr == ADDR_FC and f.cmd == CMD_EXTERN
    ]


def extern_controls(recording: RawRecording) -> list[tuple[int, ExternControl]]:
    """Every ExternControl written to the FC in an ``mk.raw``, decoded: ``(t_ns, command)``.

    The frames of :func:`extern_control_frames`; one too short to decode is left out.
    """
    return _extern_controls(recording)[0]


def _extern_controls(recording: RawRecording) -> tuple[list[tuple[int, ExternControl]], int]:
    """The decoded commands, and how many 'b' frames were too short to decode."""
    out: list[tuple[int, ExternControl]] = []
    bad = 0
    for t_ns, f in _frames(recording, "w"):
        if f.addr == ADDR_FC and f.cmd == CMD_EXTERN:
            try:
                out.append((t_ns, ExternControl.decode(f)))
            except ProtocolError:
                bad += 1
    return out, bad


def _commands(mk: RawRecording, t0_ns: int, warnings: list[str]) -> Array:
    decoded, bad = _extern_controls(mk)
    if bad:
        warnings.append(f"{mk.path}: {bad} ExternControl frames too short to decode")
    out = np.zeros(len(decoded), COMMAND_DTYPE)
    out["t_s"] = [(t - t0_ns) / NS_PER_S for t, _ in decoded]
    for key in _COMMAND_FIELDS:
        out[key] = [int(getattr(c, key)) for _, c in decoded]
    return out


def _calibration(info: flight_json.FlightInfo | None, path: Path) -> MkCalibration:
    """The flight's own MK calibration (``config.mk``), defaults for keys it lacks."""
    if info is None:
        return DEFAULT_CALIBRATION
    mk = info.config.get("mk", {})
    if not isinstance(mk, dict):
        msg = f"{path}: config.mk: expected an object, got {type(mk).__name__}"
        raise ReplayError(msg)
    try:
        cfg = msgspec.convert({k: mk[k] for k in _CAL_KEYS if k in mk}, type=MkConfig)
    except msgspec.ValidationError as err:
        msg = f"{path}: config.mk: {err}"
        raise ReplayError(msg) from err
    return MkCalibration.from_config(cfg)


def _samples(mk: RawRecording, t0_ns: int, cal: MkCalibration, warnings: list[str]) -> Array:
    rows: list[tuple[float | int, ...]] = []
    bad = 0
    for t_ns, f in _frames(mk, "r"):
        if f.addr != ADDR_FC or f.cmd != CMD_DEBUG_ANSWER:
            continue
        try:
            s = imu_from_debug(DebugOut.decode(f), t_ns, cal)
        except ProtocolError:
            bad += 1
            continue
        rows.append(
            (
                (t_ns - t0_ns) / NS_PER_S,
                s.pitch_rad,
                s.roll_rad,
                s.yaw_rad,
                s.acc_x_mps2,
                s.acc_y_mps2,
                s.acc_z_mps2,
                s.battery_v,
                s.gas_counts,
            )
        )
    if bad:
        warnings.append(f"{mk.path}: {bad} DebugOut frames too short to decode")
    return np.array(rows, dtype=SAMPLE_DTYPE)


def _read_truth(path: Path, t0_ns: int | None, warnings: list[str]) -> Array:
    """``truth.txt`` (mkflight.sim.world): ``t x y z`` rows, ``t`` s since ``# t0_ns N``."""
    lines, cut = read_lines(path)
    if cut:
        warnings.append(f"{path}:{len(lines) + 1}: incomplete last row dropped")
    origin_ns = 0  # no comment: 't' is the clock's own seconds (sim hover)
    rows: list[tuple[float, ...]] = []
    for line_no, line in enumerate(lines, start=1):
        words = line.split()
        if not words or (line_no == 1 and words == ["t", "x", "y", "z"]):
            continue
        if words[0] == "#":
            if len(words) > 2 and words[1] == "t0_ns":
                origin_ns = _parse_int(words[2], path, line_no)
            continue
        try:
            values = tuple(float(w) for w in words)
        except ValueError:
            values = ()
        if len(values) != 4:
            msg = f"{path}:{line_no}: expected 't x y z' numbers, got {line[:80]!r}"
            raise ReplayError(msg)
        rows.append(values)
    out = np.array(rows, dtype=np.float64).reshape(-1, 4)
    shift_s = _since(origin_ns, t0_ns or 0, path)
    truth = np.zeros(len(out), TRUTH_DTYPE)
    truth["t_s"] = out[:, 0] + shift_s
    for i, key in enumerate(("x_m", "y_m", "height_m"), start=1):
        truth[key] = out[:, i]
    return truth


def _parse_int(text: str, path: Path, line_no: int) -> int:
    try:
        return int(text)
    except ValueError as err:
        msg = f"{path}:{line_no}: t0_ns {text!r} is not an integer"
        raise ReplayError(msg) from err
