"""The MikroKopter messages mkflight uses: pure encoders and decoders (``mk-serial.md`` §4-6).

Each message is a frozen record with ``encode()`` (bytes of a complete frame) and, for
answers, ``decode(frame)``. Outgoing fields are range-checked and never wrapped: a
negative gas wrapped into an unsigned byte sends the vehicle up at full power (§K of the
2011 QUT CyPhy MikroKopter documentation), so :meth:`ExternControl.pack` raises instead.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import ClassVar, Final

from mkflight.errors import CommandRangeError, ProtocolError
from mkflight.mk.codec import ADDR_FC, Frame, encode_frame

# Request and answer command characters (§4).
CMD_VERSION: Final = "v"
CMD_VERSION_ANSWER: Final = "V"
CMD_DEBUG: Final = "d"
CMD_DEBUG_ANSWER: Final = "D"
CMD_EXTERN: Final = "b"
CMD_CONFIRM: Final = "B"
CMD_PPM: Final = "p"
CMD_PPM_ANSWER: Final = "P"
CMD_LABEL: Final = "a"
CMD_LABEL_ANSWER: Final = "A"

# Commands a client must never send (§4): reset, motor test, default settings, write settings.
FORBIDDEN_COMMANDS: Final = frozenset({"R", "t", "q", "s"})

# DebugOut Analog[] indexes used by mkflight (FC 0.84a labels, §6.1).
ANALOG_ANGLE_NICK: Final = 0
ANALOG_ANGLE_ROLL: Final = 1
ANALOG_ACC_NICK: Final = 2
ANALOG_ACC_ROLL: Final = 3
ANALOG_YAW_GYRO: Final = 4
ANALOG_HEIGHT: Final = 5
ANALOG_ACC_Z: Final = 6
ANALOG_GAS: Final = 7
ANALOG_COMPASS: Final = 8
ANALOG_VOLTAGE: Final = 9
ANALOG_RECEIVER_LEVEL: Final = 10
ANALOG_GYRO_COMPASS: Final = 11
ANALOG_MOTOR_1: Final = 12
ANALOG_HOVERGAS: Final = 21
ANALOG_CURRENT: Final = 22
ANALOG_CAPACITY: Final = 23
ANALOG_I2C_ERROR: Final = 28
ANALOG_BL_LIMIT: Final = 29
ANALOG_COUNT: Final = 32

#: FC 0.84a labels of the 32 DebugOut values (answers to 'a', §6.1).
ANALOG_LABELS_084A: Final[tuple[str, ...]] = (
    "AngleNick",
    "AngleRoll",
    "AccNick",
    "AccRoll",
    "YawGyro",
    "Height Value",
    "AccZ",
    "Gas",
    "Compass Value",
    "Voltage [0.1V]",
    "Receiver Level",
    "Gyro Compass",
    "Motor 1",
    "Motor 2",
    "Motor 3",
    "Motor 4",
    "16",
    "17",
    "18",
    "19",
    "Servo",
    "Hovergas",
    "Current [0.1A]",
    "Capacity [mAh]",
    "Hight Setpoint",
    "25",
    "26",
    "Compass Setpoint",
    "I2C-Error",
    "BL Limit",
    "GPS_Nick",
    "GPS_Roll",
)

_S16 = struct.Struct("<32h")


def _payload(frame: Frame, size: int, what: str) -> bytes:
    """Return the first ``size`` decoded bytes of ``frame`` or raise if it is too short."""
    if len(frame.payload) < size:
        msg = f"{what} frame carries {len(frame.payload)} bytes, needs {size}"
        raise ProtocolError(msg)
    return frame.payload[:size]


def request(cmd: str, payload: bytes = b"", addr: int = ADDR_FC) -> bytes:
    """Encode a request frame to the FC, refusing the commands a client must never send."""
    if cmd in FORBIDDEN_COMMANDS:
        msg = f"refusing to send {cmd!r}: it resets, spins motors or rewrites FC settings"
        raise ProtocolError(msg)
    return encode_frame(addr, cmd, payload)


def version_request(addr: int = ADDR_FC) -> bytes:
    """The 'v' request (vector MK-01)."""
    return request(CMD_VERSION, b"", addr)


def debug_request(interval_10ms: int, addr: int = ADDR_FC) -> bytes:
    """The 'd' subscription: period ``10*interval`` FC ticks, 0 stops (vectors MK-04..06)."""
    if not 0 <= interval_10ms <= 255:
        msg = f"debug interval {interval_10ms} outside 0..255"
        raise CommandRangeError(msg)
    return request(CMD_DEBUG, bytes((interval_10ms,)), addr)


def ppm_request() -> bytes:
    """The 'p' stick request; the FC answers it only on its own address (MK-15)."""
    return request(CMD_PPM, b"", ADDR_FC)


def label_request(index: int, addr: int = ADDR_FC) -> bytes:
    """The 'a' request for the label of DebugOut value ``index`` (MK-17)."""
    if not 0 <= index < ANALOG_COUNT:
        msg = f"label index {index} outside 0..31"
        raise CommandRangeError(msg)
    return request(CMD_LABEL, bytes((index,)), addr)


@dataclass(frozen=True, slots=True)
class VersionInfo:
    """The FC's 'V' answer (§5.1): bytes 0-4 decoded, the version-specific tail kept raw."""

    sw_major: int
    sw_minor: int
    proto_major: int
    proto_minor: int
    sw_patch: int
    hardware_error: bytes = bytes(5)
    addr: int = ADDR_FC

    SIZE: ClassVar[int] = 10

    @property
    def text(self) -> str:
        """The version as the MK tools print it, e.g. ``0.84a``."""
        return f"{self.sw_major}.{self.sw_minor:02d}{chr(ord('a') + self.sw_patch)}"

    @property
    def has_hardware_error(self) -> bool:
        """True if any HardwareError byte is set (fails the pre-flight checks)."""
        return any(self.hardware_error)

    @classmethod
    def decode(cls, frame: Frame) -> VersionInfo:
        """Decode a 'V' frame."""
        p = _payload(frame, cls.SIZE, "VersionInfo")
        return cls(p[0], p[1], p[2], p[3], p[4], bytes(p[5:10]), frame.addr)

    def encode(self) -> bytes:
        """Encode as the FC sends it (vector MK-03)."""
        head = bytes((self.sw_major, self.sw_minor, self.proto_major, self.proto_minor))
        tail = bytes((self.sw_patch,)) + self.hardware_error.ljust(5, b"\0")[:5]
        return encode_frame(self.addr, CMD_VERSION_ANSWER, head + tail)


