"""The MK messages: vectors MK-01..MK-19 both ways, range checks and round trips (§4-6)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.errors import CommandRangeError, ProtocolError
from mkflight.mk.codec import Frame, FrameParser, encode_frame
from mkflight.mk.messages import (
    ANALOG_COUNT,
    ANALOG_LABELS_084A,
    FORBIDDEN_COMMANDS,
    Confirm,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
    VersionInfo,
    debug_request,
    label_request,
    pack_sticks,
    ppm_request,
    request,
    version_request,
)

from .vectors import (
    CONFIRM_VECTORS,
    DEBUG_OUT_VECTORS,
    DEBUG_REQUEST_VECTORS,
    EXTERN_CONTROL_VECTORS,
    LABEL_VECTORS,
    MK_01,
    MK_02,
    MK_11,
    MK_13,
    MK_15,
    MK_17,
    MK_19,
    PPM_VECTORS,
    VERSION_VECTORS,
    ConfirmVector,
    DebugOutVector,
    DebugRequestVector,
    ExternControlVector,
    FrameVector,
    LabelVector,
    PpmVector,
    VersionInfoVector,
)


def parse_one(data: bytes) -> Frame:
    """Parse ``data`` and insist it is exactly one good frame with nothing left over."""
    parser = FrameParser()
    frames = parser.feed(data)
    assert len(frames) == 1, frames
    assert parser.stats.discarded_bytes == 0
    assert parser.stats.bytes_in == len(data)
    return frames[0]


def extern_of(v: ExternControlVector) -> ExternControl:
    """The ExternControl a vector describes."""
    return ExternControl(
        nick=v.nick,
        roll=v.roll,
        yaw=v.yaw,
        gas=v.gas,
        height=v.height,
        frame=v.frame,
        config=v.config,
        digital=v.digital,
        remote_buttons=v.remote_buttons,
        free=v.free,
        addr=v.addr,
    )


def make_extern(fields: Mapping[str, object], **extra: object) -> ExternControl:
    """An ExternControl from field names (values of any type: the packer checks them)."""
    kwargs: dict[str, Any] = {**fields, **extra}
    return ExternControl(**kwargs)


# --- requests: MK-01, MK-02, MK-04..06, MK-15, MK-17, MK-19 ------------------------------


REQUEST_BUILDERS: list[tuple[FrameVector, Callable[[], bytes]]] = [
    (MK_01, version_request),
    (MK_02, lambda: version_request(0)),
    (MK_15, ppm_request),
    (MK_17, lambda: label_request(0)),
    (MK_19, lambda: encode_frame(3, "k", MK_19.payload)),
]


@pytest.mark.parametrize(
    ("vector", "build"), REQUEST_BUILDERS, ids=[v.id for v, _b in REQUEST_BUILDERS]
)
def test_request_vectors_encode(vector: FrameVector, build: Callable[[], bytes]) -> None:
    assert build() == vector.data


@pytest.mark.parametrize("vector", [MK_01, MK_02, MK_15, MK_17, MK_19], ids=lambda v: v.id)
def test_request_vectors_decode(vector: FrameVector) -> None:
    frame = parse_one(vector.data)
    assert (frame.addr, frame.cmd) == (vector.addr, vector.cmd)
    assert frame.payload[: len(vector.payload)] == vector.payload
    assert not any(frame.payload[len(vector.payload) :])


def test_mk3mag_frame_fields() -> None:
    frame = parse_one(MK_19.data)
    nick, roll = (int.from_bytes(frame.payload[i : i + 2], "little", signed=True) for i in (0, 2))
    assert (frame.addr, nick, roll, frame.payload[7]) == (3, -123, 45, 1)


@pytest.mark.parametrize("vector", DEBUG_REQUEST_VECTORS, ids=lambda v: v.id)
def test_debug_request_vectors(vector: DebugRequestVector) -> None:
    assert debug_request(vector.interval, vector.addr) == vector.data
    frame = parse_one(vector.data)
    assert (frame.addr, frame.cmd, frame.payload) == (
        vector.addr,
        "d",
        bytes((vector.interval, 0, 0)),
    )


@pytest.mark.parametrize("interval", [-1, 256, 1000])
def test_debug_request_range(interval: int) -> None:
    with pytest.raises(CommandRangeError, match=f"debug interval {interval} outside 0..255"):
        debug_request(interval)


@pytest.mark.parametrize("index", [-1, 32])
def test_label_request_range(index: int) -> None:
    with pytest.raises(CommandRangeError, match=f"label index {index} outside 0..31"):
        label_request(index)


@pytest.mark.parametrize("cmd", sorted(FORBIDDEN_COMMANDS))
def test_forbidden_commands_are_refused(cmd: str) -> None:
    with pytest.raises(ProtocolError, match=f"refusing to send {cmd!r}"):
        request(cmd)
    with pytest.raises(ProtocolError, match="refusing"):
        request(cmd, b"\x0a", addr=0)


def test_forbidden_set_is_the_documented_one() -> None:
    assert frozenset({"R", "t", "q", "s"}) == FORBIDDEN_COMMANDS


# --- VersionInfo: MK-03 ------------------------------------------------------------------


@pytest.mark.parametrize("vector", VERSION_VECTORS, ids=lambda v: v.id)
def test_version_info_vector(vector: VersionInfoVector) -> None:
    info = VersionInfo(
        sw_major=vector.sw_major,
        sw_minor=vector.sw_minor,
        proto_major=vector.proto_major,
        proto_minor=vector.proto_minor,
        sw_patch=vector.sw_patch,
        hardware_error=vector.hardware_error,
        addr=vector.addr,
    )
    assert info.encode() == vector.data
    decoded = VersionInfo.decode(parse_one(vector.data))
    assert decoded == info
    assert decoded.text == "0.84a"
    assert not decoded.has_hardware_error


def test_version_info_text_and_hardware_error() -> None:
    info = VersionInfo(2, 0, 11, 0, 3, hardware_error=b"\x00\x00\x04\x00\x00")
    assert info.text == "2.00d"
    assert info.has_hardware_error


def test_version_info_short_payload() -> None:
    with pytest.raises(ProtocolError, match="VersionInfo frame carries 9 bytes, needs 10"):
        VersionInfo.decode(Frame(1, "V", bytes(9)))


@given(
    st.tuples(*[st.integers(0, 255)] * 5),
    st.binary(min_size=5, max_size=5),
    st.integers(0, 63),
)
def test_version_info_round_trip(
    head: tuple[int, int, int, int, int], hardware_error: bytes, addr: int
) -> None:
    info = VersionInfo(*head, hardware_error=hardware_error, addr=addr)
    data = info.encode()
    assert len(data) == 22
    assert VersionInfo.decode(parse_one(data)) == info


# --- DebugOut: MK-07, MK-08 --------------------------------------------------------------


@pytest.mark.parametrize("vector", DEBUG_OUT_VECTORS, ids=lambda v: v.id)
def test_debug_out_vectors(vector: DebugOutVector) -> None:
    debug = DebugOut.from_values(vector.analog, status=vector.status, addr=vector.addr)
    assert debug.encode() == vector.data
    decoded = DebugOut.decode(parse_one(vector.data))
    assert decoded == debug
    assert decoded.status == vector.status
    assert decoded.addr == vector.addr
    expected = [vector.analog.get(i, 0) for i in range(ANALOG_COUNT)]
    assert list(decoded.analog) == expected


def test_debug_out_labelled() -> None:
    decoded = DebugOut.decode(parse_one(DEBUG_OUT_VECTORS[1].data))
    named = decoded.labelled()
    assert list(named) == list(ANALOG_LABELS_084A)
    assert named["AngleNick"] == -12
    assert named["Gyro Compass"] == 271
    assert named["Voltage [0.1V]"] == 118
    assert named["Hovergas"] == 120


@pytest.mark.parametrize("value", [32768, -32769, 1 << 40])
def test_debug_out_value_out_of_range(value: int) -> None:
    with pytest.raises(CommandRangeError, match="DebugOut value out of range"):
        DebugOut.from_values({5: value}).encode()


def test_debug_out_wrong_count_and_status() -> None:
    with pytest.raises(CommandRangeError, match="needs 32 analog values, got 31"):
        DebugOut(status=(3, 0), analog=(0,) * 31).encode()
    with pytest.raises(CommandRangeError, match="DebugOut value out of range"):
        DebugOut(status=(256, 0), analog=(0,) * 32).encode()


def test_debug_out_short_payload() -> None:
    with pytest.raises(ProtocolError, match="DebugOut frame carries 63 bytes, needs 66"):
        DebugOut.decode(Frame(1, "D", bytes(63)))
    with pytest.raises(ProtocolError, match="DebugOut frame carries 63 bytes, needs 66"):
        DebugOut.analog_of(Frame(1, "D", bytes(63)))


@given(st.lists(st.integers(-32768, 32767), min_size=32, max_size=32))
def test_debug_out_analog_of_is_the_decoded_analog(analog: list[int]) -> None:
    """What the link unpacks per sample is what the whole decoding gives."""
    frame = parse_one(DebugOut(status=(3, 0), analog=tuple(analog)).encode())
    assert DebugOut.analog_of(frame) == DebugOut.decode(frame).analog == tuple(analog)


@given(
    st.lists(st.integers(-32768, 32767), min_size=32, max_size=32),
    st.tuples(st.integers(0, 255), st.integers(0, 255)),
    st.integers(0, 63),
)
def test_debug_out_round_trip(analog: list[int], status: tuple[int, int], addr: int) -> None:
    debug = DebugOut(status=status, analog=tuple(analog), addr=addr)
    data = debug.encode()
    assert len(data) == 94
    assert DebugOut.decode(parse_one(data)) == debug


# --- ExternControl: MK-09..12 ------------------------------------------------------------


@pytest.mark.parametrize("vector", EXTERN_CONTROL_VECTORS, ids=lambda v: v.id)
def test_extern_control_vectors(vector: ExternControlVector) -> None:
    command = extern_of(vector)
    assert command.encode() == vector.data
    assert len(command.pack()) == 11
    decoded = ExternControl.decode(parse_one(vector.data))
    assert decoded == command
    assert decoded.takes_control == bool(vector.config & 1)


def test_neutral_is_mk11() -> None:
    assert ExternControl.neutral(frame=MK_11.frame).encode() == MK_11.data
    assert not ExternControl.neutral().takes_control


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gas", -1),
        ("gas", 256),
        ("gas", -1.0),
        ("nick", 128),
        ("nick", -129),
        ("roll", 128),
        ("yaw", -129),
        ("height", 128),
        ("frame", 256),
        ("frame", -1),
        ("config", 256),
        ("config", -1),
        ("free", 256),
        ("remote_buttons", -1),
    ],
)
def test_extern_control_never_wraps(field: str, value: float) -> None:
    command = make_extern({field: value})
    with pytest.raises(CommandRangeError, match=rf"ExternControl\.{field} = .* outside"):
        command.pack()
    with pytest.raises(CommandRangeError, match=rf"ExternControl\.{field}"):
        command.encode()


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 0.5, 127.5, -0.25], ids=repr)
@pytest.mark.parametrize("field", ["nick", "roll", "yaw", "gas", "height", "frame", "config"])
def test_extern_control_rejects_non_integral(field: str, value: float) -> None:
    with pytest.raises(CommandRangeError, match=rf"ExternControl\.{field} must be a finite"):
        make_extern({field: value}).pack()


@pytest.mark.parametrize("value", [True, False, "1", None, b"\x01"], ids=repr)
def test_extern_control_rejects_non_numbers(value: object) -> None:
    with pytest.raises(CommandRangeError, match=r"ExternControl\.gas must be a number"):
        make_extern({"gas": value}).pack()


def test_extern_control_digital() -> None:
    with pytest.raises(CommandRangeError, match="digital needs 2 values, got 3"):
        ExternControl(digital=(0, 0, 0)).pack()  # type: ignore[arg-type]
    with pytest.raises(CommandRangeError, match=r"ExternControl\.digital1 = 256"):
        ExternControl(digital=(0, 256)).pack()
    with pytest.raises(CommandRangeError, match=r"ExternControl\.config must be a finite"):
        _ = ExternControl(config=math.nan).takes_control


def test_extern_control_whole_floats_pack_like_ints() -> None:
    as_float = ExternControl(nick=-20.0, roll=15.0, gas=100.0, frame=7.0, config=1.0)
    as_int = ExternControl(nick=-20, roll=15, gas=100, frame=7, config=1)
    assert as_float.encode() == as_int.encode() == EXTERN_CONTROL_VECTORS[0].data


WIRE_RANGES: dict[str, tuple[int, int]] = {
    "nick": (-128, 127),
    "roll": (-128, 127),
    "yaw": (-128, 127),
    "gas": (0, 255),
    "height": (-128, 127),
    "frame": (0, 255),
    "config": (0, 255),
}

any_number = st.floats(allow_nan=True, allow_infinity=True) | st.integers()
near_range = st.integers(-300, 300) | st.integers(-300, 300).map(float) | any_number


def _valid(value: float, lo: int, hi: int) -> bool:
    """True if ``value`` is a finite whole number inside ``lo..hi``."""
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        return False
    return lo <= value <= hi


@given(st.fixed_dictionaries({name: near_range for name in WIRE_RANGES}))
def test_extern_control_packs_exactly_or_raises(fields: dict[str, float]) -> None:
    command = make_extern(fields)
    expected_ok = all(_valid(fields[n], *WIRE_RANGES[n]) for n in WIRE_RANGES)
    try:
        payload = command.pack()
    except CommandRangeError:
        assert not expected_ok, f"{fields} is valid but was refused"
        return
    assert expected_ok, f"{fields} is out of range but packed (wrapped?)"
    assert len(payload) == 11
    decoded = ExternControl.decode(parse_one(command.encode()))
    for name, (lo, hi) in WIRE_RANGES.items():
        got = getattr(decoded, name)
        assert got == fields[name], name
        assert lo <= got <= hi, name


@given(
    st.fixed_dictionaries(
        {name: st.integers(lo, hi) for name, (lo, hi) in WIRE_RANGES.items()}
        | {"remote_buttons": st.integers(0, 255), "free": st.integers(0, 255)}
    ),
    st.tuples(st.integers(0, 255), st.integers(0, 255)),
    st.integers(0, 63),
)
def test_extern_control_round_trip(
    fields: dict[str, int], digital: tuple[int, int], addr: int
) -> None:
    command = make_extern(fields, digital=digital, addr=addr)
    data = command.encode()
    assert len(data) == 22
    frame = parse_one(data)
    assert frame.payload[11:] == b"\x00"
    assert ExternControl.decode(frame) == command


@given(
    st.integers(-128, 127),
    st.integers(-128, 127),
    st.integers(-128, 127),
    st.integers(0, 255),
    st.integers(0, 255),
    st.integers(0, 255),
)
def test_pack_sticks_is_the_commands_pack(
    nick: int, roll: int, yaw: int, gas: int, frame: int, config: int
) -> None:
    command = ExternControl(nick=nick, roll=roll, yaw=yaw, gas=gas, frame=frame, config=config)
    assert pack_sticks(nick, roll, yaw, gas, frame, config) == command.pack()


# --- Confirm: MK-13, MK-14 ---------------------------------------------------------------


@pytest.mark.parametrize("vector", CONFIRM_VECTORS, ids=lambda v: v.id)
def test_confirm_vectors(vector: ConfirmVector) -> None:
    confirm = Confirm(frame=vector.frame, addr=vector.addr)
    assert confirm.encode() == vector.data
    assert Confirm.decode(parse_one(vector.data)) == confirm


def test_confirm_matches_its_command() -> None:
    command = ExternControl.decode(parse_one(EXTERN_CONTROL_VECTORS[0].data))
    assert Confirm.decode(parse_one(MK_13.data)).frame == command.frame == 7


@pytest.mark.parametrize("frame", [-1, 256, 1.5, math.nan], ids=repr)
def test_confirm_range(frame: object) -> None:
    with pytest.raises(CommandRangeError, match=r"ExternControl\.frame"):
        Confirm(frame=frame).encode()  # type: ignore[arg-type]


def test_confirm_empty_payload() -> None:
    with pytest.raises(ProtocolError, match="Confirm frame carries 0 bytes, needs 1"):
        Confirm.decode(Frame(1, "B", b""))


@given(st.integers(0, 255), st.integers(0, 63))
def test_confirm_round_trip(number: int, addr: int) -> None:
    confirm = Confirm(frame=number, addr=addr)
    data = confirm.encode()
    assert len(data) == 10
    assert Confirm.decode(parse_one(data)) == confirm


# --- PPM: MK-16 --------------------------------------------------------------------------


@pytest.mark.parametrize("vector", PPM_VECTORS, ids=lambda v: v.id)
def test_ppm_vectors(vector: PpmVector) -> None:
    ppm = Ppm.from_channels(vector.channels, addr=vector.addr)
    assert ppm.encode() == vector.data
    decoded = Ppm.decode(parse_one(vector.data))
    assert decoded == ppm
    assert list(decoded.channels) == [vector.channels.get(i, 0) for i in range(26)]


def test_ppm_out_of_range() -> None:
    with pytest.raises(CommandRangeError, match="PPM channel out of range"):
        Ppm.from_channels({1: 40000}).encode()


@given(st.lists(st.integers(-32768, 32767), min_size=26, max_size=26))
def test_ppm_round_trip(channels: list[int]) -> None:
    ppm = Ppm(tuple(channels))
    assert Ppm.decode(parse_one(ppm.encode())) == ppm


# --- Label: MK-18 ------------------------------------------------------------------------


@pytest.mark.parametrize("vector", LABEL_VECTORS, ids=lambda v: v.id)
def test_label_vectors(vector: LabelVector) -> None:
    label = Label(index=vector.index, label=vector.label, addr=vector.addr)
    assert label.encode() == vector.data
    assert Label.decode(parse_one(vector.data)) == label
    assert ANALOG_LABELS_084A[vector.index] == vector.label


def test_label_decode_nul_padding() -> None:
    frame = Frame(1, "A", b"\x09" + b"Voltage [0.1V]\x00\x00" + b"\x00")
    assert Label.decode(frame) == Label(9, "Voltage [0.1V]")


@given(
    st.integers(0, 31),
    st.text(
        alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1, max_size=16
    ),
)
def test_label_round_trip(index: int, text: str) -> None:
    label = Label(index, text)
    assert Label.decode(parse_one(label.encode())) == label
