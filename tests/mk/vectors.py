r"""The byte vectors of ``protocols/mk-serial.md`` §9.1 (MK-01..MK-19) and §9.2 (MK-20..MK-24).

Source: ``../shared/protocols/mk-serial.md`` ("MikroKopter FlightCtrl serial protocol — as
mkflight uses it", reference firmware FlightCtrl V0.84a), §9 "Test vectors", tables §9.1
"Frames" and §9.2 "Byte streams". Copied by hand as Python literals so the suite stands alone on
a clone without the shared folder; the tests marked ``shared`` in ``test_codec.py`` re-read the
document's tables when it is there and check that every ``bytes`` literal and every ``fields``
call below equals the document's. Each record's
fields mirror the document's ``Kind(key=value, ...)`` call: the class is the kind, ``data``
the ``bytes`` column. Defaults are the document's ("0 where not given").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, TypeAlias


@dataclass(frozen=True, slots=True)
class FrameVector:
    """A bare frame: ``Frame(addr, cmd, payload)`` (payload before padding)."""

    id: str
    data: bytes
    addr: int
    cmd: str
    payload: bytes = b""


@dataclass(frozen=True, slots=True)
class VersionInfoVector:
    """``VersionInfo(...)``: the FC's 'V' answer."""

    id: str
    data: bytes
    addr: int
    sw_major: int
    sw_minor: int
    proto_major: int
    proto_minor: int
    sw_patch: int
    hardware_error: bytes


@dataclass(frozen=True, slots=True)
class DebugRequestVector:
    """``DebugRequest(addr, interval)``: the 'd' subscription."""

    id: str
    data: bytes
    addr: int
    interval: int


@dataclass(frozen=True, slots=True)
class DebugOutVector:
    """``DebugOut(addr, status, analog={index: value})``; unlisted values are 0."""

    id: str
    data: bytes
    addr: int
    status: tuple[int, int]
    analog: dict[int, int]


@dataclass(frozen=True, slots=True)
class ExternControlVector:
    """``ExternControl(...)`` in wire counts; digital/remote_buttons/free default to 0."""

    id: str
    data: bytes
    addr: int
    nick: int
    roll: int
    yaw: int
    gas: int
    height: int
    frame: int
    config: int
    digital: tuple[int, int] = (0, 0)
    remote_buttons: int = 0
    free: int = 0


@dataclass(frozen=True, slots=True)
class ConfirmVector:
    """``Confirm(addr, frame)``: the FC's 'B' answer."""

    id: str
    data: bytes
    addr: int
    frame: int


@dataclass(frozen=True, slots=True)
class PpmVector:
    """``PPM(addr, channels={channel: value})``; unlisted channels are 0."""

    id: str
    data: bytes
    addr: int
    channels: dict[int, int]


@dataclass(frozen=True, slots=True)
class LabelVector:
    """``Label(addr, index, label)``: the FC's 'A' answer."""

    id: str
    data: bytes
    addr: int
    index: int
    label: str


@dataclass(frozen=True, slots=True)
class StreamVector:
    """``Stream(...)``: bytes from the port, cut at ``split_at``, and what the client delivers.

    ``frames`` are ``(address, command, decoded payload as hex, padding included)``;
    ``fc_frames``/``fc_crc_errors`` (None when the document gives none) are what the FC's
    own receiver makes of the same bytes.
    """

    id: str
    data: bytes
    frames: tuple[tuple[int, str, str], ...]
    crc_errors: int
    discarded: int
    split_at: tuple[int, ...] = ()
    fc_frames: tuple[tuple[int, str, str], ...] | None = None
    fc_crc_errors: int | None = None


# --- §9.1 Frames -------------------------------------------------------------------------