@dataclass(frozen=True, slots=True)
class DebugOut:
    """The FC's 'D' answer (§6): two status bytes and 32 signed 16-bit analog values."""

    status: tuple[int, int]
    analog: tuple[int, ...]
    addr: int = ADDR_FC

    SIZE: ClassVar[int] = 66

    @classmethod
    def from_values(
        cls, values: dict[int, int], status: tuple[int, int] = (3, 0), addr: int = ADDR_FC
    ) -> DebugOut:
        """Build a DebugOut from ``{index: value}``, every other value 0."""
        analog = [0] * ANALOG_COUNT
        for i, v in values.items():
            analog[i] = v
        return cls(status=status, analog=tuple(analog), addr=addr)

    @classmethod
    def decode(cls, frame: Frame) -> DebugOut:
        """Decode a 'D' frame."""
        p = frame.payload
        if len(p) < cls.SIZE:
            _payload(frame, cls.SIZE, "DebugOut")  # raises, saying why
        return cls((p[0], p[1]), _S16.unpack_from(p, 2), frame.addr)

    @staticmethod
    def analog_of(frame: Frame) -> tuple[int, ...]:
        """Only the 32 analog values of a 'D' frame: what each step needs of it.

        Raises:
            ProtocolError: the frame is too short for a DebugOut.
        """
        p = frame.payload
        if len(p) < DebugOut.SIZE:
            _payload(frame, DebugOut.SIZE, "DebugOut")  # raises, saying why
        return _S16.unpack_from(p, 2)

    def encode(self) -> bytes:
        """Encode as the FC sends it (vectors MK-07, MK-08); values must fit int16."""
        if len(self.analog) != ANALOG_COUNT:
            msg = f"DebugOut needs {ANALOG_COUNT} analog values, got {len(self.analog)}"
            raise CommandRangeError(msg)
        try:
            body = bytes(self.status) + _S16.pack(*self.analog)
        except (struct.error, ValueError) as err:
            msg = f"DebugOut value out of range: {err}"
            raise CommandRangeError(msg) from err
        return encode_frame(self.addr, CMD_DEBUG_ANSWER, body)

    def labelled(self, labels: tuple[str, ...] = ANALOG_LABELS_084A) -> dict[str, int]:
        """The analog values keyed by their FC labels."""
        return dict(zip(labels, self.analog, strict=True))


