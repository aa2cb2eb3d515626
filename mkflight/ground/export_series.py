"""A flight folder's records as MCAP topics: pure conversions, column-wise.

Each topic is a :class:`Series`: the recorded time of every message (``t_ns``, the
flight clock's) and its values in SI, named columns, NaN where a value is unknown. The
encoders (:mod:`mkflight.ground.export_json`, :mod:`mkflight.ground.ros2_msgs`) turn a
row into a message; nothing here knows an encoding.

Where each topic comes from (the original system's topics first, §I of the 2011 QUT CyPhy
MikroKopter documentation):

- ``/pose2D`` (TABLE V: ``x``, ``y``, ``theta``): one per TABLE III row, its
  ``CurrentPosition.x``, ``.y``, ``.theta``, at the row's scan time.
- ``/mikoImu`` (TABLE VI: ``pitchAngle``, ``rollAngle``, ``yawAngle``, ``AccX``,
  ``AccY``, ``AccZ``): one per TABLE IV row, its ``AnglePitch``, ``AngleRoll``,
  ``AngleYaw``, ``AccX``, ``AccY``, ``AccZ`` (rad, m/s², body frame), at the row's step.
- ``/mikoCmd`` (TABLE VII: ``pitch``, ``roll``, ``yaw``, ``throttle``): one per
  ExternControl written to the FC (``mk.raw``), its ``nick``, ``roll``, ``yaw`` and
  ``gas`` counts as on the wire (MK signs, SPEC §1), at the write. A folder without
  ``mk.raw`` (``sim hover``'s, or the original system's two tables alone) gets one per
  TABLE IV row instead: ``ControlPitch``, ``ControlRoll``, ``ControlYaw``, and the gas of
  the row's ``step`` event; with no events, ``throttle`` is unknown (:data:`NO_THROTTLE`),
  since TABLE IV records no commanded gas.
- ``/scan``: every scan of ``laser.raw`` (:func:`mkflight.logs.scans.read_scans`), the
  beams of ``laser.scan_steps`` (the scan plane; the hat's beams give ``/height``), in m,
  NaN for the URG's error codes, in the vehicle frame. Its log time is the ``laser.raw``
  read that completed the reply (when the flight had it); its ``timestamp`` (``header.stamp``)
  is the driver's stamp, when the front step was measured (the ``scan`` event's ``t_ns``).
- ``/pose`` and ``/tf`` (world -> vehicle): every ``step`` event with a position: ``x_m``,
  ``y_m``, height up as ``z = -height_m`` (W is z down; 0 while the height is unknown),
  and the heading of the latest TABLE III row (0 before the first). Attitude is not in
  the pose: it is on ``/attitude``.
- ``/setpoint``: every ``step`` event with a set-point (``sp_x_m``, ``sp_y_m``,
  ``sp_height_m``), heading 0 (the yaw controller holds the initial heading, §J).
- ``/height``: every ``step``: ``height_m``, ``vz_up_mps``, ``sp_height_m``.
- ``/velocity``: every TABLE III row's velocities (W, B from the laser, B estimated).
- ``/attitude`` and ``/battery``: every DebugOut read, in SI with the flight's own
  calibration (:func:`mkflight.logs.load_flight`).
- ``/command``: every ExternControl written: ``nick``, ``roll``, ``yaw``, ``gas``,
  ``config`` counts.
- ``/phase`` and ``/failsafe``: the ``phase`` and ``failsafe`` events.
- ``/truth``: the simulator's ``truth.txt`` rows (x, y in W, height up), when present.
- ``/tf_static``: map -> world once, at the first message's time (W turned z up), with
  ``/tf`` or ``/scan``.

Time: ``t_ns`` is the flight clock's time of the record (host monotonic on the vehicle,
the simulator's clock in ``sim hover``), as the events, the raw records and the truth
rows carry it: ``t0_ns + t_s`` of :class:`~mkflight.logs.flight.FlightData`, exact to
the nanosecond. A tables-only folder has no clock: its rows are at their nominal times
(``index`` times 50 ms or 100 ms) from 0. A table row without a time (no event for it,
e.g. the last row of a killed flight) is left out and counted.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Literal, Protocol

import numpy as np
import numpy.typing as npt

from mkflight.conversions import NS_PER_S
from mkflight.ground import topics

if TYPE_CHECKING:
    from mkflight.logs.flight import FlightData

__all__ = [
    "KINDS",
    "NO_THROTTLE",
    "Kind",
    "Scans",
    "Series",
    "flight_series",
    "left_out",
    "miko_cmd_from_commands",
    "miko_cmd_from_table4",
    "miko_imu_from_table4",
    "original_series",
    "pose2d_from_table3",
    "row_gas",
    "scan_series",
    "static_transform",
]

Array = npt.NDArray[Any]


class Scans(Protocol):
    """What ``/scan`` reads of :class:`mkflight.logs.scans.ScanLog` (the scans of ``laser.raw``)."""

    @property
    def t_ns(self) -> npt.NDArray[np.int64]:
        """(n,) the read that completed each scan reply (flight clock)."""

    @property
    def stamp_t_ns(self) -> npt.NDArray[np.int64]:
        """(n,) when each scan was taken: the driver's stamp of its front step."""

    @property
    def angle_min_rad(self) -> float:
        """Beam 0's angle in the vehicle frame, positive to the right."""

    @property
    def angle_increment_rad(self) -> float:
        """The angle between neighbouring beams."""

    @property
    def ranges_m(self) -> npt.NDArray[np.float64]:
        """(n, beams) ranges; NaN where the URG reported none."""