MK_01: Final = FrameVector("MK-01", b"#bv@x\r", addr=1, cmd="v")
MK_02: Final = FrameVector("MK-02", b"#av@w\r", addr=0, cmd="v")
MK_03: Final = VersionInfoVector(
    "MK-03",
    b"#bV=BMH============PH\r",
    addr=1,
    sw_major=0,
    sw_minor=84,
    proto_major=11,
    proto_minor=0,
    sw_patch=0,
    hardware_error=b"\x00\x00\x00\x00\x00",
)
MK_04: Final = DebugRequestVector("MK-04", b"#bd>M==Dk\r", addr=1, interval=5)
MK_05: Final = DebugRequestVector("MK-05", b"#bd====DZ\r", addr=1, interval=0)
MK_06: Final = DebugRequestVector("MK-06", b"#ad====DY\r", addr=0, interval=0)
MK_07: Final = DebugOutVector(
    "MK-07",
    b"#bD=m?B\x7coq=rLxw=Ld\x7c[=@n\x7cv=>S]>s=I]=j==y=@q=L]=\x7c=================]"
    b"====================@\x7c\\m?=hm\r",
    addr=1,
    status=(3, 0),
    analog={
        0: -123,
        1: 45,
        2: -300,
        3: 250,
        4: -7,
        5: 120,
        6: -15,
        7: 400,
        8: 90,
        9: 118,
        10: 200,
        11: 180,
        12: 60,
        13: 61,
        14: 62,
        15: 63,
        21: 512,
        30: 32767,
        31: -32768,
    },
)
MK_08: Final = DebugOutVector(
    "MK-08",
    b"#bD=m@q\x7cny=y\x7cy^=Lt\x7c@]@{\x7c{=>==>s=I]=@mBs=De=[=>z==============>u"
    b"============================ge\r",
    addr=1,
    status=(3, 0),
    analog={
        0: -12,
        1: 31,
        2: -13,
        3: 33,
        4: -3,
        5: 14,
        6: -2,
        7: 480,
        8: 0,
        9: 118,
        10: 200,
        11: 271,
        12: 118,
        13: 122,
        14: 120,
        15: 125,
        21: 120,
    },
)
MK_09: Final = ExternControlVector(
    "MK-09",
    b"#bb====x=y=V===>mA=Ry\r",
    addr=1,
    nick=-20,
    roll=15,
    yaw=0,
    gas=100,
    height=0,
    frame=7,
    config=1,
)
MK_10: Final = ExternControlVector(
    "MK-10",
    b"#bb====GKYG]]==?=A=Qx\r",
    addr=1,
    nick=40,
    roll=-25,
    yaw=10,
    gas=130,
    height=0,
    frame=8,
    config=1,
)
MK_11: Final = ExternControlVector(
    "MK-11",
    b"#bb============?M==PF\r",
    addr=1,
    nick=0,
    roll=0,
    yaw=0,
    gas=0,
    height=0,
    frame=9,
    config=0,
)
MK_12: Final = ExternControlVector(
    "MK-12",
    b"#abRWf\x7c]D\x7c\x7c\x7cu==\x7cmA=XY\r",
    addr=0,
    digital=(85, 170),
    remote_buttons=127,
    nick=-128,
    roll=127,
    yaw=-1,
    gas=255,
    height=-128,
    free=0,
    frame=255,
    config=1,
)
MK_13: Final = ConfirmVector("MK-13", b"#bB>m==Di\r", addr=1, frame=7)
MK_14: Final = ConfirmVector("MK-14", b"#bB?M==DJ\r", addr=1, frame=9)
MK_15: Final = FrameVector("MK-15", b"#bp@r\r", addr=1, cmd="p")
MK_16: Final = PpmVector(
    "MK-16",
    b"#bP==>k=J\x60\x7cCM===D]=========================================================HU\r",
    addr=1,
    channels={1: 110, 2: -40, 3: 25, 5: 120},
)
MK_17: Final = FrameVector("MK-17", b"#ba====DW\r", addr=1, cmd="a", payload=b"\x00")
MK_18: Final = LabelVector(
    "MK-18", b"#bA=ABkVsnbPcb\x60Wo=]E?=]E?==^x\r", addr=1, index=0, label="AngleNick"
)
MK_19: Final = FrameVector(
    "MK-19",
    b"#dk^\\yj======A=Nx\r",
    addr=3,
    cmd="k",
    payload=b"\x85\xff\x2d\x00\x00\x00\x00\x01",
)

