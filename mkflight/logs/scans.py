"""The scans of a flight: every scan the URG driver took, decoded from ``laser.raw``.

``laser.raw`` holds the bytes read from the URG (:mod:`mkflight.logs.raw`); this module
feeds them, chunk by chunk as they were read, through the driver's own pieces: the SCIP
reply parser (:class:`~mkflight.urg.replies.ReplyParser`), the PP parameters
(:func:`~mkflight.urg.units.parse_params`) and the stamper
(:class:`~mkflight.urg.stamping.ScanStamper`: mm to m, error codes to NaN, the front
step's host time), so a scan here is the scan the daemon got, value for value.

Which replies are scans: those the driver numbers, in the same order, so ``seq`` here is
the ``seq`` of the flight's ``scan`` events (:class:`mkflight.logs.schema.Scan`): an
MD/MS stream message (status 99) answering the last MD written ('w' records), with the
driver's parser resets repeated (a port (re)opened or lost, and the drain after a QT,
which ends just before the next command is written) and its timer reset (an RS
answered). Scans of an older stream (a sensor still streaming from a previous run) are
not the flight's: the driver counts them as stale and so are they left out here.

Each scan's pose and height come from the ``scan`` event of the same ``seq``
(``events.jsonl`` of the folder), NaN where there is none: scans before the first match
(the pre-flight's), scans the matcher never got (the driver keeps only the newest), a
matcher that found no pose.

Damage: a ``laser.raw`` cut short by a kill is read up to its last whole record, a
reply with a bad checksum or a malformed body is dropped (the parser's counters), each
said in :attr:`ScanLog.warnings`; a broken record structure is the reader's
:class:`~mkflight.errors.ReplayError` (:func:`~mkflight.logs.raw.read_raw`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import msgspec
import numpy as np
import numpy.typing as npt

from mkflight.config import LaserConfig
from mkflight.conversions import NS_PER_S
from mkflight.errors import ProtocolError, ReplayError
from mkflight.logs import events as events_log
from mkflight.logs import flight_json
from mkflight.logs.events import Event, read_events
from mkflight.logs.raw import RawRecording, read_raw
from mkflight.logs.schema import Scan
from mkflight.urg.replies import InfoReply, ReplyParser, ScanReply
from mkflight.urg.stamping import ScanStamper
from mkflight.urg.units import (
    URG_04LX,
    SensorParams,
    parse_params,
    step_body_angle_rad,
    value_steps,
)

__all__ = [
    "LASER_RAW",
    "DecodedScan",
    "DecodedScans",
    "ScanLog",
    "decode_scans",
    "laser_config",
    "read_scans",
    "scan_log",
]

LASER_RAW: Final = "laser.raw"
_STREAM_COMMANDS: Final = (b"MD", b"MS")
_F64 = npt.NDArray[np.float64]
_I64 = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, eq=False)
class ScanLog:
    """Every scan a flight's ``laser.raw`` holds, decoded, on the flight's time base.

    Beams are in order of increasing body angle (as ``laser scan --json``, SPEC §7):
    beam i points at ``angle_min_rad + i * angle_increment_rad`` in the body frame,
    positive to the right like psi, and stands for step ``beam_steps[i]`` (all the steps
    the driver streamed: the scan steps and the hat's; :meth:`only_steps` keeps some).

    Attributes:
        t_ns: (n,) host time of the read that completed each scan reply (flight clock).
        t_s: (n,) ``(t_ns - t0_ns) / 1e9``, the time base of
            :func:`~mkflight.logs.flight.load_flight`.
        stamp_t_ns: (n,) the driver's stamp: the host time the front step was measured
            (:mod:`mkflight.urg.stamping`); the ``scan`` event's ``t_ns``.
        sensor_ms: (n,) the URG's own 24-bit timestamp field of each reply.
        seq: (n,) the driver's sequence number (1, 2, ...; the ``scan`` event's ``seq``).
        angle_min_rad: body-frame angle of beam 0 (the most negative: to the left).
        angle_increment_rad: angle between neighbouring beams (> 0; cluster x 2 pi / ARES).
        beam_steps: (beams,) the URG step of each beam (a cluster's centre).
        ranges_m: (n, beams) metres; NaN where the URG reported an error code or a range
            beyond DMIN..DMAX.
        pose_x_m: (n,) the scan matcher's pose for the scan in W (its ``scan`` event),
        pose_y_m: NaN where none (module docstring).
        pose_psi_rad: (n,) its heading, clockwise; NaN where none.
        height_m: (n,) the laser hat's height for the scan (its ``scan`` event), NaN
            where none.
        t0_ns: the flight clock's time at ``t_s`` = 0.
        params: the sensor's PP parameters (from the recording; the URG-04LX's if it
            holds no PP reply).
        scan_steps: the flight's ``laser.scan_steps`` (its ``flight.json``, else the
            default): the steps the matcher used.
        warnings: what was dropped or assumed, naming the file.
    """

    t_ns: _I64
    t_s: _F64
    stamp_t_ns: _I64
    sensor_ms: _I64
    seq: _I64
    angle_min_rad: float
    angle_increment_rad: float
    beam_steps: _F64
    ranges_m: _F64
    pose_x_m: _F64
    pose_y_m: _F64
    pose_psi_rad: _F64
    height_m: _F64
    t0_ns: int
    params: SensorParams
    scan_steps: tuple[int, int]
    warnings: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.t_ns.size)

    @property
    def angles_rad(self) -> _F64:
        """(beams,) each beam's body-frame angle, positive to the right."""
        index = np.arange(self.beam_steps.size, dtype=np.float64)
        angles: _F64 = self.angle_min_rad + index * self.angle_increment_rad
        return angles

    def only_steps(self, first: int, last: int) -> ScanLog:
        """The same scans with only the beams of steps ``first..last`` (e.g. ``scan_steps``)."""
        keep = (self.beam_steps >= first) & (self.beam_steps <= last)
        index = np.flatnonzero(keep)
        angle_min = self.angle_min_rad + (index[0] if index.size else 0) * self.angle_increment_rad
        return replace(
            self,
            angle_min_rad=float(angle_min),
            beam_steps=self.beam_steps[keep],
            ranges_m=self.ranges_m[:, keep],
        )