FieldType = Literal["float64", "int32", "int64", "string"]

#: ``/mikoCmd``'s throttle when the folder does not record it (TABLE IV has no gas
#: column); TABLE VII's throttle is 0-512, so no real command has it.
NO_THROTTLE: Final = -1


@dataclass(frozen=True, slots=True)
class Kind:
    """A message type: its name and its fields in order.

    The scan, the poses and the transforms have shapes of their own; theirs are the
    columns they read.
    """

    name: str
    fields: tuple[tuple[str, FieldType], ...]


_F: Final = "float64"
KINDS: Final[dict[str, Kind]] = {
    k.name: k
    for k in (
        Kind("Pose2D", (("x", _F), ("y", _F), ("theta", _F))),  # TABLE V
        Kind(
            "MikoImu",  # TABLE VI
            tuple((n, _F) for n in ("pitchAngle", "rollAngle", "yawAngle", "AccX", "AccY", "AccZ")),
        ),
        Kind("MikoCmd", tuple((n, "int32") for n in ("pitch", "roll", "yaw", "throttle"))),
        Kind(
            "LaserScan",
            (
                ("stamp_ns", "int64"),
                ("angle_min_rad", _F),
                ("angle_increment_rad", _F),
                ("ranges_m", _F),
            ),
        ),
        Kind("Pose", (("x_m", _F), ("y_m", _F), ("z_m", _F), ("yaw_rad", _F))),
        Kind("Transform", (("x_m", _F), ("y_m", _F), ("z_m", _F), ("yaw_rad", _F))),
        Kind("StaticTransform", ()),
        Kind("Height", (("height_m", _F), ("vz_up_mps", _F), ("sp_height_m", _F))),
        Kind(
            "Velocity",
            tuple(
                (f"{frame}_vel_{axis}_mps", _F)
                for axis in ("x", "y")
                for frame in ("w", "b", "b_esti")
            ),
        ),
        Kind("Attitude", (("pitch_rad", _F), ("roll_rad", _F), ("yaw_rad", _F))),
        Kind("Battery", (("battery_v", _F),)),
        Kind("Command", tuple((n, "int32") for n in ("nick", "roll", "yaw", "gas", "config"))),
        Kind("Phase", (("phase", "string"), ("reason", "string"))),
        Kind("Failsafe", (("action", "string"), ("cause", "string"))),
        Kind("Truth", (("x_m", _F), ("y_m", _F), ("height_m", _F))),
    )
}
"""Every message type the export writes, by name."""


