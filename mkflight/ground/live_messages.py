"""The live view's messages, built from the flight's own values: pure functions.

Frames (SPEC §1). The poses, the set-point and the transforms are published in W as the
flight has them, frame ``world`` (x forward at the first scan, y right, z down; ψ
clockwise seen from above), and the scan in B, frame ``vehicle`` (x forward, y right,
z down): the numbers on the wire are the flight folder's, a height ``h`` is ``z = -h``.
A clockwise yaw ψ is a right-handed turn about z *down*, so its quaternion is
``(x, y, z, w) = (0, 0, sin ψ/2, cos ψ/2)``; the vehicle's orientation is
``q_z(ψ) q_y(θ) q_x(φ)`` (yaw, pitch nose up, roll right side down: FRD's Z-Y-X). For
viewers that assume a z-up world, ``/tf`` also carries the fixed transform ``map`` ->
``world``, a half turn about x (``map`` = W turned z up: x forward, y left): set the 3D
panel's display frame to ``map`` and the vehicle flies upright.

The scan carries the wall beams only (``laser.scan_steps``; the hat's beams look down
through the mirror and give the height, ``/height``). Step ``s`` is at body angle
``-(s - 384)·2π/1024`` (right positive, :func:`~mkflight.urg.units.step_body_angle_rad`),
which in B's x-y plane is the LaserScan's bearing; the ranges go in rising bearing
(left to right), so ``ranges[0]`` is the last scan step. NaN (no return) stays NaN.

The other topics are JSON with a JSON schema (``SCHEMAS``); a non-finite value is
``null`` (JSON has no NaN). Every message's log time is the flight clock's ``t_ns`` of
the value (the DebugOut's, the scan's, the event's), the time the flight folder records.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Final

from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    LaserScan,
    Pose,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)

from mkflight.ground import frames, topics
from mkflight.ground.frames import MAP_TO_WORLD, sec_nsec
from mkflight.urg.units import step_body_angle_rad

if TYPE_CHECKING:
    from mkflight.control.controller import Setpoint
    from mkflight.control.phases import PhaseEvent
    from mkflight.msgs import Command, Estimate, ImuSample, Scan
    from mkflight.safety.failsafe import TransitionEvent

Json = dict[str, Any]


def stamp(t_ns: int) -> Timestamp:
    """A Foxglove timestamp of the flight clock's ``t_ns``."""
    return Timestamp(*sec_nsec(t_ns))


def finite_or(value: float, default: float) -> float:
    """``value``, or ``default`` when it is NaN or infinite."""
    return value if math.isfinite(value) else default


def quaternion(yaw_rad: float, pitch_rad: float = 0.0, roll_rad: float = 0.0) -> Quaternion:
    """``q_z(ψ) q_y(θ) q_x(φ)`` in an FRD frame (module docstring); NaN angles as 0."""
    x, y, z, w = frames.quaternion(
        finite_or(yaw_rad, 0.0), finite_or(pitch_rad, 0.0), finite_or(roll_rad, 0.0)
    )
    return Quaternion(x=x, y=y, z=z, w=w)


def _vehicle_pose(est: Estimate, sample: ImuSample) -> Pose:
    """The estimated position in W and the attitude: heading estimated, tilt measured."""
    return Pose(
        position=Vector3(x=est.x_m, y=est.y_m, z=-est.height_m),
        orientation=quaternion(est.yaw_rad, sample.pitch_rad, sample.roll_rad),
    )


def pose_message(est: Estimate, sample: ImuSample) -> PoseInFrame:
    """``/pose``: the estimated pose in ``world``, at the DebugOut's time."""
    return PoseInFrame(
        timestamp=stamp(sample.t_ns),
        frame_id=topics.WORLD_FRAME,
        pose=_vehicle_pose(est, sample),
    )


def setpoint_message(t_ns: int, sp: Setpoint) -> PoseInFrame:
    """``/setpoint``: where the controller was told to be, in ``world`` (heading only)."""
    return PoseInFrame(
        timestamp=stamp(t_ns),
        frame_id=topics.WORLD_FRAME,
        pose=Pose(
            position=Vector3(x=sp.x_m, y=sp.y_m, z=-sp.height_m),
            orientation=quaternion(sp.yaw_rad),
        ),
    )


def transforms_message(est: Estimate, sample: ImuSample) -> FrameTransforms:
    """``/tf``: ``map`` -> ``world`` (fixed) and ``world`` -> ``vehicle`` (the estimate)."""
    t = stamp(sample.t_ns)
    x, y, z, w = MAP_TO_WORLD
    return FrameTransforms(
        transforms=[
            FrameTransform(
                timestamp=t,
                parent_frame_id=topics.MAP_FRAME,
                child_frame_id=topics.WORLD_FRAME,
                translation=Vector3(),
                rotation=Quaternion(x=x, y=y, z=z, w=w),
            ),
            FrameTransform(
                timestamp=t,
                parent_frame_id=topics.WORLD_FRAME,
                child_frame_id=topics.VEHICLE_FRAME,
                translation=Vector3(x=est.x_m, y=est.y_m, z=-est.height_m),
                rotation=quaternion(est.yaw_rad, sample.pitch_rad, sample.roll_rad),
            ),
        ]
    )


