"""Fuzzing MK streams (``mk-serial.md``): frame pieces, their seeded random draws, the pure pass.

The pieces, each with what ``FrameParser`` must make of it (§3): valid frames of every kind
the link knows (DebugOut, VersionInfo, ExternControl, Confirm, PPM, Label, the requests, the
``#dk`` MK3MAG frame, any address and command); frames with one byte changed (one CRC error
each); truncated frames and ``'#'`` look-alikes (abandoned at the next frame's ``'#'``);
malformed frames (short, bad length, a character outside ``'='..'|'``, a bad address, all with
a good checksum); overflows (170 bytes without ``'\r'``); garbage runs (any byte but ``'#'``:
CR, LF, payload characters). :func:`run_mk_parser` feeds them through a ``FrameParser``.
"""

from __future__ import annotations

import dataclasses
import random
import struct
from collections.abc import Callable, Iterator
from typing import Final

from fuzz_pieces import Advance, PassResult, Piece, feed_pass, join, random_length

from mkflight.mk.codec import MAX_FRAME_BYTES, Frame, FrameParser, checksum, encode_frame
from mkflight.mk.messages import Confirm, DebugOut, ExternControl, Label, Ppm, VersionInfo

# ================================================================= MK pieces (mk-serial.md)
_START, _END = 0x23, 0x0D
_NO_START = bytes(range(256)).replace(b"#", b"$")
_NO_START_END = _NO_START.replace(b"\r", b"\x0e")
_CHARS = bytes(range(0x3D, 0x7D))  # '='..'|': the payload alphabet (§2.2)


def frame_bytes(frame: Frame) -> int:
    """Wire size of a decoded frame: '#', addr, cmd, 4 chars per 3 bytes, CRC, CR (§2)."""
    return 6 + len(frame.payload) * 4 // 3


def _pad3(payload: bytes) -> bytes:
    return payload + bytes(-len(payload) % 3)


def mk_frame(addr: int, cmd: str, payload: bytes = b"") -> Piece[Frame]:
    """A valid frame of any address and command (the codec's generic frame)."""
    data = encode_frame(addr, cmd, payload)
    return Piece(data, (Frame(addr, cmd, _pad3(payload)),), (len(data),))


MkMessage = DebugOut | VersionInfo | ExternControl | Confirm | Ppm | Label


def mk_message(msg: MkMessage) -> Piece[Frame]:
    """A message as its ``encode()`` writes it; the frame expected from its layout (§5-6)."""
    if isinstance(msg, DebugOut):
        cmd, payload = "D", bytes(msg.status) + struct.pack("<32h", *msg.analog)
    elif isinstance(msg, VersionInfo):
        head = (msg.sw_major, msg.sw_minor, msg.proto_major, msg.proto_minor, msg.sw_patch)
        cmd, payload = "V", bytes(head) + msg.hardware_error.ljust(5, b"\0")[:5]
    elif isinstance(msg, ExternControl):
        cmd, payload = "b", msg.pack()
    elif isinstance(msg, Confirm):
        cmd, payload = "B", bytes((int(msg.frame),))
    elif isinstance(msg, Ppm):
        cmd, payload = "P", struct.pack("<26h", *msg.channels)
    else:
        cmd, payload = "A", bytes((msg.index,)) + msg.label.encode("ascii")[:16].ljust(16, b" ")
    data = msg.encode()
    return Piece(data, (Frame(msg.addr, cmd, _pad3(payload)),), (len(data),))


def mk_corrupt(valid: Piece[Frame], index: int, new: int) -> Piece[Frame]:
    """A valid frame with one byte after '#' and before CR changed: one CRC error."""
    data = valid.data
    i = 1 + index % (len(data) - 2)
    b = new % 256
    while b in (_START, _END, data[i]):
        b = (b + 1) % 256
    return Piece(data[:i] + bytes((b,)) + data[i + 1 :], counts=(("crc_errors", 1),))


def mk_truncated(frame: bytes, cut: int, then: Piece[Frame]) -> Piece[Frame]:
    """The first bytes of ``frame`` (no CR), abandoned at the '#' of ``then``."""
    assert then.data[:1] == b"#"
    return join([Piece(frame[: 1 + cut % (len(frame) - 1)]), then])


def mk_lookalike(noise: bytes, then: Piece[Frame]) -> Piece[Frame]:
    """'#' and up to 168 bytes of noise (no '#', no CR): abandoned at ``then``'s '#'."""
    assert then.data[:1] == b"#"
    return join([Piece(b"#" + noise.translate(_NO_START_END)[: MAX_FRAME_BYTES - 2]), then])