@dataclass(frozen=True, slots=True, eq=False)
class Series:
    """One topic's messages: ``t_ns`` (n,) and the :class:`Kind`'s columns, each (n, ...)."""

    topic: str
    kind: str
    t_ns: npt.NDArray[np.int64]
    columns: Mapping[str, Array]

    def __len__(self) -> int:
        return len(self.t_ns)

    def row(self, i: int) -> dict[str, Any]:
        """Message ``i``'s values as Python values (NaN stays NaN; ranges a float list)."""
        return {k: v[i].tolist() for k, v in self.columns.items()}


def _t_ns(t_s: npt.NDArray[np.float64], t0_ns: int) -> npt.NDArray[np.int64]:
    """The flight clock's ns of times in s since ``t0_ns`` (exact: ``t_s`` came from ns)."""
    ns = np.rint(np.asarray(t_s, dtype=np.float64) * NS_PER_S).astype(np.int64)
    return ns + np.int64(t0_ns)


def _series(topic: str, kind: str, t_s: Array, t0_ns: int, columns: Mapping[str, Array]) -> Series:
    """The series of the rows whose time is known, sorted by time (stable)."""
    t = np.asarray(t_s, dtype=np.float64)
    keep = np.isfinite(t)
    t_ns = _t_ns(t[keep], t0_ns)
    order = np.argsort(t_ns, kind="stable")
    cols = {k: np.asarray(v)[keep][order] for k, v in columns.items()}
    return Series(topic, kind, t_ns[order], cols)


def pose2d_from_table3(laser: Array, t_s: Array, t0_ns: int) -> Series:
    """``/pose2D`` (TABLE V) from TABLE III rows: ``CurrentPosition.x/.y/.theta``."""
    cols = {
        "x": laser["CurrentPosition.x"],
        "y": laser["CurrentPosition.y"],
        "theta": laser["CurrentPosition.theta"],
    }
    return _series(topics.POSE2D, "Pose2D", t_s, t0_ns, cols)


_IMU_COLUMNS: Final = {
    "pitchAngle": "AnglePitch",
    "rollAngle": "AngleRoll",
    "yawAngle": "AngleYaw",
    "AccX": "AccX",
    "AccY": "AccY",
    "AccZ": "AccZ",
}


def miko_imu_from_table4(imu: Array, t_s: Array, t0_ns: int) -> Series:
    """``/mikoImu`` (TABLE VI) from TABLE IV rows: the angles and accelerations."""
    cols = {name: imu[col] for name, col in _IMU_COLUMNS.items()}
    return _series(topics.MIKO_IMU, "MikoImu", t_s, t0_ns, cols)


def miko_cmd_from_commands(commands: Array, t0_ns: int) -> Series:
    """``/mikoCmd`` (TABLE VII) from the ExternControls written: nick, roll, yaw, gas."""
    cols = {
        "pitch": commands["nick"],
        "roll": commands["roll"],
        "yaw": commands["yaw"],
        "throttle": commands["gas"],
    }
    return _series(topics.MIKO_CMD, "MikoCmd", commands["t_s"], t0_ns, cols)


def miko_cmd_from_table4(
    imu: Array, t_s: Array, t0_ns: int, gas: npt.NDArray[np.int64] | None = None
) -> Series:
    """``/mikoCmd`` (TABLE VII) from TABLE IV's ``Control*`` and each row's ``gas`` sent.

    ``gas``: one per row (:data:`NO_THROTTLE` where unknown); None: all unknown.
    """
    cols = {
        "pitch": imu["ControlPitch"],
        "roll": imu["ControlRoll"],
        "yaw": imu["ControlYaw"],
        "throttle": np.full(len(imu), NO_THROTTLE, dtype=np.int64) if gas is None else gas,
    }
    return _series(topics.MIKO_CMD, "MikoCmd", t_s, t0_ns, cols)


