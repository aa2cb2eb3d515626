r"""The emulated FlightCtrl's UART: its own receiver and the wire timing of what it sends.

Receiving (``mk-serial.md`` §3 "How the FC receives") differs from the client decoder
(:class:`mkflight.mk.codec.FrameParser`) on purpose:

- a ``'#'`` starts a frame only when the receiver is idle *and* the last good frame has
  been handled by the main loop (:meth:`FcReceiver.take`); until then every byte outside
  a frame is ignored, so a frame sent too soon after another is lost;
- inside a frame every byte is kept until ``'\r'``, ``'#'`` included, so a truncated frame
  swallows the next one and both cost one checksum error (vector MK-23);
- a frame reaching 170 bytes without ``'\r'`` resets the receiver (§2.4);
- the payload characters are not range-checked (§2.2): only the checksum is.

Sending: 57600 Bd, 10 bits a byte (§1); a frame reaches the host when its last byte has left.
"""

from __future__ import annotations

from typing import Final

from mkflight.mk.codec import END, MAX_FRAME_BYTES, MIN_FRAME_BYTES, OFFSET, START, Frame, checksum

BAUD: Final = 57600  # §1
BITS_PER_BYTE: Final = 10  # start + 8 data + stop
_NS_PER_S: Final = 1_000_000_000


def wire_ns(n_bytes: int) -> int:
    """Time ``n_bytes`` take on the wire, rounded up to the nanosecond (§1)."""
    return -(-n_bytes * BITS_PER_BYTE * _NS_PER_S // BAUD)


def bytes_sent(elapsed_ns: int) -> int:
    """How many whole bytes leave the UART in ``elapsed_ns``."""
    return max(0, elapsed_ns) * BAUD // (BITS_PER_BYTE * _NS_PER_S)


def corrupt_checksum(frame: bytes) -> bytes:
    """Return ``frame`` with its second checksum character changed (still in range)."""
    bad = OFFSET + (frame[-2] - OFFSET + 1) % 64
    return frame[:-2] + bytes((bad,)) + frame[-1:]


def decode_leniently(chars: bytes | bytearray) -> bytes:
    """Decode payload characters as the FC does: no range check, whole groups only (§2.2)."""
    out = bytearray()
    for i in range(0, len(chars) - 3, 4):
        v1, v2, v3, v4 = ((c - OFFSET) & 0xFF for c in chars[i : i + 4])
        out.append(((v1 << 2) | (v2 >> 4)) & 0xFF)
        out.append(((v2 << 4) | (v3 >> 2)) & 0xFF)
        out.append(((v3 << 6) | v4) & 0xFF)
    return bytes(out)


class FcReceiver:
    """Bytes in, at most one good frame waiting for the main loop; bad input counted."""

    def __init__(self) -> None:
        self._buf: bytearray | None = None  # the frame being received, from its '#'
        self._pending: Frame | None = None
        self.crc_errors = 0
        self.overflows = 0
        self.ignored_bytes = 0

    @property
    def pending(self) -> bool:
        """A good frame is waiting to be handled (the receiver will not start another)."""
        return self._pending is not None

    def feed(self, data: bytes) -> bool:
        """Receive ``data``; return True if it completed a good frame (now pending)."""
        completed = False
        for byte in data:
            buf = self._buf
            if buf is None:
                if byte == START and self._pending is None:
                    self._buf = bytearray((START,))
                else:
                    self.ignored_bytes += 1
                continue
            buf.append(byte)
            if byte == END:
                self._buf = None
                completed = self._complete(buf) or completed
            elif len(buf) >= MAX_FRAME_BYTES:
                self._buf = None
                self.overflows += 1
        return completed

    def _complete(self, raw: bytearray) -> bool:
        """Check one frame; keep it if its checksum is right, else count it (no NAK)."""
        if len(raw) < MIN_FRAME_BYTES or checksum(raw[:-3]) != raw[-3:-1]:
            self.crc_errors += 1
            return False
        payload = decode_leniently(raw[3:-3])
        self._pending = Frame(addr=raw[1] - ord("a"), cmd=chr(raw[2]), payload=payload)
        return True

    def take(self) -> Frame | None:
        """Hand the pending frame to the main loop; the receiver may start a new one."""
        frame, self._pending = self._pending, None
        return frame