def mk_overflow(noise: bytes, extra: int) -> Piece[Frame]:
    """'#' and 169 + ``extra`` bytes without '#' or CR: one overflow, the rest garbage."""
    body = (noise or b"x").translate(_NO_START_END)
    n = MAX_FRAME_BYTES - 1 + extra % 400
    return Piece(b"#" + (body * (n // len(body) + 1))[:n], counts=(("overflows", 1),))


def mk_malformed(variant: int, noise: bytes, cmd: int) -> Piece[Frame]:
    """A frame the parser must reject although its checksum is good: one malformed frame.

    ``variant`` % 4: 0 shorter than 6 bytes; 1 a payload length not a multiple of 4; 2 a
    payload character outside '='..'|'; 3 an address byte outside 'a'..'a'+63.
    """
    kind = variant % 4
    if kind == 0:
        return Piece(b"#" + noise[:3].translate(_NO_START_END) + b"\r", counts=(("malformed", 1),))
    chars = bytes(_CHARS[b % 64] for b in noise[:156])
    c = bytes((cmd % 256,)).translate(_NO_START_END)
    whole = chars[: len(chars) // 4 * 4]
    if kind == 1:
        head = b"#b" + c + (whole + b"===")[: len(whole) + 1 + variant // 4 % 3]
    elif kind == 2:
        whole = whole or b"===="
        bad = bytes((noise[-1] if noise and noise[-1] not in _CHARS else 0x7E,))
        i = variant // 4 % len(whole)
        head = b"#b" + c + whole[:i] + bad.translate(_NO_START_END) + whole[i + 1 :]
    else:
        addr = 0xA1 + variant // 4 % 95 if variant % 8 == 3 else variant // 4 % 0x61
        head = b"#" + bytes((addr,)).translate(_NO_START_END) + c + whole
    return Piece(head + checksum(head) + b"\r", counts=(("malformed", 1),))


def mk_garbage(noise: bytes) -> Piece[Frame]:
    """Bytes without '#' (CR, LF, payload characters, anything else): all discarded."""
    return Piece(noise.translate(_NO_START))


# ================================================================= seeded random pieces
_EDGE16: Final = (-32768, -32767, -1, 0, 1, 32766, 32767)
_MK_NOISE: Final = b"\r\n\r\n=>?@|{}~bBdDvV \x00\xff"


def _noise(rng: random.Random, n: int, alphabet: bytes) -> bytes:
    return bytes(
        rng.choice(alphabet) if rng.random() < 0.5 else rng.randrange(256) for _ in range(n)
    )


def random_debug(rng: random.Random, addr: int = 1) -> DebugOut:
    """A DebugOut with random values, a tenth of them at the int16 edges."""
    analog = tuple(
        rng.choice(_EDGE16) if rng.random() < 0.1 else rng.randint(-2000, 2000) for _ in range(32)
    )
    return DebugOut(status=(rng.randrange(256), rng.randrange(256)), analog=analog, addr=addr)


def random_mk_valid(rng: random.Random) -> Piece[Frame]:
    """A valid frame of a random kind, mostly to the FC's address."""
    a = 1 if rng.random() < 0.8 else rng.randrange(64)
    kind, u8 = rng.randrange(10), rng.randrange
    if kind == 0:
        return mk_message(random_debug(rng, a))
    if kind == 1:
        hw = bytes(5) if rng.random() < 0.7 else rng.randbytes(5)
        return mk_message(VersionInfo(u8(256), u8(256), u8(256), u8(256), u8(256), hw, a))
    if kind == 2:
        nick, roll, yaw, height = (rng.randint(-128, 127) for _ in range(4))
        ec = ExternControl(nick, roll, yaw, u8(256), height, u8(256), u8(256), (u8(256), 0))
        return mk_message(dataclasses.replace(ec, addr=a))
    if kind == 3:
        return mk_message(Confirm(u8(256), a))
    if kind == 4:
        return mk_message(Ppm(tuple(rng.randint(-32768, 32767) for _ in range(26)), a))
    if kind == 5:
        text = "".join(rng.choice("AngleNick Voltage[0.1V]") for _ in range(u8(17)))
        return mk_message(Label(u8(32), text, a))
    if kind == 6:
        cmd = rng.choice("vdapb")
        return mk_frame(1, cmd, rng.randbytes({"v": 0, "p": 0, "b": 11}.get(cmd, 1)))
    if kind == 7:
        return mk_frame(3, "k", rng.randbytes(8))
    cmd = chr(rng.choice([c for c in range(0x20, 0x7F) if c != _START]))
    return mk_frame(a, cmd, rng.randbytes(u8(124)))


def random_mk_piece(
    rng: random.Random, valid: Callable[[], Piece[Frame]], budget: int
) -> tuple[Piece[Frame], int]:
    """Maybe a garbage run, then a frame piece, valid or not; and how many frames it tried
    (a truncated frame and the frame that abandons it are two, if ``budget`` allows)."""
    head: Piece[Frame] = Piece(b"")
    if rng.random() < 0.5:
        head = mk_garbage(_noise(rng, random_length(rng, 20), _MK_NOISE))
    r, frame = rng.random(), random_mk_valid(rng)
    if r < 0.55:
        return join([head, valid()]), 1
    if r < 0.70:
        return join([head, mk_corrupt(frame, rng.randrange(1 << 16), rng.randrange(256))]), 1
    if r < 0.78 and budget >= 2:
        return join([head, mk_truncated(frame.data, rng.randrange(1 << 16), valid())]), 2
    if r < 0.82:
        noise = _noise(rng, rng.randrange(169), _MK_NOISE)
        return join([head, mk_lookalike(noise, valid())]), 1
    if r < 0.97:
        noise = _noise(rng, rng.randrange(1, 200), _MK_NOISE)
        return join([head, mk_malformed(rng.randrange(1 << 16), noise, rng.randrange(256))]), 1
    noise = _noise(rng, rng.randrange(1, 40), _MK_NOISE)
    return join([head, mk_overflow(noise, rng.randrange(400))]), 1


# ================================================================= the pure pass
def run_mk_parser(n: int, rng: random.Random, advance: Advance = lambda k: None) -> PassResult:
    """``n`` frame pieces (valid, corrupted, truncated, malformed ...) through FrameParser."""

    def batches() -> Iterator[tuple[Piece[Frame], int]]:
        left = n
        while left > 0:
            pieces: list[Piece[Frame]] = []
            tried = 0
            while left - tried > 0 and len(pieces) < 200:
                piece, k = random_mk_piece(rng, lambda: random_mk_valid(rng), left - tried)
                pieces.append(piece)
                tried += k
            left -= tried
            yield join(pieces), tried

    return feed_pass("MK parser", FrameParser(), batches(), rng, advance)