def scan_series(scans: Scans) -> Series:
    """``/scan``: every scan at the read that completed it, stamped when it was taken."""
    n = len(scans.t_ns)
    cols = {
        "stamp_ns": np.asarray(scans.stamp_t_ns, dtype=np.int64),
        "angle_min_rad": np.full(n, scans.angle_min_rad),
        "angle_increment_rad": np.full(n, scans.angle_increment_rad),
        "ranges_m": np.asarray(scans.ranges_m, dtype=np.float64).reshape(n, -1),
    }
    t_ns = np.asarray(scans.t_ns, dtype=np.int64)
    order = np.argsort(t_ns, kind="stable")
    return Series(topics.SCAN, "LaserScan", t_ns[order], {k: v[order] for k, v in cols.items()})


def _headings(step_t_s: Array, laser: Array, laser_t_s: Array) -> npt.NDArray[np.float64]:
    """The heading of the latest TABLE III row at or before each step (0 before any)."""
    theta = np.asarray(laser["CurrentPosition.theta"], dtype=np.float64)
    good = np.isfinite(laser_t_s) & np.isfinite(theta)
    t, th = np.asarray(laser_t_s)[good], theta[good]
    order = np.argsort(t, kind="stable")
    t, th = t[order], th[order]
    at = np.searchsorted(t, step_t_s, side="right") - 1
    return np.where(at >= 0, th[np.maximum(at, 0)] if len(th) else 0.0, 0.0)


def _zero_nan(values: Array) -> npt.NDArray[np.float64]:
    v = np.asarray(values, dtype=np.float64)
    return np.where(np.isfinite(v), v, 0.0)


def _step_series(flight: FlightData, t0_ns: int) -> list[Series]:
    """``/pose``, ``/tf``, ``/setpoint`` and ``/height`` from the ``step`` events."""
    s = flight.steps
    t = s["t_s"]
    has_pose = np.isfinite(s["x_m"]) & np.isfinite(s["y_m"])
    pose = {
        "x_m": s["x_m"],
        "y_m": s["y_m"],
        "z_m": -_zero_nan(s["height_m"]),
        "yaw_rad": _headings(t, flight.laser, flight.laser_t_s),
    }
    pose_t = np.where(has_pose, t, np.nan)
    has_sp = np.isfinite(s["sp_x_m"]) & np.isfinite(s["sp_y_m"])
    setpoint = {
        "x_m": s["sp_x_m"],
        "y_m": s["sp_y_m"],
        "z_m": -_zero_nan(s["sp_height_m"]),
        "yaw_rad": np.zeros(len(s)),
    }
    height = {k: s[k] for k in ("height_m", "vz_up_mps", "sp_height_m")}
    return [
        _series(topics.POSE, "Pose", pose_t, t0_ns, pose),
        _series(topics.TF, "Transform", pose_t, t0_ns, pose),
        _series(topics.SETPOINT, "Pose", np.where(has_sp, t, np.nan), t0_ns, setpoint),
        _series(topics.HEIGHT, "Height", t, t0_ns, height),
    ]


def _velocity(laser: Array, t_s: Array, t0_ns: int) -> Series:
    cols = {
        f"{frame}_vel_{axis}_mps": laser[f"{column}_Vel.{axis}"]
        for axis in ("x", "y")
        for frame, column in (("w", "W"), ("b", "B"), ("b_esti", "B_esti"))
    }
    return _series(topics.VELOCITY, "Velocity", t_s, t0_ns, cols)


def _event_series(flight: FlightData, t0_ns: int) -> list[Series]:
    """``/phase`` and ``/failsafe`` from their events."""
    phases = flight.event_table("phase")
    failsafes = flight.event_table("failsafe")
    return [
        _series(
            topics.PHASE,
            "Phase",
            phases["t_s"],
            t0_ns,
            {"phase": phases["to"], "reason": phases["reason"]},
        ),
        _series(
            topics.FAILSAFE,
            "Failsafe",
            failsafes["t_s"],
            t0_ns,
            {"action": failsafes["action"], "cause": failsafes["cause"]},
        ),
    ]