def scan_message(scan: Scan, scan_steps: tuple[int, int]) -> LaserScan | None:
    """``/scan``: the wall beams of ``scan`` in ``vehicle`` (None: none of them in it)."""
    n = len(scan.ranges_m)
    i0 = max(0, scan_steps[0] - scan.first_step)
    i1 = min(n, scan_steps[1] - scan.first_step + 1)
    if i1 - i0 < 2:  # a bearing range needs two beams
        return None
    return LaserScan(
        timestamp=stamp(scan.t_ns),
        frame_id=topics.VEHICLE_FRAME,
        start_angle=step_body_angle_rad(scan.first_step + i1 - 1),
        end_angle=step_body_angle_rad(scan.first_step + i0),
        ranges=scan.ranges_m[i0:i1][::-1].tolist(),
    )


def _num(value: float) -> float | None:
    """A JSON number: ``None`` for NaN or infinity."""
    return value if math.isfinite(value) else None


def height_json(est: Estimate) -> Json:
    """``/height``: the estimated height (up) and climb rate, and whether it is valid."""
    return {
        "height_m": _num(est.height_m),
        "vz_up_mps": _num(est.vz_up_mps),
        "valid": est.height_valid,
    }


def attitude_json(sample: ImuSample) -> Json:
    """``/attitude``: the FC's pitch, roll and heading (SPEC §1, DebugOut)."""
    return {
        "pitch_rad": _num(sample.pitch_rad),
        "roll_rad": _num(sample.roll_rad),
        "yaw_rad": _num(sample.yaw_rad),
    }


def velocity_json(est: Estimate) -> Json:
    """``/velocity``: the velocity estimate in W (z up), and whether the pose is valid."""
    return {
        "vx_mps": _num(est.vx_mps),
        "vy_mps": _num(est.vy_mps),
        "vz_up_mps": _num(est.vz_up_mps),
        "valid": est.pose_valid,
    }


def command_json(cmd: Command) -> Json:
    """``/command``: the ExternControl sent, in MK counts (signs applied, SPEC §4)."""
    return {
        "nick_counts": cmd.nick_counts,
        "roll_counts": cmd.roll_counts,
        "yaw_counts": cmd.yaw_counts,
        "gas_counts": cmd.gas_counts,
        "take_control": cmd.take_control,
    }


def battery_json(sample: ImuSample) -> Json:
    """``/battery``: the DebugOut's voltage."""
    return {"battery_v": _num(sample.battery_v)}


def phase_json(phase: str) -> Json:
    """``/phase``: the phase now (published with the state, for a viewer that joins late)."""
    return {"phase": phase, "change": False, "reason": ""}


def phase_change_json(event: PhaseEvent) -> Json:
    """``/phase`` for a phase change (the ``phase`` event of ``events.jsonl``)."""
    return {"phase": event.to_phase.name, "change": True, "reason": event.reason}


def failsafe_json(event: TransitionEvent) -> Json:
    """``/failsafe``: a cause raised or escalated (the ``failsafe`` event)."""
    return {
        "action": event.action.name,
        "cause": event.cause.value,
        "overall": event.overall.name,
        "detail": event.detail,
    }


def _schema(title: str, description: str, props: dict[str, str]) -> Json:
    """A JSON schema of an object whose properties are ``name: type``."""
    types = {"number": ["number", "null"], "integer": "integer", "boolean": "boolean"}
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {k: {"type": types.get(t, t)} for k, t in props.items()},
    }


SCHEMAS: Final[dict[str, Json]] = {
    topics.HEIGHT: _schema(
        "mkflight.Height",
        "estimated height above the floor (up) and its rate",
        {"height_m": "number", "vz_up_mps": "number", "valid": "boolean"},
    ),
    topics.ATTITUDE: _schema(
        "mkflight.Attitude",
        "the FlightCtrl's attitude (FRD: pitch nose up, roll right down, yaw clockwise)",
        {"pitch_rad": "number", "roll_rad": "number", "yaw_rad": "number"},
    ),
    topics.VELOCITY: _schema(
        "mkflight.Velocity",
        "velocity estimate in the world frame W (x forward, y right), vz up",
        {"vx_mps": "number", "vy_mps": "number", "vz_up_mps": "number", "valid": "boolean"},
    ),
    topics.COMMAND: _schema(
        "mkflight.Command",
        "the ExternControl sent, MK counts",
        {
            "nick_counts": "integer",
            "roll_counts": "integer",
            "yaw_counts": "integer",
            "gas_counts": "integer",
            "take_control": "boolean",
        },
    ),
    topics.BATTERY: _schema("mkflight.Battery", "battery voltage", {"battery_v": "number"}),
    topics.PHASE: _schema(
        "mkflight.Phase",
        "the flight phase; change: a phase change, with its reason",
        {"phase": "string", "change": "boolean", "reason": "string"},
    ),
    topics.FAILSAFE: _schema(
        "mkflight.Failsafe",
        "a failsafe cause raised or escalated (SPEC §5)",
        {"action": "string", "cause": "string", "overall": "string", "detail": "string"},
    ),
}
"""The JSON topics' schemas, by topic."""
