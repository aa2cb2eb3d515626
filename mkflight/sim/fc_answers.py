"""What the emulated FlightCtrl puts in its frames (``mk-serial.md`` §5-7).

Pure builders used by :class:`mkflight.sim.fc.FcModel`: the VersionInfo of a configured
version, the DebugOut filled from an analog source, and the attitude frame the FC sends
to the MK3MAG compass. When, and in which order, they are sent is the model's business.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Mapping
from typing import Final

from mkflight.errors import ConfigError
from mkflight.mk.codec import ADDR_MK3MAG, encode_frame
from mkflight.mk.messages import (
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_COUNT,
    ANALOG_GAS,
    ANALOG_RECEIVER_LEVEL,
    ANALOG_VOLTAGE,
    DebugOut,
    VersionInfo,
)
from mkflight.sim.fc_control import INT16_MAX, INT16_MIN

PROTO_VERSION: Final = (11, 0)  # ProtoMajor/Minor of 0.84a (§5.1)
DEFAULT_STATUS: Final = (3, 0)  # DebugOut Status after boot (§6)
MK3MAG_ORIENTATION: Final = 1  # last byte of the '#dk' payload (MK-19)
_MK3MAG = struct.Struct("<hhBBBB")  # nick, roll (0.1°), 2 user parameters, cal state, orientation
_VERSION_RE = re.compile(r"(\d+)\.(\d+)([a-z]?)")


def parse_version(text: str) -> VersionInfo:
    """The VersionInfo an FC of version ``text`` (e.g. ``0.84a``) answers (§5.1).

    Raises:
        ConfigError: ``text`` is not ``MAJOR.MINOR[patch letter]``.
    """
    match = _VERSION_RE.fullmatch(text)
    if match is None or int(match[1]) > 255 or int(match[2]) > 255:
        msg = f"sim.fc.version: {text!r} is not a FlightCtrl version like '0.84a'"
        raise ConfigError(msg)
    patch = ord(match[3]) - ord("a") if match[3] else 0
    return VersionInfo(int(match[1]), int(match[2]), *PROTO_VERSION, sw_patch=patch)


def saturate(value: int) -> int:
    """Clamp to int16, as the FC's own variables saturate."""
    return max(INT16_MIN, min(INT16_MAX, int(value)))


def build_debug_out(
    values: Mapping[int, int],
    *,
    gas: int,
    battery_v: float,
    receiver_level: int,
    status: tuple[int, int] = DEFAULT_STATUS,
) -> DebugOut:
    """A DebugOut (§6): Gas x4, Voltage and Receiver Level filled in, ``values`` win.

    Raises:
        ValueError: ``values`` has an index outside 0..31 (a broken source).
    """
    analog = [0] * ANALOG_COUNT
    analog[ANALOG_GAS] = 4 * gas
    analog[ANALOG_VOLTAGE] = round(battery_v * 10)
    analog[ANALOG_RECEIVER_LEVEL] = receiver_level
    for index, value in values.items():
        if not 0 <= index < ANALOG_COUNT:
            msg = f"analog source gave index {index}, outside 0..{ANALOG_COUNT - 1}"
            raise ValueError(msg)
        analog[index] = saturate(value)
    return DebugOut(status=status, analog=tuple(analog))


def mk3mag_frame(values: Mapping[int, int]) -> bytes:
    """The FC → compass attitude frame ``#dk`` (§7.6, MK-19) from AngleNick/AngleRoll."""
    nick = saturate(values.get(ANALOG_ANGLE_NICK, 0))
    roll = saturate(values.get(ANALOG_ANGLE_ROLL, 0))
    return encode_frame(ADDR_MK3MAG, "k", _MK3MAG.pack(nick, roll, 0, 0, 0, MK3MAG_ORIENTATION))