# Wire ranges of the ExternControl fields (§5.2): name -> (min, max).
_EC_RANGES: Final[dict[str, tuple[int, int]]] = {
    "digital0": (0, 255),
    "digital1": (0, 255),
    "remote_buttons": (0, 255),
    "nick": (-128, 127),
    "roll": (-128, 127),
    "yaw": (-128, 127),
    "gas": (0, 255),
    "height": (-128, 127),
    "free": (0, 255),
    "frame": (0, 255),
    "config": (0, 255),
}
_EC_STRUCT = struct.Struct("<BBBbbbBbBBB")  # the byte ranges of _EC_RANGES, in field order
_INT_ONLY: Final = {int}

EC_VALID: Final = 0x01  # Config bit 0: take control
EXTERN_FRAME_OFFSET: Final = 9  # the Frame byte inside the 11-byte payload
EXTERN_CONFIG_OFFSET: Final = 10  # the Config byte inside the 11-byte payload


def pack_sticks(nick: int, roll: int, yaw: int, gas: int, frame: int, config: int) -> bytes:
    """The payload of an ExternControl with these fields (the rest 0), without building it.

    ``ExternControl(nick=nick, roll=roll, yaw=yaw, gas=gas, frame=frame,
    config=config).pack()``, for the flight's path (one a step). For ints already checked
    against their wire ranges (as the link checks its stricter limits); anything else
    raises ``struct.error``, which names no field: :meth:`ExternControl.pack` is the
    checking path.
    """
    return _EC_STRUCT.pack(0, 0, 0, nick, roll, yaw, gas, 0, 0, frame, config)


def _wire_int(name: str, value: object) -> int:
    """Check one outgoing field: an integral, finite number inside its wire range."""
    lo, hi = _EC_RANGES[name]
    if type(value) is int and lo <= value <= hi:  # the common case, checked first
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        msg = f"ExternControl.{name} must be a number, got {value!r}"
        raise CommandRangeError(msg)
    if isinstance(value, float):
        if not math.isfinite(value) or not value.is_integer():
            msg = f"ExternControl.{name} must be a finite whole number, got {value!r}"
            raise CommandRangeError(msg)
        value = int(value)
    if not lo <= value <= hi:
        msg = f"ExternControl.{name} = {value} outside {lo}..{hi}; refusing to wrap it"
        raise CommandRangeError(msg)
    return value


@dataclass(frozen=True, slots=True)
class ExternControl:
    """The 'b' command (§5.2), in MK counts exactly as they go on the wire.

    nick/roll/yaw/height are signed bytes, gas and the rest unsigned. ``frame`` != 0 asks
    for a 'B' confirm; ``config`` bit 0 takes control and 0 hands it back to the pilot.
    Signs (SPEC §1): + nick = nose down / fly forward, + roll = left side down / fly left.
    """

    nick: int | float = 0
    roll: int | float = 0
    yaw: int | float = 0
    gas: int | float = 0
    height: int | float = 0
    frame: int | float = 0
    config: int | float = 0
    digital: tuple[int, int] = (0, 0)
    remote_buttons: int | float = 0
    free: int | float = 0
    addr: int = ADDR_FC

    SIZE: ClassVar[int] = 11

    @classmethod
    def neutral(cls, frame: int = 0) -> ExternControl:
        """Neutral sticks, gas 0, Config 0: the handshake and release frame (MK-11)."""
        return cls(frame=frame)

    @property
    def takes_control(self) -> bool:
        """True if Config bit 0 is set."""
        return bool(_wire_int("config", self.config) & EC_VALID)

    def pack(self) -> bytes:
        """Pack the 11 payload bytes; raise :class:`CommandRangeError` rather than wrap.

        Every field must be a finite whole number inside its wire range; NaN, inf, 127.5,
        -1 gas or 128 nick all raise, naming the field.
        """
        digital = self.digital
        if len(digital) != 2:
            msg = f"ExternControl.digital needs 2 values, got {len(digital)}"
            raise CommandRangeError(msg)
        values = (
            digital[0],
            digital[1],
            self.remote_buttons,
            self.nick,
            self.roll,
            self.yaw,
            self.gas,
            self.height,
            self.free,
            self.frame,
            self.config,
        )
        if set(map(type, values)) == _INT_ONLY:
            # The common case in one pass: ints only, and struct's own range check is
            # _EC_RANGES (the format's byte ranges); anything else gets the field's name.
            try:
                return _EC_STRUCT.pack(*values)
            except struct.error:
                pass  # out of range: the checks below name the field
        return _EC_STRUCT.pack(
            _wire_int("digital0", self.digital[0]),
            _wire_int("digital1", self.digital[1]),
            _wire_int("remote_buttons", self.remote_buttons),
            _wire_int("nick", self.nick),
            _wire_int("roll", self.roll),
            _wire_int("yaw", self.yaw),
            _wire_int("gas", self.gas),
            _wire_int("height", self.height),
            _wire_int("free", self.free),
            _wire_int("frame", self.frame),
            _wire_int("config", self.config),
        )

    def encode(self) -> bytes:
        """Encode the complete 'b' frame (vectors MK-09..12)."""
        return encode_frame(self.addr, CMD_EXTERN, self.pack())

    @classmethod
    def decode(cls, frame: Frame) -> ExternControl:
        """Decode a 'b' frame (what the FC, or the emulator, receives)."""
        p = _payload(frame, cls.SIZE, "ExternControl")
        d0, d1, rb, nick, roll, yaw, gas, height, free, fr, cfg = _EC_STRUCT.unpack(p)
        return cls(nick, roll, yaw, gas, height, fr, cfg, (d0, d1), rb, free, frame.addr)


