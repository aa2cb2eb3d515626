"""A small Foxglove WebSocket client: what the live view's tests and benchmark watch with.

It speaks the server side's protocol (subprotocol ``foxglove.sdk.v1``, the Foxglove
WebSocket protocol): the server's JSON ``serverInfo`` and ``advertise`` come first; the
client sends ``subscribe`` with one id of its own per channel; each message then comes
as a binary frame ``0x01, subscription id (u32), log time (u64 ns), payload``, little
endian. A JSON channel's payload is JSON; a Foxglove schema's (``foxglove.LaserScan``)
is protobuf, which :func:`protobuf_fields` reads without a protobuf library.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

from mkflight.conversions import NS_PER_S

if TYPE_CHECKING:
    from collections.abc import Iterable

    from websockets.asyncio.client import ClientConnection

SUBPROTOCOL: Final = "foxglove.sdk.v1"
MESSAGE_DATA: Final = 0x01
_HEADER = struct.Struct("<BIQ")

#: A protobuf message's top-level fields by number, each a list of its raw values.
Fields = dict[int, list[int | float | bytes]]


@dataclass(frozen=True, slots=True)
class Message:
    """One received message: its topic, log time and payload."""

    topic: str
    log_time_ns: int
    payload: bytes

    def json(self) -> Any:
        """The payload of a JSON channel."""
        return json.loads(self.payload)


@dataclass(slots=True)
class Subscriptions:
    """The advertised channels by topic, and which subscription id is which topic."""

    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    topic_of: dict[int, str] = field(default_factory=dict)

    def advertised(self, text: str | bytes) -> bool:
        """Take a text frame; True if it advertised channels."""
        op = json.loads(text)
        if op.get("op") != "advertise":
            return False
        for ch in op["channels"]:
            self.channels[ch["topic"]] = ch
        return True

    def subscribe_op(self, topics: Iterable[str]) -> str:
        """The ``subscribe`` op for ``topics`` (ids 1, 2, ... in order of subscription)."""
        subs = []
        for topic in topics:
            sub_id = len(self.topic_of) + 1
            self.topic_of[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        return json.dumps({"op": "subscribe", "subscriptions": subs})

    def message(self, frame: bytes) -> Message | None:
        """A binary message-data frame as a :class:`Message` (None: another opcode)."""
        if len(frame) < _HEADER.size or frame[0] != MESSAGE_DATA:
            return None
        _, sub_id, log_time = _HEADER.unpack_from(frame)
        return Message(self.topic_of[sub_id], log_time, frame[_HEADER.size :])


async def subscribe(ws: ClientConnection, topics: Iterable[str] | None = None) -> Subscriptions:
    """Read frames until the channels are advertised; subscribe to ``topics`` (None: all).

    Raises:
        KeyError: a topic that is not advertised.
    """
    subs = Subscriptions()
    while not subs.channels:
        frame = await ws.recv()
        if isinstance(frame, str):
            subs.advertised(frame)
    await ws.send(subs.subscribe_op(list(subs.channels) if topics is None else topics))
    return subs


def _varint(data: bytes, i: int) -> tuple[int, int]:
    """A protobuf varint at ``data[i]``; the value and the next index."""
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, i


def protobuf_fields(data: bytes) -> Fields:
    """The top-level fields of a protobuf message by number, each a list of raw values.

    Varints are ints, 64-bit fields doubles, 32-bit ones floats, length-delimited ones
    bytes (a nested message, a string, or a packed repeated field: :func:`packed_doubles`).
    """
    out: Fields = {}
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        value: int | float | bytes
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 1:
            (value,) = struct.unpack_from("<d", data, i)
            i += 8
        elif wire == 5:
            (value,) = struct.unpack_from("<f", data, i)
            i += 4
        elif wire == 2:
            n, i = _varint(data, i)
            value, i = data[i : i + n], i + n
        else:
            msg = f"protobuf wire type {wire} not supported"
            raise ValueError(msg)
        out.setdefault(number, []).append(value)
    return out


def packed_doubles(data: bytes) -> list[float]:
    """A packed ``repeated double`` field's values."""
    return list(struct.unpack(f"<{len(data) // 8}d", data))


@dataclass(frozen=True, slots=True)
class DecodedScan:
    """A ``foxglove.LaserScan``'s fields.

    ``foxglove/LaserScan.proto``: 1 timestamp, 2 frame_id, 3 pose, 4 start_angle,
    5 end_angle, 6 ranges, 7 intensities.
    """

    stamp_ns: int
    frame_id: str
    start_angle: float
    end_angle: float
    ranges: list[float]


def _bytes(fields: Fields, number: int) -> bytes:
    """Field ``number``'s first value as bytes (b"": absent)."""
    value = fields.get(number, [b""])[0]
    return value if isinstance(value, bytes) else b""


def _number(fields: Fields, number: int) -> float:
    """Field ``number``'s first value as a number (0: absent)."""
    value = fields.get(number, [0])[0]
    return 0.0 if isinstance(value, bytes) else value


def decode_laser_scan(payload: bytes) -> DecodedScan:
    """A ``foxglove.LaserScan`` payload, decoded."""
    f = protobuf_fields(payload)
    ts = protobuf_fields(_bytes(f, 1))  # google.protobuf.Timestamp: 1 seconds, 2 nanos
    ranges: list[float] = []
    for chunk in f.get(6, []):
        ranges += packed_doubles(chunk) if isinstance(chunk, bytes) else [float(chunk)]
    return DecodedScan(
        stamp_ns=int(_number(ts, 1)) * NS_PER_S + int(_number(ts, 2)),
        frame_id=_bytes(f, 2).decode(),
        start_angle=float(_number(f, 4)),
        end_angle=float(_number(f, 5)),
        ranges=ranges,
    )


def numbers(data: bytes, count: int) -> tuple[float, ...]:
    """Fields 1..``count`` of a message of doubles (a Vector3, a Quaternion); absent: 0."""
    f = protobuf_fields(data)
    return tuple(float(_number(f, k)) for k in range(1, count + 1))


@dataclass(frozen=True, slots=True)
class DecodedPose:
    """A ``foxglove.PoseInFrame``: 1 timestamp, 2 frame_id, 3 pose (1 position, 2 orientation)."""

    stamp_ns: int
    frame_id: str
    position: tuple[float, ...]  #: x, y, z
    orientation: tuple[float, ...]  #: x, y, z, w


def decode_pose_in_frame(payload: bytes) -> DecodedPose:
    """A ``foxglove.PoseInFrame`` payload, decoded."""
    f = protobuf_fields(payload)
    ts = protobuf_fields(_bytes(f, 1))
    pose = protobuf_fields(_bytes(f, 3))
    return DecodedPose(
        stamp_ns=int(_number(ts, 1)) * NS_PER_S + int(_number(ts, 2)),
        frame_id=_bytes(f, 2).decode(),
        position=numbers(_bytes(pose, 1), 3),
        orientation=numbers(_bytes(pose, 2), 4),
    )