@dataclass(frozen=True, slots=True)
class DecodedScan:
    """One scan as the driver got it: the reply, when it was read, its number and stamp."""

    reply: ScanReply
    read_t_ns: int
    seq: int
    stamp_t_ns: int
    ranges_m: _F64


@dataclass(frozen=True, slots=True)
class DecodedScans:
    """What :func:`decode_scans` found: the scans, the sensor's parameters, the parser's view."""

    scans: list[DecodedScan]
    params: SensorParams | None
    sum_errors: int
    malformed: int
    problems: tuple[str, ...] = ()


def decode_scans(recording: RawRecording, laser: LaserConfig | None = None) -> DecodedScans:
    """The scans the driver numbered, in order (module docstring: which replies, why).

    ``laser``: the flight's ``laser`` config (its ``transport_delay_s`` stamps the scans,
    as in flight); default :class:`~mkflight.config.LaserConfig`.
    """
    cfg = laser if laser is not None else LaserConfig()
    parser = ReplyParser()
    stamper = ScanStamper(cfg.transport_delay_s)
    params: SensorParams | None = None
    problems: list[str] = []
    stream: bytes | None = None  # the last MD/MS written: its messages are the flight's scans
    drained = False  # the last write was QT: the driver drains, then resets its parser
    out: list[DecodedScan] = []
    for rec in recording.records:
        if rec.kind in "oc":
            parser.reset()
            continue
        if rec.kind == "w":
            is_qt = rec.data.startswith(b"QT")
            if drained and not is_qt:
                parser.reset()
            drained = is_qt
            if rec.data[:2] in _STREAM_COMMANDS:
                stream = rec.data
            continue
        for reply in parser.feed(rec.data):
            if isinstance(reply, ScanReply) and reply.status == "99":
                if stream is not None and reply.answers(stream):
                    scan = stamper.stamp(reply, rec.t_ns, params or URG_04LX, seq=len(out) + 1)
                    out.append(DecodedScan(reply, rec.t_ns, scan.seq, scan.t_ns, scan.ranges_m))
            elif isinstance(reply, InfoReply) and reply.command == "PP" and reply.ok:
                try:
                    params = parse_params(reply.info)
                except ProtocolError as err:
                    problems.append(f"{recording.path}: {err}: the URG-04LX's assumed")
            elif reply.command == "RS" and reply.ok:
                stamper.reset()  # the sensor's timer restarts at 0
    stats = parser.stats
    return DecodedScans(out, params, stats.sum_errors, stats.malformed, tuple(problems))


def _pose_columns(seqs: Iterable[int], events: Iterable[Event]) -> tuple[_F64, _F64, _F64, _F64]:
    """x, y, psi and height of each ``seq`` from its ``scan`` event; NaN where none."""
    by_seq: dict[int, Scan] = {e.seq: e for e in events if isinstance(e, Scan)}

    def value(v: object) -> float:
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan

    rows = [
        (value(e.x_m), value(e.y_m), value(e.yaw_rad), value(e.height_m))
        if (e := by_seq.get(s)) is not None
        else (math.nan,) * 4
        for s in seqs
    ]
    table = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return table[:, 0], table[:, 1], table[:, 2], table[:, 3]


