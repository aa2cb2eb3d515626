"""The export's ``--ros2`` encoding: ROS 2 message definitions and the messages of each row.

Standard types where ROS 2 has one, so that ``ros2 bag play`` and RViz need nothing
built: ``/scan`` ``sensor_msgs/msg/LaserScan``, ``/pose2D`` ``geometry_msgs/msg/Pose2D``
(TABLE V), ``/pose`` and ``/setpoint`` ``geometry_msgs/msg/PoseStamped``, ``/tf`` and
``/tf_static`` ``tf2_msgs/msg/TFMessage`` (each ``/tf`` message holds map -> world as
well as world -> vehicle: ``ros2 bag play`` offers ``/tf_static`` with the default QoS,
which RViz's latched static listener does not take), ``/phase`` and ``/failsafe``
``std_msgs/msg/String`` (its ``data`` the JSON object the default export writes). Every
``header.stamp`` is the recorded time (:mod:`mkflight.ground.export_series`).

The others are ``mkflight_msgs/msg/*``, defined here (:data:`DEFINITIONS`; the README says
how to build them into a package for ``ros2 bag play``). ``MikoImu`` and ``MikoCmd``
carry TABLE VI's and VII's fields and no header, as the original system's did, with ROS 2's
field names (lower case: ``pitchAngle`` is ``pitch_angle``, ``AccX`` is ``acc_x``); the
rest (``Height``, ``Velocity``, ``Attitude``, ``Battery``, ``Command``, ``Truth``) have a
``std_msgs/Header`` and the fields of :data:`mkflight.ground.export_series.KINDS`.

NaN (a value unknown, a scan's invalid range) stays NaN, as in ROS's LaserScan (REP 117).
"""

from __future__ import annotations

import json
import re
from typing import Any, Final

from mkflight.conversions import NS_PER_S
from mkflight.ground import topics
from mkflight.ground.export_series import (
    KINDS,
    NO_THROTTLE,
)
from mkflight.ground.frames import MAP_TO_WORLD, quaternion, sec_nsec
from mkflight.urg.units import URG_04LX

__all__ = ["DEFINITIONS", "TYPE_NAMES", "msgdef", "ros2_field", "ros2_message"]

_SEPARATOR: Final = "=" * 80
#: Every message definition the export needs, by type (``pkg/Name``), without its deps.
DEFINITIONS: Final[dict[str, str]] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/String": "string data\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    "geometry_msgs/Pose2D": "float64 x\nfloat64 y\nfloat64 theta\n",
    "geometry_msgs/Transform": (
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
    ),
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"
    ),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/LaserScan": (
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n"
        "float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n"
        "float32[] ranges\nfloat32[] intensities\n"
    ),
    "mkflight_msgs/MikoImu": "".join(
        f"float64 {n}\n"
        for n in ("pitch_angle", "roll_angle", "yaw_angle", "acc_x", "acc_y", "acc_z")
    ),
    "mkflight_msgs/MikoCmd": (
        f"int32 THROTTLE_NOT_RECORDED={NO_THROTTLE}\n"
        "int32 pitch\nint32 roll\nint32 yaw\nint32 throttle\n"
    ),
    **{
        f"mkflight_msgs/{k.name}": "std_msgs/Header header\n"
        + "".join(f"{t} {n}\n" for n, t in k.fields)
        for k in KINDS.values()
        if k.name in ("Height", "Velocity", "Attitude", "Battery", "Command", "Truth")
    },
}
#: The ROS 2 type of each kind.
TYPE_NAMES: Final = {
    "Pose2D": "geometry_msgs/Pose2D",
    "MikoImu": "mkflight_msgs/MikoImu",
    "MikoCmd": "mkflight_msgs/MikoCmd",
    "LaserScan": "sensor_msgs/LaserScan",
    "Pose": "geometry_msgs/PoseStamped",
    "Transform": "tf2_msgs/TFMessage",
    "StaticTransform": "tf2_msgs/TFMessage",
    "Phase": "std_msgs/String",
    "Failsafe": "std_msgs/String",
    **{n: f"mkflight_msgs/{n}" for n in ("Height", "Velocity", "Attitude", "Battery")},
    **{n: f"mkflight_msgs/{n}" for n in ("Command", "Truth")},
}
_TYPE_WORD: Final = re.compile(r"^([A-Za-z_][\w]*/[A-Za-z_]\w*)(\[\])?\s")


def _deps(type_name: str, seen: list[str]) -> None:
    for line in DEFINITIONS[type_name].splitlines():
        m = _TYPE_WORD.match(line)
        if m and m.group(1) not in seen:
            seen.append(m.group(1))
            _deps(m.group(1), seen)