@dataclass(frozen=True, slots=True)
class Confirm:
    """The FC's 'B' answer to a 'b' with Frame != 0 (§5.3)."""

    frame: int
    addr: int = ADDR_FC

    @classmethod
    def decode(cls, frame: Frame) -> Confirm:
        """Decode a 'B' frame."""
        return cls(frame=_payload(frame, 1, "Confirm")[0], addr=frame.addr)

    def encode(self) -> bytes:
        """Encode as the FC sends it (vectors MK-13, MK-14)."""
        return encode_frame(self.addr, CMD_CONFIRM, bytes((_wire_int("frame", self.frame),)))


@dataclass(frozen=True, slots=True)
class Ppm:
    """The FC's 'P' answer (§5.4): ``PPM_in[0..25]``, receiver channels 1..25 around 0."""

    channels: tuple[int, ...] = field(default=(0,) * 26)
    addr: int = ADDR_FC

    SIZE: ClassVar[int] = 52
    _STRUCT: ClassVar[struct.Struct] = struct.Struct("<26h")

    @classmethod
    def from_channels(cls, channels: dict[int, int], addr: int = ADDR_FC) -> Ppm:
        """Build from ``{channel: value}``, every other channel 0."""
        values = [0] * 26
        for i, v in channels.items():
            values[i] = v
        return cls(tuple(values), addr)

    @classmethod
    def decode(cls, frame: Frame) -> Ppm:
        """Decode a 'P' frame."""
        p = _payload(frame, cls.SIZE, "PPM")
        return cls(cls._STRUCT.unpack(p), frame.addr)

    def encode(self) -> bytes:
        """Encode as the FC sends it (vector MK-16)."""
        try:
            body = self._STRUCT.pack(*self.channels)
        except struct.error as err:
            msg = f"PPM channel out of range: {err}"
            raise CommandRangeError(msg) from err
        return encode_frame(self.addr, CMD_PPM_ANSWER, body)


@dataclass(frozen=True, slots=True)
class Label:
    """The FC's 'A' answer (§4): the 16-character label of one DebugOut value."""

    index: int
    label: str
    addr: int = ADDR_FC

    @classmethod
    def decode(cls, frame: Frame) -> Label:
        """Decode an 'A' frame; the label is NUL/space padded ASCII."""
        p = _payload(frame, 17, "Label")
        text = p[1:17].split(b"\0", 1)[0].decode("ascii", "replace").rstrip()
        return cls(p[0], text, frame.addr)

    def encode(self) -> bytes:
        """Encode as the FC sends it (vector MK-18): the label padded to 16 with spaces."""
        raw = self.label.encode("ascii")[:16].ljust(16, b" ")
        return encode_frame(self.addr, CMD_LABEL_ANSWER, bytes((self.index,)) + raw)