# --- §9.2 Byte streams -------------------------------------------------------------------

MK_20: Final = StreamVector(
    "MK-20", b"#bV=BMH============PI\r", frames=(), crc_errors=1, discarded=22
)
MK_21: Final = StreamVector(
    "MK-21",
    b"#bB>m==Di\r",
    split_at=(4,),
    frames=((1, "B", "070000"),),
    crc_errors=0,
    discarded=0,
)
MK_22: Final = StreamVector(
    "MK-22",
    b"\x00\xff\r\nAT+X\r#bB>m==Di\r",
    frames=((1, "B", "070000"),),
    crc_errors=0,
    discarded=9,
)
MK_23: Final = StreamVector(
    "MK-23",
    b"#bd>M#bB>m==Di\r",
    frames=((1, "B", "070000"),),
    crc_errors=0,
    discarded=5,
    fc_frames=(),
    fc_crc_errors=1,
)
MK_24: Final = StreamVector(
    "MK-24",
    b"#dk^\\yj======A=Nx\r#bB>m==Di\r",
    frames=((3, "k", "85ff2d000000000100"), (1, "B", "070000")),
    crc_errors=0,
    discarded=0,
)

# --- Groupings ---------------------------------------------------------------------------

FRAME_VECTORS: Final = (MK_01, MK_02, MK_15, MK_17, MK_19)
VERSION_VECTORS: Final = (MK_03,)
DEBUG_REQUEST_VECTORS: Final = (MK_04, MK_05, MK_06)
DEBUG_OUT_VECTORS: Final = (MK_07, MK_08)
EXTERN_CONTROL_VECTORS: Final = (MK_09, MK_10, MK_11, MK_12)
CONFIRM_VECTORS: Final = (MK_13, MK_14)
PPM_VECTORS: Final = (MK_16,)
LABEL_VECTORS: Final = (MK_18,)
STREAM_VECTORS: Final = (MK_20, MK_21, MK_22, MK_23, MK_24)

#: A §9.1 vector: one complete frame.
FrameLike: TypeAlias = (
    FrameVector
    | VersionInfoVector
    | DebugRequestVector
    | DebugOutVector
    | ExternControlVector
    | ConfirmVector
    | PpmVector
    | LabelVector
)
#: Any §9 vector.
Vector: TypeAlias = FrameLike | StreamVector

#: Every vector of §9.1 and §9.2 by id, in document order.
_EVERY: tuple[Vector, ...] = (
    *FRAME_VECTORS,
    *VERSION_VECTORS,
    *DEBUG_REQUEST_VECTORS,
    *DEBUG_OUT_VECTORS,
    *EXTERN_CONTROL_VECTORS,
    *CONFIRM_VECTORS,
    *PPM_VECTORS,
    *LABEL_VECTORS,
    *STREAM_VECTORS,
)
ALL_VECTORS: Final[dict[str, Vector]] = {v.id: v for v in sorted(_EVERY, key=lambda v: v.id)}

#: The §9.1 frame vectors (everything but the streams): each is one complete frame.
SINGLE_FRAME_VECTORS: Final[tuple[FrameLike, ...]] = tuple(
    v for v in ALL_VECTORS.values() if not isinstance(v, StreamVector)
)

#: The document's ``Kind`` name for each record class (the first word of ``fields``).
KIND_OF: Final[dict[str, type[Vector]]] = {
    "Frame": FrameVector,
    "VersionInfo": VersionInfoVector,
    "DebugRequest": DebugRequestVector,
    "DebugOut": DebugOutVector,
    "ExternControl": ExternControlVector,
    "Confirm": ConfirmVector,
    "PPM": PpmVector,
    "Label": LabelVector,
    "Stream": StreamVector,
}