def _sample_series(flight: FlightData, t0_ns: int) -> list[Series]:
    """``/attitude``, ``/battery`` (DebugOut) and ``/command`` (ExternControl)."""
    sm, cm = flight.samples, flight.commands
    return [
        _series(
            topics.ATTITUDE,
            "Attitude",
            sm["t_s"],
            t0_ns,
            {k: sm[k] for k in ("pitch_rad", "roll_rad", "yaw_rad")},
        ),
        _series(topics.BATTERY, "Battery", sm["t_s"], t0_ns, {"battery_v": sm["battery_v"]}),
        _series(
            topics.COMMAND,
            "Command",
            cm["t_s"],
            t0_ns,
            {k: cm[k] for k in ("nick", "roll", "yaw", "gas", "config")},
        ),
    ]


def row_gas(imu: Array, steps: Array) -> npt.NDArray[np.int64]:
    """Each TABLE IV row's gas sent, from its step event's ``gas_counts``.

    The k-th step event is the row of index k; a row without one gets :data:`NO_THROTTLE`.
    """
    gas = np.full(len(imu), NO_THROTTLE, dtype=np.int64)
    k = np.asarray(imu["index"], dtype=np.int64) - 1
    step_gas = np.asarray(steps["gas_counts"], dtype=np.float64)
    ok = (k >= 0) & (k < len(step_gas))
    ok[ok] &= np.isfinite(step_gas[k[ok]])
    gas[ok] = step_gas[k[ok]].astype(np.int64)
    return gas


def original_series(flight: FlightData) -> list[Series]:
    """``/pose2D``, ``/mikoImu`` and ``/mikoCmd``: the original system's topics (TABLE V-VII)."""
    t0 = flight.t0_ns or 0
    cmd = (
        miko_cmd_from_commands(flight.commands, t0)
        if len(flight.commands)
        else miko_cmd_from_table4(flight.imu, flight.imu_t_s, t0, row_gas(flight.imu, flight.steps))
    )
    return [
        pose2d_from_table3(flight.laser, flight.laser_t_s, t0),
        miko_imu_from_table4(flight.imu, flight.imu_t_s, t0),
        cmd,
    ]


def static_transform(t_ns: int) -> Series:
    """``/tf_static``: map -> world (:data:`~mkflight.ground.frames.MAP_TO_WORLD`), at ``t_ns``."""
    return Series(topics.TF_STATIC, "StaticTransform", np.array([t_ns], dtype=np.int64), {})


def flight_series(
    flight: FlightData, scans: Scans | None = None, *, tables_only: bool = False
) -> list[Series]:
    """Every topic of a flight folder (module docstring); empty series left out.

    ``tables_only``: the original system's three topics alone.
    """
    out = original_series(flight)
    if not tables_only:
        t0 = flight.t0_ns or 0
        if scans is not None:
            out.append(scan_series(scans))
        if len(flight.events):
            out += _step_series(flight, t0)
            out += _event_series(flight, t0)
        out.append(_velocity(flight.laser, flight.laser_t_s, t0))
        out += _sample_series(flight, t0)
        if flight.truth is not None:
            tr = flight.truth
            cols = {k: tr[k] for k in ("x_m", "y_m", "height_m")}
            out.append(_series(topics.TRUTH, "Truth", tr["t_s"], t0, cols))
    out = [s for s in out if len(s)]
    if any(s.topic in (topics.SCAN, topics.TF) for s in out):  # frames to show them in
        out.append(static_transform(min(int(s.t_ns[0]) for s in out)))
    return out


def left_out(flight: FlightData) -> dict[str, int]:
    """How many table rows have no time and are not exported, by file."""
    return {
        name: int(np.count_nonzero(~np.isfinite(t)))
        for name, t in (("imu_50ms.log", flight.imu_t_s), ("laser_100ms.log", flight.laser_t_s))
        if not np.all(np.isfinite(t))
    }
