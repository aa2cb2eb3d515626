"""The export's default encoding: JSON messages with JSON Schemas, Foxglove's where it has one.

``/scan`` is a ``foxglove.LaserScan``, ``/pose`` and ``/setpoint`` ``foxglove.PoseInFrame``,
``/tf`` and ``/tf_static`` ``foxglove.FrameTransform``: the Foxglove app knows these schema
names in any encoding and draws them in its 3D panel. The rest are plain records, named
after what they are (``geometry_msgs/Pose2D``, ``sensor_msgs/mikoImu`` and
``sensor_msgs/mikoCmd`` as TABLE V-VII name them, then ``mkflight.Height``...), with the
fields of :data:`mkflight.ground.export_series.KINDS`; Plot and Raw Messages panels read them.

Strict JSON has no NaN: an unknown value is ``null`` (a scan's invalid range too).
Foxglove's JSON times are ``{"sec", "nsec"}``.
"""

from __future__ import annotations

import json
import math
from typing import Any, Final

from mkflight.ground import topics
from mkflight.ground.export_series import (
    KINDS,
    NO_THROTTLE,
    Kind,
)
from mkflight.ground.frames import MAP_TO_WORLD, quaternion, sec_nsec

__all__ = ["SCHEMA_NAMES", "json_message", "json_schema"]

_TIME: Final = {
    "type": "object",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
}
_VECTOR3: Final = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z")},
}
_QUATERNION: Final = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")},
}
_POSE: Final = {"type": "object", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_TRANSFORM: Final[dict[str, Any]] = {
    "title": "foxglove.FrameTransform",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _VECTOR3,
        "rotation": _QUATERNION,
    },
}
_FOXGLOVE: Final[dict[str, tuple[str, dict[str, Any]]]] = {
    "LaserScan": (
        "foxglove.LaserScan",
        {
            "title": "foxglove.LaserScan",
            "type": "object",
            "properties": {
                "timestamp": _TIME,
                "frame_id": {"type": "string"},
                "pose": _POSE,
                "start_angle": {"type": "number"},
                "end_angle": {"type": "number"},
                "ranges": {"type": "array", "items": {"type": ["number", "null"]}},
                "intensities": {"type": "array", "items": {"type": "number"}},
            },
        },
    ),
    "Pose": (
        "foxglove.PoseInFrame",
        {
            "title": "foxglove.PoseInFrame",
            "type": "object",
            "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
        },
    ),
    "Transform": ("foxglove.FrameTransform", _TRANSFORM),
    "StaticTransform": ("foxglove.FrameTransform", _TRANSFORM),
}
#: The schema name of each of our own kinds.
SCHEMA_NAMES: Final = {
    **{name: f"mkflight.{name}" for name in KINDS},
    **{name: schema_name for name, (schema_name, _) in _FOXGLOVE.items()},
    "Pose2D": "geometry_msgs/Pose2D",
    "MikoImu": "sensor_msgs/mikoImu",
    "MikoCmd": "sensor_msgs/mikoCmd",
}
_JSON_TYPE: Final = {
    "float64": ["number", "null"],
    "int32": "integer",
    "int64": "integer",
    "string": "string",
}
_DESCRIPTION: Final = {
    "Pose2D": "TABLE V: the laser pose in the world frame (m, rad)",
    "MikoImu": "TABLE VI: attitude (rad) and specific force (m/s^2) in the body frame",
    "MikoCmd": f"TABLE VII: ExternControl counts; throttle {NO_THROTTLE}: not recorded",
}


def _record_schema(kind: Kind) -> dict[str, Any]:
    schema: dict[str, Any] = {
        "title": SCHEMA_NAMES[kind.name],
        "type": "object",
        "properties": {name: {"type": _JSON_TYPE[t]} for name, t in kind.fields},
        "required": [name for name, _ in kind.fields],
    }
    if kind.name in _DESCRIPTION:
        schema["description"] = _DESCRIPTION[kind.name]
    return schema


def json_schema(kind: str) -> tuple[str, bytes]:
    """A kind's schema name and its JSON Schema text."""
    if kind in _FOXGLOVE:
        name, schema = _FOXGLOVE[kind]
    else:
        name, schema = SCHEMA_NAMES[kind], _record_schema(KINDS[kind])
    return name, json.dumps(schema).encode()


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _time(t_ns: int) -> dict[str, int]:
    sec, nsec = sec_nsec(t_ns)
    return {"sec": sec, "nsec": nsec}


def _quat(q: tuple[float, float, float, float]) -> dict[str, float]:
    return dict(zip(("x", "y", "z", "w"), q, strict=True))


def _xyz(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _shaped(kind: str, row: dict[str, Any], t_ns: int) -> dict[str, Any]:
    """A Foxglove-schema message of one row (the kinds of ``_FOXGLOVE``)."""
    if kind == "LaserScan":
        ranges = [_finite(r) for r in row["ranges_m"]]
        start = row["angle_min_rad"]
        return {
            "timestamp": _time(row["stamp_ns"]),
            "frame_id": topics.VEHICLE_FRAME,
            "pose": {"position": _xyz(0.0, 0.0, 0.0), "orientation": _quat(quaternion())},
            "start_angle": start,
            "end_angle": start + (len(ranges) - 1) * row["angle_increment_rad"],
            "ranges": ranges,
            "intensities": [],
        }
    if kind == "StaticTransform":
        return {
            "timestamp": _time(t_ns),
            "parent_frame_id": topics.MAP_FRAME,
            "child_frame_id": topics.WORLD_FRAME,
            "translation": _xyz(0.0, 0.0, 0.0),
            "rotation": _quat(MAP_TO_WORLD),
        }
    position = _xyz(row["x_m"], row["y_m"], row["z_m"])
    orientation = _quat(quaternion(yaw_rad=row["yaw_rad"]))
    if kind == "Transform":
        return {
            "timestamp": _time(t_ns),
            "parent_frame_id": topics.WORLD_FRAME,
            "child_frame_id": topics.VEHICLE_FRAME,
            "translation": position,
            "rotation": orientation,
        }
    return {
        "timestamp": _time(t_ns),
        "frame_id": topics.WORLD_FRAME,
        "pose": {"position": position, "orientation": orientation},
    }


def json_message(kind: str, row: dict[str, Any], t_ns: int) -> bytes:
    """One message of ``kind`` (a :class:`~mkflight.ground.export_series.Series` row)."""
    if kind in _FOXGLOVE:
        out = _shaped(kind, row, t_ns)
    else:
        out = {name: _finite(row[name]) for name, _ in KINDS[kind].fields}
    return json.dumps(out, separators=(",", ":"), allow_nan=False).encode()
