r"""The emulated FlightCtrl's UART: its receiver, and the wire timing both ways.

Receiving (``mk-serial.md`` §3 "How the FC receives") differs from the client decoder
(:class:`mkflight.mk.codec.FrameParser`) on purpose:

- a ``'#'`` starts a frame only when the receiver is idle *and* the last good frame has
  been handled by the main loop (:meth:`FcReceiver.take`); until then every byte outside
  a frame is ignored, so a frame sent too soon after another is lost;
- inside a frame every byte is kept until ``'\r'``, ``'#'`` included, so a truncated frame
  swallows the next one and both cost one checksum error (vector MK-23);
- a frame reaching 170 bytes without ``'\r'`` resets the receiver (§2.4);
- the payload characters are not range-checked (§2.2): only the checksum is.

Wire timing: 57600 Bd, 10 bits a byte (§1). A frame the FC sends reaches the host when its
last byte has left. What the host writes goes through a :class:`HostLine`: each chunk
starts when it was written or when the previous byte finished arriving, whichever is
later, and its bytes arrive back to back, each one byte time after the last.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Final

from mkflight.conversions import NS_PER_S
from mkflight.mk.codec import END, MAX_FRAME_BYTES, MIN_FRAME_BYTES, OFFSET, START, Frame, checksum

BAUD: Final = 57600  # §1
BITS_PER_BYTE: Final = 10  # start + 8 data + stop


def wire_ns(n_bytes: int) -> int:
    """Time ``n_bytes`` take on the wire, rounded up to the nanosecond (§1)."""
    return -(-n_bytes * BITS_PER_BYTE * NS_PER_S // BAUD)


def bytes_sent(elapsed_ns: int) -> int:
    """How many whole bytes leave the UART in ``elapsed_ns``."""
    return max(0, elapsed_ns) * BAUD // (BITS_PER_BYTE * NS_PER_S)


@dataclass(frozen=True, slots=True)
class WireChunk:
    """Bytes on the wire from ``start_ns``; the last one has arrived at ``end_ns``."""

    start_ns: int
    end_ns: int
    data: bytes

    def arrival_ns(self, i: int) -> int:
        """When byte ``i`` (0-based) has fully arrived."""
        return self.start_ns + wire_ns(i + 1)


class HostLine:
    """The host-to-FC direction: written chunks, arriving byte by byte at wire speed.

    Bytes are taken off the line in order with :meth:`arrived` and :meth:`consume`;
    pure, integer nanoseconds.
    """

    def __init__(self) -> None:
        self._chunks: deque[WireChunk] = deque()
        self._pos = 0  # bytes of the first chunk already consumed
        self._free_ns: int | None = None

    @property
    def free_ns(self) -> int | None:
        """When the last byte written so far has arrived (None: nothing written yet)."""
        return self._free_ns

    def write(self, data: bytes, t_ns: int) -> WireChunk:
        """The host writes ``data`` at ``t_ns``: it goes out after what is still on the line."""
        start = t_ns if self._free_ns is None else max(t_ns, self._free_ns)
        chunk = WireChunk(start, start + wire_ns(len(data)), data)
        self._free_ns = chunk.end_ns
        if data:
            self._chunks.append(chunk)
        return chunk

    def next_ns(self) -> int | None:
        """When the next unconsumed byte has arrived, or None if nothing is on the line."""
        return self._chunks[0].arrival_ns(self._pos) if self._chunks else None

    def next_event_ns(self) -> int | None:
        r"""When the next '\r' or the end of the current chunk arrives, whichever is first."""
        if not self._chunks:
            return None
        chunk = self._chunks[0]
        end = chunk.data.find(b"\r", self._pos)
        return chunk.arrival_ns(len(chunk.data) - 1 if end < 0 else end)

    def arrived(self, t_ns: int) -> bytes:
        """The unconsumed bytes of the current chunk that have arrived by ``t_ns``."""
        if not self._chunks:
            return b""
        chunk = self._chunks[0]
        return chunk.data[self._pos : min(len(chunk.data), bytes_sent(t_ns - chunk.start_ns))]

    def consume(self, n: int) -> int:
        """Take ``n`` bytes from :meth:`arrived` off the line; return when the last arrived."""
        chunk = self._chunks[0]
        self._pos += n
        t_last = chunk.arrival_ns(self._pos - 1)
        if self._pos >= len(chunk.data):
            self._chunks.popleft()
            self._pos = 0
        return t_last


class FcTransmitter:
    """The FC's sending side: one chunk at a time on the wire, with the injected faults.

    The chunks and the faults belong to the line and survive a reboot; the counters are
    the FC's and restart with :meth:`restart`.
    """

    def __init__(self, t_ns: int) -> None:
        self._outbox: deque[WireChunk] = deque()
        self.garbage = b""  # sent just before the next frame
        self.corrupt_count = 0  # the next frames get a bad checksum
        self.silent_until_ns = t_ns  # frames starting before this are lost
        self.restart(t_ns)

    def restart(self, boot_ns: int) -> None:
        """A (re)booted FC: the line is free from ``boot_ns``, the counters are zero."""
        self.free_ns = boot_ns  # when the last frame started has left
        self.by_cmd: Counter[str] = Counter()
        self.dropped = 0
        self.corrupted = 0

    def emit(self, t_ns: int, frame: bytes, kind: str) -> None:
        """Put ``frame`` on the wire at ``t_ns`` (or lose it, as the faults say)."""
        if t_ns < self.silent_until_ns:
            self.dropped += 1
            self.free_ns = t_ns + wire_ns(len(frame))
            return
        if self.corrupt_count > 0:
            self.corrupt_count -= 1
            self.corrupted += 1
            frame = corrupt_checksum(frame)
        chunk, self.garbage = self.garbage + frame, b""
        self.free_ns = t_ns + wire_ns(len(chunk))
        self._outbox.append(WireChunk(t_ns, self.free_ns, chunk))
        self.by_cmd[kind] += 1

    def next_end_ns(self) -> int | None:
        """When the next chunk has fully left, or None if nothing is on the wire."""
        return self._outbox[0].end_ns if self._outbox else None

    def take_sent(self, t_ns: int) -> list[bytes]:
        """The chunks whose last byte has left by ``t_ns``, in order."""
        out: list[bytes] = []
        while self._outbox and self._outbox[0].end_ns <= t_ns:
            out.append(self._outbox.popleft().data)
        return out

    def cut(self, t_ns: int) -> None:
        """The FC resets at ``t_ns``: a chunk still on the wire ends after its last whole byte."""
        if self._outbox and self._outbox[-1].end_ns > t_ns:
            chunk = self._outbox.pop()
            sent = bytes_sent(t_ns - chunk.start_ns)
            if sent > 0:
                self._outbox.append(WireChunk(chunk.start_ns, t_ns, chunk.data[:sent]))


class UartCounters:
    """The receiver's and the transmitter's counters, as attributes of the FC model."""

    rx: FcReceiver
    tx: FcTransmitter

    @property
    def rx_crc_errors(self) -> int:
        """Frames dropped for a bad checksum (or too short to have one)."""
        return self.rx.crc_errors

    @property
    def rx_overflows(self) -> int:
        r"""Frames dropped for reaching 170 bytes without '\r' (§2.4)."""
        return self.rx.overflows

    @property
    def rx_ignored_bytes(self) -> int:
        """Bytes outside frames, including frames lost while the last was unhandled."""
        return self.rx.ignored_bytes

    @property
    def tx_by_cmd(self) -> Counter[str]:
        """Frames sent (put on a live line), by command; '#dk' counts as 'k'."""
        return self.tx.by_cmd

    @property
    def tx_dropped(self) -> int:
        """Frames lost on a silenced line (:meth:`~mkflight.sim.fc.FcModel.silence`)."""
        return self.tx.dropped

    @property
    def tx_corrupted(self) -> int:
        """Frames sent with a bad checksum (:meth:`~mkflight.sim.fc.FcModel.corrupt_next`)."""
        return self.tx.corrupted

    @property
    def rx_lost_frames(self) -> int:
        """Frames whose '#' arrived while the last good frame was still unhandled (§3)."""
        return self.rx.lost_frames


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
        self.lost_frames = 0

    @property
    def pending(self) -> bool:
        """A good frame is waiting to be handled (the receiver will not start another)."""
        return self._pending is not None

    def feed_until_frame(self, data: bytes) -> tuple[int, bool]:
        """Receive ``data`` up to and including the end of a good frame, if one completes.

        Returns how many bytes were taken and whether a good frame is now pending; the
        caller hands the rest in once it has noted when that frame completed.
        """
        for i, byte in enumerate(data):
            buf = self._buf
            if buf is None:
                if byte != START:
                    self.ignored_bytes += 1
                elif self._pending is not None:
                    self.ignored_bytes += 1
                    self.lost_frames += 1  # the last frame is not handled yet (§3)
                else:
                    self._buf = bytearray((START,))
                continue
            buf.append(byte)
            if byte == END:
                self._buf = None
                if self._complete(buf):
                    return i + 1, True
            elif len(buf) >= MAX_FRAME_BYTES:
                self._buf = None
                self.overflows += 1
        return len(data), False

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
