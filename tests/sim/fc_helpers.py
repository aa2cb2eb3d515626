"""Shared by the FC model tests: the mk-serial.md §9 vectors and a driver for the model."""

from __future__ import annotations

from collections.abc import Sequence

from mkflight.config import SimFcConfig
from mkflight.mk.codec import Frame, FrameParser
from mkflight.mk.messages import ExternControl
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_uart import wire_ns
from mkflight.sim.sources import FixedSource

# Vectors of mk-serial.md §9 (bytes literals copied from the tables).
MK_01 = b"#bv@x\r"
MK_02 = b"#av@w\r"
MK_03 = b"#bV=BMH============PH\r"
MK_04 = b"#bd>M==Dk\r"
MK_05 = b"#bd====DZ\r"
MK_07 = (
    b"#bD=m?B|oq=rLxw=Ld|[=@n|v=>S]>s=I]=j==y=@q=L]=|=================]"
    b"====================@|\\m?=hm\r"
)
MK_08 = (
    b"#bD=m@q|ny=y|y^=Lt|@]@{|{=>==>s=I]=@mBs=De=[=>z==============>u"
    b"============================ge\r"
)
MK_09 = b"#bb====x=y=V===>mA=Ry\r"
MK_11 = b"#bb============?M==PF\r"
MK_13 = b"#bB>m==Di\r"
MK_14 = b"#bB?M==DJ\r"
MK_15 = b"#bp@r\r"
MK_16 = b"#bP==>k=J`|CM===D]=========================================================HU\r"
MK_17 = b"#ba====DW\r"
MK_18 = b"#bA=ABkVsnbPcb`Wo=]E?=]E?==^x\r"
MK_19 = b"#dk^\\yj======A=Nx\r"
MK_23 = b"#bd>M#bB>m==Di\r"

MK07_VALUES = {0: -123, 1: 45, 2: -300, 3: 250, 4: -7, 5: 120, 6: -15, 7: 400, 8: 90, 9: 118}
MK07_VALUES |= {10: 200, 11: 180, 12: 60, 13: 61, 14: 62, 15: 63, 21: 512, 30: 32767}
MK07_VALUES |= {31: -32768}
MK08_VALUES = {0: -12, 1: 31, 2: -13, 3: 33, 4: -3, 5: 14, 6: -2, 7: 480, 8: 0, 9: 118}
MK08_VALUES |= {10: 200, 11: 271, 12: 118, 13: 122, 14: 120, 15: 125, 21: 120}
MK16_CHANNELS = {1: 110, 2: -40, 3: 25, 5: 120}

SETTINGS = SimFcConfig(mk3mag_frames=False, external_control=200)
T0 = 7_000_000_123  # boot time: deliberately not a multiple of anything
MS = 1_000_000
S = 1_000_000_000
D_WIRE_NS = wire_ns(94)  # a DebugOut on the wire (§1)
B_WIRE_NS = wire_ns(22)  # an ExternControl on the wire
MK04_WIRE_NS = wire_ns(len(MK_04))  # the 'd' 5 request on the wire


def make(settings: SimFcConfig = SETTINGS, values: dict[int, int] | None = None) -> FcModel:
    return FcModel(settings, FixedSource(values or {}), t_ns=T0)


def run(
    fc: FcModel, end_ns: int, inputs: Sequence[tuple[int, bytes]] = ()
) -> list[tuple[int, bytes]]:
    """Drive the model at its own event times and the input times only, as the server does.

    Returns each chunk with the time it was polled: its delivery time.
    """
    out: list[tuple[int, bytes]] = []
    todo = list(inputs)
    while True:
        t_event = fc.next_event_ns()
        t = min(x for x in (t_event, todo[0][0] if todo else None, end_ns) if x is not None)
        out += [(t, chunk) for chunk in fc.poll(t)]
        if todo and todo[0][0] == t:
            fc.receive(todo.pop(0)[1], t)
        elif t >= end_ns:
            return out


def frames(chunks: list[tuple[int, bytes]], parser: FrameParser | None = None) -> list[Frame]:
    parser = parser or FrameParser()
    return [f for _, chunk in chunks for f in parser.feed(chunk)]


def times_of(chunks: list[tuple[int, bytes]], cmd: str) -> list[int]:
    return [t for t, chunk in chunks if chunk[2:3] == cmd.encode()]


def extern(
    *, nick: int = 0, roll: int = 0, yaw: int = 0, gas: int = 0, frame: int = 0, config: int = 0
) -> bytes:
    return ExternControl(nick, roll, yaw, gas, frame=frame, config=config).encode()
