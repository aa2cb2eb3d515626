# ruff: noqa: E501  (the literals are copied whole from the document, one per line)
r"""The byte vectors of ``protocols/scip2.md`` §7.1 (SC-C1..SC-C10) and §7.2 (SC-01..SC-21).

Source: ``../shared/protocols/scip2.md`` ("Hokuyo SCIP 2.0 for the URG-04LX — as mkflight uses
it"), §7 "Test vectors", tables §7.1 "Codec" and §7.2 "Exchanges". Copied as Python literals so
the suite stands alone on a clone without the shared folder; the tests marked ``shared`` in
``test_codec.py`` re-read the document's tables when it is there and check that every bytes
literal and every ``fields`` call below equals the document's. Each record mirrors the
document's ``Kind(key=value, ...)``: the class is the kind, ``data`` (codec) or ``command`` and
``reply`` (exchanges) the bytes columns. Defaults are the document's: an exchange starts
in SCIP 2.0 with the laser off, the timer at 0, the command sent at step 0 of a scan
(``at_ms=0``), 1000 mm at every step not in ``ranges``, and no time running afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, TypeAlias


@dataclass(frozen=True, slots=True)
class EncodeVector:
    """``Encode(value, chars)``: a number in ``chars`` SCIP characters (§2.4)."""

    id: str
    data: bytes
    value: int
    chars: int


@dataclass(frozen=True, slots=True)
class SumVector:
    """``Sum(text)``: the sum character of a line (§2.3)."""

    id: str
    data: bytes
    text: bytes


@dataclass(frozen=True, slots=True)
class TimestampVector:
    """``Timestamp(ms)``: 4 timestamp characters and their sum (§3.3)."""

    id: str
    data: bytes
    ms: int


@dataclass(frozen=True, slots=True)
class ExchangeVector:
    """``Exchange(...)``: the emulator set-up, then what the reply decodes to (§7)."""

    id: str
    command: bytes
    reply: bytes
    scip1: bool = False
    laser_on: bool = False
    timer_ms: int = 0
    at_ms: int = 0
    ranges: dict[int, int] = field(default_factory=dict)
    wait_ms: int = 0
    status: str = ""
    info: dict[str, str] = field(default_factory=dict)
    timestamp: int | None = None
    values: list[int] | None = None
    scans: list[tuple[str, int, list[int]]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class CorruptVector:
    """``Corrupt(of, line)``: vector ``of`` with reply line ``line`` (1-based) damaged."""

    id: str
    command: bytes
    reply: bytes
    of: str
    line: int


Vector: TypeAlias = EncodeVector | SumVector | TimestampVector | ExchangeVector | CorruptVector

KIND_OF: Final[dict[str, type[Vector]]] = {
    "Encode": EncodeVector,
    "Sum": SumVector,
    "Timestamp": TimestampVector,
    "Exchange": ExchangeVector,
    "Corrupt": CorruptVector,
}

VECTORS: Final[tuple[Vector, ...]] = (
    EncodeVector(id="SC-C1", data=b"CB", value=1234, chars=2),
    EncodeVector(id="SC-C2", data=b"1Dh", value=5432, chars=3),
    EncodeVector(id="SC-C3", data=b"m2@0", value=16000000, chars=4),
    EncodeVector(id="SC-C4", data=b"00D", value=20, chars=3),
    SumVector(id="SC-C5", data=b"P", text=b"00"),
    SumVector(id="SC-C6", data=b"b", text=b"99"),
    SumVector(id="SC-C7", data=b"4", text=b"DMIN:20"),
    TimestampVector(id="SC-C8", data=b"JUGnD", ms=6968830),
    TimestampVector(id="SC-C9", data=b"ooool", ms=16777215),
    TimestampVector(id="SC-C10", data=b"00000", ms=0),
    ExchangeVector(id="SC-01", command=b"SCIP2.0\n", reply=b"SCIP2.0\n0\n\n", scip1=True),
    ExchangeVector(id="SC-02", command=b"SCIP2.0\n", reply=b"SCIP2.0\n0Ee\n\n", status="0E"),
    ExchangeVector(
        id="SC-03",
        command=b"VV\n",
        reply=b"VV\n00P\nVEND:Hokuyo Automatic Co.,Ltd.;[\nPROD:SOKUIKI Sensor URG-04LX;[\nFIRM:3.1.04(02/Aug./2007);a\nPROT:SCIP 2.0;N\nSERI:H0706400;F\n\n",
        status="00",
        info={"PROT": "SCIP 2.0", "SERI": "H0706400"},
    ),
    ExchangeVector(
        id="SC-04",
        command=b"PP\n",
        reply=b"PP\n00P\nMODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\nDMIN:20;4\nDMAX:5600;_\nARES:1024;\\\nAMIN:44;7\nAMAX:725;o\nAFRT:384;6\nSCAN:600;e\n\n",
        status="00",
        info={
            "DMIN": "20",
            "DMAX": "5600",
            "ARES": "1024",
            "AMIN": "44",
            "AMAX": "725",
            "AFRT": "384",
            "SCAN": "600",
        },
    ),
    ExchangeVector(
        id="SC-05",
        command=b"II\n",
        reply=b"II\n00P\nMODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\nLASR:ON;9\nSCSP:Initial(600[rpm])<-Default setting by user;A\nMESM:CLASSIC;^\nSBPS:19200[bps]<-Default setting by user;A\nTIME:6A55F8;8\nSTAT:Sensor works well.;8\n\n",
        laser_on=True,
        timer_ms=6968824,
        status="00",
        info={"LASR": "ON", "TIME": "6A55F8"},
    ),
    ExchangeVector(id="SC-06", command=b"BM\n", reply=b"BM\n00P\n\n", status="00"),
    ExchangeVector(id="SC-07", command=b"BM\n", reply=b"BM\n02R\n\n", laser_on=True, status="02"),
    ExchangeVector(id="SC-08", command=b"QT\n", reply=b"QT\n00P\n\n", laser_on=True, status="00"),
    ExchangeVector(id="SC-09", command=b"RS\n", reply=b"RS\n00P\n\n", laser_on=True, status="00"),
    ExchangeVector(
        id="SC-10", command=b"GD0044072501\n", reply=b"GD0044072501\n10Q\n\n", status="10"
    ),
    ExchangeVector(
        id="SC-11",
        command=b"GD0384038601\n",
        reply=b"GD0384038601\n00P\nJUGnD\n1Dh00C000@\n\n",
        laser_on=True,
        timer_ms=6968830,
        ranges={384: 5432, 385: 19, 386: 6000},
        wait_ms=100,
        status="00",
        timestamp=6968830,
        values=[5432, 19, 0],
    ),
    ExchangeVector(
        id="SC-12",
        command=b"GD0380040301\n",
        reply=b"GD0380040301\n00P\n3d900\n00D00C0000070CB1Dh1GP0000oo1000?X0?Y0?Z0?[0?\\0?]0?^0?_0?\x600?a0?b0[\n?c0?d0?e9\n\n",
        laser_on=True,
        timer_ms=1000000,
        ranges={
            380: 20,
            381: 19,
            382: 0,
            383: 7,
            384: 1234,
            385: 5432,
            386: 5600,
            387: 5601,
            388: 4095,
            389: 4096,
            390: 1000,
            391: 1001,
            392: 1002,
            393: 1003,
            394: 1004,
            395: 1005,
            396: 1006,
            397: 1007,
            398: 1008,
            399: 1009,
            400: 1010,
            401: 1011,
            402: 1012,
            403: 1013,
        },
        wait_ms=100,
        status="00",
        timestamp=1000000,
        values=[
            20,
            19,
            0,
            7,
            1234,
            5432,
            5600,
            0,
            4095,
            4096,
            1000,
            1001,
            1002,
            1003,
            1004,
            1005,
            1006,
            1007,
            1008,
            1009,
            1010,
            1011,
            1012,
            1013,
        ],
    ),
    ExchangeVector(
        id="SC-13",
        command=b"GS0380040301\n",
        reply=b"GS0380040301\n00P\n3d900\n0D0C0007CB000000oo00?X?Y?Z?[?\\?]?^?_?\x60?a?b?c?d?e^\n\n",
        laser_on=True,
        timer_ms=1000000,
        ranges={
            380: 20,
            381: 19,
            382: 0,
            383: 7,
            384: 1234,
            385: 5432,
            386: 5600,
            387: 5601,
            388: 4095,
            389: 4096,
            390: 1000,
            391: 1001,
            392: 1002,
            393: 1003,
            394: 1004,
            395: 1005,
            396: 1006,
            397: 1007,
            398: 1008,
            399: 1009,
            400: 1010,
            401: 1011,
            402: 1012,
            403: 1013,
        },
        wait_ms=100,
        status="00",
        timestamp=1000000,
        values=[
            20,
            19,
            0,
            7,
            1234,
            0,
            0,
            0,
            4095,
            0,
            1000,
            1001,
            1002,
            1003,
            1004,
            1005,
            1006,
            1007,
            1008,
            1009,
            1010,
            1011,
            1012,
            1013,
        ],
    ),
    ExchangeVector(
        id="SC-14",
        command=b"GD0380040303\n",
        reply=b"GD0380040303\n00P\n3d900\n00D0CB0oo0?X0?Z0?]0?\x600?cT\n\n",
        laser_on=True,
        timer_ms=1000000,
        ranges={
            380: 20,
            381: 19,
            382: 0,
            383: 7,
            384: 1234,
            385: 5432,
            386: 5600,
            387: 5601,
            388: 4095,
            389: 4096,
            390: 1000,
            391: 1001,
            392: 1002,
            393: 1003,
            394: 1004,
            395: 1005,
            396: 1006,
            397: 1007,
            398: 1008,
            399: 1009,
            400: 1010,
            401: 1011,
            402: 1012,
            403: 1013,
        },
        wait_ms=100,
        status="00",
        timestamp=1000000,
        values=[20, 1234, 4095, 1000, 1002, 1005, 1008, 1011],
    ),
    ExchangeVector(
        id="SC-15",
        command=b"MD0384038601002\n",
        reply=b"MD0384038601002\n00P\n\nMD0384038601001\n99b\nJUWV<\n1Dh00C000@\n\nMD0384038601000\n99b\nJUY:b\n1Dh00C000@\n\n",
        timer_ms=6969830,
        ranges={384: 5432, 385: 19, 386: 6000},
        wait_ms=400,
        status="00",
        scans=[("01", 6969830, [5432, 19, 0]), ("00", 6969930, [5432, 19, 0])],
    ),
    ExchangeVector(
        id="SC-16",
        command=b"MS0384038601100\n",
        reply=b"MS0384038601100\n00P\n\nMS0384038601100\n99b\n7XCTV\n000C00c\n\nMS0384038601100\n99b\n7XF\\a\n000C00c\n\n",
        timer_ms=2000000,
        ranges={384: 5432, 385: 19, 386: 6000},
        at_ms=30,
        wait_ms=470,
        status="00",
        scans=[("00", 2000100, [0, 19, 0]), ("00", 2000300, [0, 19, 0])],
    ),
    ExchangeVector(
        id="SC-17",
        command=b"GD0725004401\n",
        reply=b"GD0725004401\n05U\n\n",
        laser_on=True,
        status="05",
    ),
    ExchangeVector(
        id="SC-18",
        command=b"GD0044080001\n",
        reply=b"GD0044080001\n04T\n\n",
        laser_on=True,
        status="04",
    ),
    ExchangeVector(
        id="SC-19", command=b"MD00440725010x3\n", reply=b"MD00440725010x3\n07W\n\n", status="07"
    ),
    ExchangeVector(id="SC-20", command=b"ZZ\n", reply=b"ZZ\n0Ee\n\n", status="0E"),
    CorruptVector(
        id="SC-21",
        command=b"GD0384038601\n",
        reply=b"GD0384038601\n00P\nJUGnD\n1Dh00D000@\n\n",
        of="SC-11",
        line=4,
    ),
)

ALL_VECTORS: Final[dict[str, Vector]] = {v.id: v for v in VECTORS}
CODEC_VECTORS: Final = tuple(
    v for v in VECTORS if isinstance(v, EncodeVector | SumVector | TimestampVector)
)
EXCHANGES: Final = tuple(v for v in VECTORS if isinstance(v, ExchangeVector))
CORRUPT: Final = tuple(v for v in VECTORS if isinstance(v, CorruptVector))
DEFAULT_RANGE_MM: Final = 1000  # "1000 mm at every other step" (§7)