def scan_log(
    recording: RawRecording,
    events: Iterable[Event] = (),
    laser: LaserConfig | None = None,
    t0_ns: int | None = None,
) -> ScanLog:
    """The :class:`ScanLog` of a read ``laser.raw``, poses from ``events`` (pure).

    ``t0_ns`` None: the recording's ``start_t_ns``. The warnings name what was dropped
    (bad replies, scans of another geometry), not the recording's cut tail
    (:attr:`RawRecording.warning` says that).
    """
    cfg = laser if laser is not None else LaserConfig()
    decoded = decode_scans(recording, cfg)
    warnings = list(decoded.problems)
    if decoded.sum_errors or decoded.malformed:
        warnings.append(
            f"{recording.path}: {decoded.sum_errors} replies with a bad checksum and "
            f"{decoded.malformed} malformed ones dropped (as in flight)"
        )
    params = decoded.params
    if params is None:
        params = URG_04LX
        if decoded.scans:
            warnings.append(f"{recording.path}: no PP reply: the URG-04LX's parameters assumed")
    scans = decoded.scans
    shape = (
        (scans[0].reply.start_step, scans[0].reply.end_step, scans[0].reply.cluster)
        if scans
        else (0, -1, 1)
    )
    same = [s for s in scans if (s.reply.start_step, s.reply.end_step, s.reply.cluster) == shape]
    if len(same) < len(scans):
        warnings.append(
            f"{recording.path}: {len(scans) - len(same)} scans of other steps than "
            f"{shape[0]}-{shape[1]} (cluster {shape[2]}) left out"
        )
    steps = np.array(value_steps(*shape)[::-1], dtype=np.float64)
    ranges = np.array([s.ranges_m[::-1] for s in same], dtype=np.float64)
    ranges = ranges.reshape(len(same), steps.size)
    origin = recording.header.start_t_ns if t0_ns is None else t0_ns
    t_ns = np.array([s.read_t_ns for s in same], dtype=np.int64)
    seq = np.array([s.seq for s in same], dtype=np.int64)
    x, y, psi, height = _pose_columns(seq.tolist(), events)
    return ScanLog(
        t_ns=t_ns,
        t_s=(t_ns - origin) / NS_PER_S,
        stamp_t_ns=np.array([s.stamp_t_ns for s in same], dtype=np.int64),
        sensor_ms=np.array([s.reply.timestamp_ms for s in same], dtype=np.int64),
        seq=seq,
        angle_min_rad=step_body_angle_rad(float(steps[0]), params) if steps.size else 0.0,
        angle_increment_rad=max(shape[2], 1) * params.step_angle_rad,
        beam_steps=steps,
        ranges_m=ranges,
        pose_x_m=x,
        pose_y_m=y,
        pose_psi_rad=psi,
        height_m=height,
        t0_ns=origin,
        params=params,
        scan_steps=(int(cfg.scan_steps[0]), int(cfg.scan_steps[1])),
        warnings=tuple(warnings),
    )


def laser_config(config: Mapping[str, Any], path: Path) -> tuple[LaserConfig, str | None]:
    """The ``laser`` section of a flight's config (``flight.json``), defaults for the rest.

    A section that does not fit :class:`~mkflight.config.LaserConfig` (another version's,
    a damaged file) gives the defaults and a warning naming the file: the scans decode
    the same, only their stamps may move by a changed ``transport_delay_s``.
    """
    section = config.get("laser", {})
    try:
        return msgspec.convert(section, type=LaserConfig), None
    except msgspec.ValidationError as err:
        return LaserConfig(), f"{path}: config.laser: {err}: the defaults used for the scans"


def read_scans(source: str | Path, t0_ns: int | None = None) -> ScanLog:
    """Read the scans of ``source``: a ``laser.raw`` file or a flight folder holding one.

    The folder's (or the file's folder's) ``events.jsonl`` gives the poses and heights,
    its ``flight.json`` the laser config flown; both optional. ``t0_ns`` None: the
    recording's ``start_t_ns``.

    Raises:
        ReplayError: no ``laser.raw``, a broken recording, events or ``flight.json``;
            naming the file and the byte or line.
    """
    path = Path(source)
    raw_path = path / LASER_RAW if path.is_dir() else path
    if not raw_path.is_file():
        msg = f"{raw_path}: no such file (a flight folder's laser recording)"
        raise ReplayError(msg)
    folder = raw_path.parent
    recording = read_raw(raw_path)
    warnings = [] if recording.warning is None else [recording.warning]
    laser = None
    info_path = folder / flight_json.FILE_NAME
    if info_path.is_file():
        laser, problem = laser_config(flight_json.read_flight_json(info_path).config, info_path)
        warnings.extend([problem] if problem else [])
    events: list[Event] = []
    events_path = folder / events_log.FILE_NAME
    if events_path.is_file():
        data = read_events(events_path)
        events = data.events
        if data.truncated:
            warnings.append(f"{events_path}: incomplete last event dropped")
    log = scan_log(recording, events, laser, t0_ns)
    return replace(log, warnings=(*warnings, *log.warnings))