def msgdef(type_name: str) -> tuple[str, str]:
    """``(pkg/msg/Name, definition text)`` of a type ``pkg/Name``.

    Its dependencies are appended as ROS 2's MCAP profile has them (``MSG: pkg/Name``
    sections after a line of ``=``).
    """
    deps: list[str] = []
    _deps(type_name, deps)
    text = DEFINITIONS[type_name] + "".join(
        f"{_SEPARATOR}\nMSG: {d}\n{DEFINITIONS[d]}" for d in deps
    )
    pkg, name = type_name.split("/")
    return f"{pkg}/msg/{name}", text


def ros2_field(name: str) -> str:
    """A TABLE VI field's ROS 2 name: ``pitchAngle`` -> ``pitch_angle``, ``AccX`` -> ``acc_x``."""
    return re.sub(r"(?<=[a-z])(?=[A-Z])", "_", name).lower()


def _header(t_ns: int, frame_id: str) -> dict[str, Any]:
    sec, nsec = sec_nsec(t_ns)
    return {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": frame_id}


def _quat(q: tuple[float, float, float, float]) -> dict[str, float]:
    return dict(zip(("x", "y", "z", "w"), q, strict=True))


def _scan(row: dict[str, Any]) -> dict[str, Any]:
    ranges = row["ranges_m"]
    start, step = row["angle_min_rad"], row["angle_increment_rad"]
    period_s = URG_04LX.scan_period_ns / NS_PER_S
    return {
        "header": _header(row["stamp_ns"], topics.VEHICLE_FRAME),
        "angle_min": start,
        "angle_max": start + (len(ranges) - 1) * step,
        "angle_increment": step,
        "time_increment": period_s / URG_04LX.ares_steps,
        "scan_time": period_s,
        "range_min": URG_04LX.dmin_mm / 1000,
        "range_max": URG_04LX.dmax_mm / 1000,
        "ranges": ranges,
        "intensities": [],
    }


def _stamped(
    t_ns: int, parent: str, child: str, xyz: tuple[float, ...], q: tuple[float, float, float, float]
) -> dict[str, Any]:
    """A ``geometry_msgs/TransformStamped``."""
    x, y, z = xyz
    return {
        "header": _header(t_ns, parent),
        "child_frame_id": child,
        "transform": {"translation": {"x": x, "y": y, "z": z}, "rotation": _quat(q)},
    }


def _map_to_world(t_ns: int) -> dict[str, Any]:
    """The transform map -> world: W turned z up (a half turn about x)."""
    q = MAP_TO_WORLD
    return _stamped(t_ns, topics.MAP_FRAME, topics.WORLD_FRAME, (0.0, 0.0, 0.0), q)


def _shaped(kind: str, row: dict[str, Any], t_ns: int) -> dict[str, Any]:
    """The standard-type messages: scan, pose, transforms, strings."""
    if kind == "LaserScan":
        return _scan(row)
    if kind == "StaticTransform":
        return {"transforms": [_map_to_world(t_ns)]}
    if kind in ("Phase", "Failsafe"):
        return {"data": json.dumps(row, allow_nan=False)}
    xyz = (row["x_m"], row["y_m"], row["z_m"])
    q = quaternion(yaw_rad=row["yaw_rad"])
    if kind == "Transform":  # map -> world again: a bag's /tf_static is not latched
        vehicle = _stamped(t_ns, topics.WORLD_FRAME, topics.VEHICLE_FRAME, xyz, q)
        return {"transforms": [_map_to_world(t_ns), vehicle]}
    position = dict(zip(("x", "y", "z"), xyz, strict=True))
    return {
        "header": _header(t_ns, topics.WORLD_FRAME),
        "pose": {"position": position, "orientation": _quat(q)},
    }


def ros2_message(kind: str, row: dict[str, Any], t_ns: int) -> dict[str, Any]:
    """One message of ``kind`` as the dict ``mcap_ros2``'s writer encodes."""
    if kind in ("Pose2D", "MikoImu", "MikoCmd"):
        return {ros2_field(n): row[n] for n, _ in KINDS[kind].fields}
    if TYPE_NAMES[kind].startswith("mkflight_msgs/"):
        frame = topics.WORLD_FRAME if kind == "Truth" else ""  # the rest are no place
        out: dict[str, Any] = {"header": _header(t_ns, frame)}
        out.update((n, row[n]) for n, _ in KINDS[kind].fields)
        return out
    return _shaped(kind, row, t_ns)
