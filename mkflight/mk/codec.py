r"""MikroKopter serial frames: encoding, checksum and an incremental parser (sans-I/O).

Frame layout (``protocols/mk-serial.md`` §2)::

    '#'  addr('a'+n)  cmd  payload(4 chars per 3 bytes, "modified base64")  CRC1 CRC2  '\\r'

The payload length is not transmitted: decoding gives ``3*ceil(n/3)`` bytes and the
message layer reads its structure from the start. The "CRC" is a byte sum mod 4096
written as two characters from ``'='``. ``'#'`` and ``'\\r'`` never occur inside a frame,
which is what lets the parser resynchronise on garbage (§3).
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass
from typing import NamedTuple

START = 0x23  # '#'
END = 0x0D  # '\r'
OFFSET = 0x3D  # '=': every encoded character is OFFSET + a 6-bit value
MAX_FRAME_BYTES = 170  # FC 0.84a buffer, '\r' included (§2.4)
MIN_FRAME_BYTES = 6  # '#' addr cmd CRC1 CRC2 '\r'

ADDR_ANY = 0
ADDR_FC = 1
ADDR_NC = 2
ADDR_MK3MAG = 3


class Frame(NamedTuple):
    """One decoded frame: address number, command character and decoded payload bytes.

    A named tuple: immutable as a frozen dataclass, but built in a third of the time
    (the parser makes 2-3 a step).
    """

    addr: int
    cmd: str
    payload: bytes


def checksum(data: bytes | bytearray | memoryview) -> bytes:
    """Return the two checksum characters for ``data`` ('#' through the last payload char)."""
    crc = sum(data) % 4096
    return bytes((OFFSET + crc // 64, OFFSET + crc % 64))


# The encoding is base64 with another alphabet: value v is written as chr(61 + v) instead
# of the standard alphabet's v-th character. Translating between the alphabets lets the C
# codec in ``binascii`` do the bit work (16x faster than a Python loop on a DebugOut).
_STD_ALPHABET = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/"
_TO_STD = bytes(
    _STD_ALPHABET[c - OFFSET] if OFFSET <= c < OFFSET + 64 else 0x21 for c in range(256)
)
_FROM_STD = bytes(OFFSET + _STD_ALPHABET.index(c) if c in _STD_ALPHABET else 0 for c in range(256))


def encode_payload(payload: bytes) -> bytes:
    """Encode bytes 3 at a time into 4 characters each, zero-padding the last group (§2.2)."""
    n = len(payload)
    if n % 3:
        payload = payload + bytes(3 - n % 3)
    return binascii.b2a_base64(payload, newline=False).translate(_FROM_STD)


def decode_payload(chars: bytes | bytearray | memoryview) -> bytes | None:
    """Decode payload characters back to bytes; None if the length or a character is invalid.

    The FC does not range-check characters; we do, because a character outside
    ``'='..'|'`` cannot come from a correct encoder even when the sum happens to match.
    """
    if len(chars) % 4:
        return None
    try:
        return binascii.a2b_base64(bytes(chars).translate(_TO_STD), strict_mode=True)
    except binascii.Error:
        return None


def encode_frame(addr: int, cmd: str, payload: bytes = b"") -> bytes:
    r"""Build a complete frame, checksum and ``'\\r'`` included.

    Raises:
        ValueError: the address, command or payload cannot form a valid frame.
    """
    if not 0 <= addr <= 63:
        msg = f"address {addr} outside 0..63"
        raise ValueError(msg)
    if len(cmd) != 1 or cmd in "#\r" or not 0x20 <= ord(cmd) < 0x7F:
        msg = f"command {cmd!r} is not one printable character"
        raise ValueError(msg)
    head = bytes((START, ord("a") + addr, ord(cmd))) + encode_payload(payload)
    frame = head + checksum(head) + b"\r"
    if len(frame) > MAX_FRAME_BYTES:
        msg = f"frame of {len(frame)} bytes exceeds the FC's {MAX_FRAME_BYTES}-byte buffer"
        raise ValueError(msg)
    return frame


#: The longest payload a frame can carry: 4 characters per 3 bytes within MAX_FRAME_BYTES.
_MAX_PAYLOAD_BYTES = (MAX_FRAME_BYTES - MIN_FRAME_BYTES) // 4 * 3


class FrameEncoder:
    r"""Encodes frames of one address and command (:func:`encode_frame`, checked once).

    The address and command are checked here; a call encodes the payload, sums the
    checksum and appends ``'\r'`` - what every 50 ms ExternControl needs, no more.

    Raises:
        ValueError: the address or command cannot form a valid frame.
    """

    __slots__ = ("_head",)

    def __init__(self, addr: int, cmd: str) -> None:
        self._head = encode_frame(addr, cmd)[:3]

    def __call__(self, payload: bytes) -> bytes:
        """The complete frame of ``payload`` (at most 123 bytes: the FC's buffer)."""
        n = len(payload)
        if n > _MAX_PAYLOAD_BYTES:  # too long: encode_frame says so
            return encode_frame(self._head[1] - ord("a"), chr(self._head[2]), payload)
        if n % 3:
            payload = payload + bytes(3 - n % 3)
        head = self._head + binascii.b2a_base64(payload, newline=False).translate(_FROM_STD)
        crc = sum(head) % 4096
        return head + bytes((OFFSET + crc // 64, OFFSET + crc % 64, END))


@dataclass(slots=True)
class ParserStats:
    """Counters of everything the parser saw; all of it ends up in ``flight.json``."""

    bytes_in: int = 0
    frames: int = 0
    crc_errors: int = 0
    discarded_bytes: int = 0
    malformed: int = 0
    overflows: int = 0


class FrameParser:
    """Incremental client decoder of ``protocols/mk-serial.md`` §3.

    Feed it any chunks; it returns the good frames completed by each chunk. Bytes outside
    a frame, abandoned frames (a new ``'#'`` inside one), bad-checksum frames, malformed
    frames and overflowing frames are all counted in :attr:`stats` (``discarded_bytes``
    counts every byte that did not end up in a good frame). Nothing it is fed can raise.
    """

    def __init__(self) -> None:
        self.stats = ParserStats()
        self._buf = bytearray()  # the frame being collected, starting with '#'; else empty

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete frame held until more data arrives."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop an incomplete frame (after the port was re-opened), counting its bytes."""
        self.stats.discarded_bytes += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Consume ``data`` and return the complete, valid frames it finished."""
        stats = self.stats
        view = bytes(data)  # the same object if it is bytes already
        n = len(view)
        stats.bytes_in += n
        frames: list[Frame] = []
        buf = self._buf
        pos = 0
        while pos < n:
            if buf:
                pos = self._continue(view, pos, frames)
                continue
            start = view.find(b"#", pos)
            if start < 0:
                stats.discarded_bytes += n - pos
                break
            stats.discarded_bytes += start - pos
            # The common case: the whole frame is in this chunk, checked without a copy
            # into the buffer.
            end = view.find(b"\r", start + 1, start + MAX_FRAME_BYTES)
            if end >= 0 and view.find(b"#", start + 1, end) < 0:
                frame = self._complete(view[start : end + 1])
                if frame is not None:
                    frames.append(frame)
                pos = end + 1
                continue
            buf.append(START)
            pos = start + 1
        return frames

    def _continue(self, view: bytes, pos: int, frames: list[Frame]) -> int:
        """Go on with the frame in the buffer from ``view[pos]``; return where it stopped."""
        stats = self.stats
        buf = self._buf
        n = len(view)
        room = MAX_FRAME_BYTES - len(buf)
        stop = min(n, pos + room)
        end = view.find(b"\r", pos, stop)
        restart = view.find(b"#", pos, stop if end < 0 else end)
        if restart >= 0:
            # A '#' always starts a new frame; the collected bytes are abandoned.
            stats.discarded_bytes += len(buf) + (restart - pos)
            buf.clear()
            return restart
        if end >= 0:
            buf += view[pos : end + 1]
            frame = self._complete(bytes(buf))
            buf.clear()
            if frame is not None:
                frames.append(frame)
            return end + 1
        buf += view[pos:stop]
        if len(buf) >= MAX_FRAME_BYTES:
            stats.overflows += 1
            stats.discarded_bytes += len(buf)
            buf.clear()
        return stop

    def _complete(self, raw: bytes) -> Frame | None:
        r"""Check and decode one ``'#'...'\\r'`` frame, counting it if it is bad.

        The checksum and the payload's decoding are :func:`checksum` and
        :func:`decode_payload` written out (this runs for every frame received).
        """
        stats = self.stats
        size = len(raw)
        if size < MIN_FRAME_BYTES:
            stats.malformed += 1
            stats.discarded_bytes += size
            return None
        crc1 = raw[-3]
        crc2 = raw[-2]
        crc = (sum(raw) - crc1 - crc2 - END) % 4096
        if crc1 != OFFSET + crc // 64 or crc2 != OFFSET + crc % 64:
            stats.crc_errors += 1
            stats.discarded_bytes += size
            return None
        addr = raw[1] - 0x61  # 'a'
        payload: bytes | None = None
        if (size - MIN_FRAME_BYTES) % 4 == 0 and 0 <= addr <= 63:
            try:
                payload = binascii.a2b_base64(raw[3:-3].translate(_TO_STD), strict_mode=True)
            except binascii.Error:
                payload = None
        if payload is None:
            stats.malformed += 1
            stats.discarded_bytes += size
            return None
        stats.frames += 1
        return Frame(addr, chr(raw[2]), payload)
