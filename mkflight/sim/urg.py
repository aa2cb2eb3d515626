"""The Hokuyo URG-04LX as a pure, sans-I/O model (``protocols/scip2.md``).

:class:`UrgModel` is what the emulator on a pty (:mod:`mkflight.sim.urg_server`) and a
lock-step simulation drive, like :class:`mkflight.sim.fc.FcModel`: command bytes go in with
:meth:`UrgModel.receive`, the replies the sensor has finished come out of
:meth:`UrgModel.poll`, and :meth:`UrgModel.next_event_ns` says when to look again. It never
reads a clock: time is integer nanoseconds passed in.

What is modelled (§3.2-3.3):

- The mirror turns at 600 rpm from the model's creation: scan k starts (step 0) at
  ``t0 + k * 100 ms`` and step s is measured ``s * 97.65625 us`` later.
- The sensor's millisecond timer (24 bits, wraps after 4.66 h) reads ``timer_ms`` at
  ``t0``; ``RS`` sets it to 0. A scan's timestamp is the timer at its step 0.
- GD/GS and MD/MS are served from the first scan whose step 0 is at or after the
  command; a message leaves when the scan's end step is measured: 70.8 ms after the
  timestamp for a full scan (step 725). ``interval`` skips scans, ``count`` counts down
  in the echo and ends the stream with the laser off.
- Other commands are answered at once. Any reply reaches the host ``delivery_delay_ns``
  after it left (the USB transfer; 0 here, the server sets it) plus a jitter uniform in
  ``0..delivery_jitter_ns`` drawn per reply (seeded), in order: a reply never overtakes
  the one before it.
- A URG-04LX starts in SCIP 1.1 and answers only ``SCIP2.0`` (with a bare ``0``) until
  switched; every other command gets the 1.1 refusal ``echo LF E LF LF`` (not a SCIP 2.0
  reply: the client counts it as garbage). A UG01 starts in SCIP 2.0 (``scip1=False``).
- ``TM0``/``TM1``/``TM2`` enter, read and leave time-adjust mode; in it every other command
  is refused with ``0E`` (§6 item 4, §8).

Not modelled: the RS-232 wire time and bit rates (``SS``), motor speed changes (``CR``),
``HS``/``DB``; jitter of the mirror itself (only the USB side jitters). A second GD while
one is pending gets ``0B``; a new MD/MS (even the same one) replaces the running stream
(§3.2, §8).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from mkflight.conversions import NS_PER_MS
from mkflight.sim.urg_answers import (
    DEAD_ZONE_CODE,
    ScanRequest,
    UrgIdentity,
    corrupt_last_sum,
    ii_lines,
    info_reply,
    parse_scan_request,
    pp_lines,
    scan_message,
    scan_values,
    status_reply,
    tag_status,
    vv_lines,
)
from mkflight.urg.codec import LF, TIMESTAMP_MODULUS_MS, timestamp_line

MAX_COMMAND_BYTES: Final = 64  # a longer line without terminator is discarded
SCIP1_REFUSAL: Final = b"E"  # a SCIP 1.1 sensor's answer to a SCIP 2.0 command (assumed)
_SIMPLE: Final = frozenset((b"VV", b"PP", b"II", b"BM", b"QT", b"RS"))


class RangeSource(Protocol):
    """Where the measured ranges come from: a fixed table, a room, a simulation."""

    def ranges_mm(self, t_ns: int, steps: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Ranges in mm of ``steps`` (ascending, within AMIN..AMAX) of one scan.

        ``t_ns`` is the time of the scan's step 0; step s is measured at ``t_ns +
        params.step_offset_ns(s)`` (97.66 us a step), so a moving vehicle can be sampled
        at each step's own time. Values < 20 are error codes (§5); values > DMAX, and
        negative values, are sent as 0.
        """
        ...


@dataclass(slots=True)
class _Job:
    """A GD/GS waiting for its scan, or a running MD/MS stream."""

    request: ScanRequest
    scan_index: int  # the next scan to send
    sent: int = 0


class UrgModel:
    """A URG-04LX seen from its USB port, driven by explicit time (module docstring)."""

    def __init__(
        self,
        source: RangeSource,
        *,
        t_ns: int = 0,
        timer_ms: int = 0,
        scip1: bool = True,
        laser_on: bool = False,
        identity: UrgIdentity | None = None,
        delivery_delay_ns: int = 0,
        delivery_jitter_ns: int = 0,
        seed: int = 0,
    ) -> None:
        """Power the sensor up at ``t_ns``: a scan starts then, the timer reads ``timer_ms``.

        Args:
            source: the ranges the sensor measures.
            t_ns: the model's start time (step 0 of scan 0).
            timer_ms: the sensor's millisecond timer at ``t_ns`` (24 bits).
            scip1: start in SCIP 1.1 like a URG-04LX (False: a UG01, already in 2.0).
            laser_on: the laser is on at the start.
            identity: the VV/PP/II texts and parameters (default: a URG-04LX).
            delivery_delay_ns: how long every reply takes to reach the host.
            delivery_jitter_ns: plus a per-reply jitter, uniform in 0..this (USB).
            seed: seeds the jitter draws (reproducible).
        """
        self.source = source
        self.identity = identity if identity is not None else UrgIdentity()
        self.params = self.identity.params
        self.starts_in_scip1 = scip1
        self.delivery_delay_ns = delivery_delay_ns
        self.delivery_jitter_ns = delivery_jitter_ns
        self._jitter_rng = np.random.default_rng([seed, 30])
        self._outbox: deque[tuple[int, bytes]] = deque()
        self._last_delivery_ns = t_ns
        self._garbage = b""
        self._corrupt_count = 0
        self._stall_until_ns = t_ns
        self.power_ups = 0
        self.rx_by_command: Counter[str] = Counter()
        self.rx_discarded_bytes = 0
        self.scans_sent = 0
        self.scans_stalled = 0
        self.tx_corrupted = 0
        self._now_ns = t_ns
        self._power_up(t_ns, timer_ms, laser_on=laser_on)

    def _power_up(self, t_ns: int, timer_ms: int, *, laser_on: bool = False) -> None:
        """The state of a sensor switched on at ``t_ns`` (the motor is at step 0 then)."""
        self.scip1 = self.starts_in_scip1
        self.laser_on = laser_on
        self.time_adjust = False
        self._origin_ns = t_ns
        self._timer_base = (t_ns, timer_ms % TIMESTAMP_MODULUS_MS)
        self._rx = bytearray()
        self._gd: _Job | None = None
        self._stream: _Job | None = None

    def power_cycle(self, t_ns: int) -> None:
        """Switch the sensor off and on at ``t_ns`` (a USB-powered URG being replugged).

        Replies not yet delivered are lost; it starts again in SCIP 1.1 (if it did at
        first), laser off, timer at 0, no stream. Fault settings and counters stay.
        """
        self._advance(t_ns)
        self._outbox.clear()
        self._last_delivery_ns = self._now_ns
        self.power_ups += 1
        self._power_up(self._now_ns, 0)

    # ----------------------------------------------------------------- time
    @property
    def now_ns(self) -> int:
        """The latest time the model has been advanced to."""
        return self._now_ns

    @property
    def scan_period_ns(self) -> int:
        """One turn of the mirror (100 ms at 600 rpm)."""
        return self.params.scan_period_ns

    def scan_start_ns(self, k: int) -> int:
        """When scan ``k`` starts (its step 0)."""
        return self._origin_ns + k * self.scan_period_ns

    def timer_ms(self, t_ns: int) -> int:
        """The sensor's 24-bit millisecond timer at ``t_ns`` (§3.3)."""
        base_ns, base_ms = self._timer_base
        return (base_ms + (t_ns - base_ns) // NS_PER_MS) % TIMESTAMP_MODULUS_MS

    @property
    def streaming(self) -> bool:
        """An MD/MS stream is running."""
        return self._stream is not None

    def _first_scan_at(self, t_ns: int) -> int:
        """The first scan whose step 0 is at or after ``t_ns``."""
        return -((self._origin_ns - t_ns) // self.scan_period_ns)

    def _ready_ns(self, job: _Job) -> int:
        """When the job's next scan message leaves: its end step has been measured."""
        end = min(job.request.end_step, self.params.ares_steps - 1)
        return self.scan_start_ns(job.scan_index) + self.params.step_offset_ns(end)

    def _advance(self, t_ns: int) -> None:
        """Send every scan message that is finished by ``t_ns``, in time order."""
        self._now_ns = max(self._now_ns, t_ns)
        while True:
            jobs = [j for j in (self._gd, self._stream) if j is not None]
            if not jobs:
                return
            job = min(jobs, key=self._ready_ns)
            ready = self._ready_ns(job)
            if ready > self._now_ns:
                return
            self._send_scan(job, ready)

    def _send_scan(self, job: _Job, ready_ns: int) -> None:
        """Measure and send ``job``'s next scan at ``ready_ns``, then plan its next one."""
        req = job.request
        t0 = self.scan_start_ns(job.scan_index)
        job.sent += 1
        if req.is_stream:
            remaining = max(req.count - job.sent, 0)
            echo, status = req.echo(remaining), "99"
            if req.count and job.sent >= req.count:
                self._stream = None
                self.laser_on = False
            else:
                job.scan_index += req.interval + 1
        else:
            echo, status = req.echo(), "00"
            self._gd = None
        if ready_ns < self._stall_until_ns:
            self.scans_stalled += 1
            return
        values = scan_values(req, self.measure(t0, req.start_step, req.end_step), self.params)
        self._emit(ready_ns, scan_message(echo, status, self.timer_ms(t0), values, req.chars))
        self.scans_sent += 1

    def measure(self, t0_ns: int, start_step: int, end_step: int) -> list[int]:
        """Per-step ranges (mm) of steps ``start..end`` of the scan starting at ``t0_ns``.

        Steps outside AMIN..AMAX carry no measurement: they read 19 (§8).
        """
        p = self.params
        lo, hi = max(start_step, p.amin_step), min(end_step, p.amax_step)
        out = [DEAD_ZONE_CODE] * (end_step - start_step + 1)
        if lo <= hi:
            steps = np.arange(lo, hi + 1, dtype=np.int64)
            measured = np.asarray(self.source.ranges_mm(t0_ns, steps), dtype=np.int64)
            out[lo - start_step : hi - start_step + 1] = measured.tolist()
        return out

    # ----------------------------------------------------------------- receiving
    def receive(self, data: bytes, t_ns: int) -> None:
        """Command bytes from the host, all arriving at ``t_ns``; LF, CR or CR LF end a line."""
        self._advance(t_ns)
        self._rx += data
        while True:
            ends = [i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0]
            if not ends:
                break
            end = min(ends)
            line = bytes(self._rx[:end])
            del self._rx[: end + 1]
            if line:
                self._handle(line, self._now_ns)
        if len(self._rx) > MAX_COMMAND_BYTES:
            self.rx_discarded_bytes += len(self._rx)
            self._rx.clear()

    def _handle(self, line: bytes, t_ns: int) -> None:
        """Answer one command line (§3, §4)."""
        head, sep, tag_text = line.partition(b";")
        tag = sep + tag_text
        name = "SCIP2.0" if head.startswith(b"SCIP") else head[:2].decode("latin-1")
        self.rx_by_command[name] += 1
        if self.scip1:
            if line == b"SCIP2.0":
                self.scip1 = False
                self._emit(t_ns, line + LF + b"0" + LF + LF)
            else:
                self._emit(t_ns, line + LF + SCIP1_REFUSAL + LF + LF)
            return
        status = tag_status(tag) if tag else None
        if status is None and self.time_adjust and head[:2] != b"TM":
            status = "0E"
        if status is not None:
            self._emit(t_ns, status_reply(line, status))
            return
        if head in _SIMPLE:
            self._simple(head, line, t_ns)
        elif head[:2] == b"TM":
            self._time_adjust(head, line, t_ns)
        elif head[:2] in (b"GD", b"GS", b"MD", b"MS"):
            self._scan_request(head, tag, line, t_ns)
        else:
            self._emit(t_ns, status_reply(line, "0E"))  # incl. SCIP2.0 in 2.0 (SC-02)

    def _simple(self, head: bytes, echo: bytes, t_ns: int) -> None:
        """VV, PP, II, BM, QT, RS (§3, SC-03..SC-09)."""
        who = self.identity
        if head == b"VV":
            self._emit(t_ns, info_reply(echo, vv_lines(who)))
        elif head == b"PP":
            self._emit(t_ns, info_reply(echo, pp_lines(who)))
        elif head == b"II":
            lines = ii_lines(who, laser_on=self.laser_on, timer_ms=self.timer_ms(t_ns))
            self._emit(t_ns, info_reply(echo, lines))
        elif head == b"BM":
            status = "02" if self.laser_on else "00"
            self.laser_on = True
            self._emit(t_ns, status_reply(echo, status))
        else:  # QT, RS: laser off, stream and pending GD stopped
            self.laser_on = False
            self._stream = self._gd = None
            if head == b"RS":
                self._timer_base = (t_ns, 0)
            self._emit(t_ns, status_reply(echo, "00"))

    def _time_adjust(self, head: bytes, echo: bytes, t_ns: int) -> None:
        """TM0 enter, TM1 read the timer, TM2 leave time-adjust mode (§3, §6 item 4)."""
        mode = head[2:]
        if mode not in (b"0", b"1", b"2"):
            self._emit(t_ns, status_reply(echo, "0C" if not mode else "01"))
        elif mode == b"0":
            status = "02" if self.time_adjust else "00"
            self.time_adjust = True
            self.laser_on = False
            self._stream = self._gd = None
            self._emit(t_ns, status_reply(echo, status))
        elif mode == b"1":
            if not self.time_adjust:
                self._emit(t_ns, status_reply(echo, "04"))
            else:
                reply = status_reply(echo, "00")[:-1] + timestamp_line(self.timer_ms(t_ns))
                self._emit(t_ns, reply + LF + LF)
        else:
            self._emit(t_ns, status_reply(echo, "00" if self.time_adjust else "03"))
            self.time_adjust = False

    def _scan_request(self, head: bytes, tag: bytes, echo: bytes, t_ns: int) -> None:
        """GD/GS (laser must be on) and MD/MS (switches it on): §3.1-3.2."""
        request = parse_scan_request(head, tag)
        if isinstance(request, str):
            self._emit(t_ns, status_reply(echo, request))
            return
        job = _Job(request, self._first_scan_at(t_ns))
        if request.is_stream:
            self.laser_on = True
            self._stream = job
            self._emit(t_ns, status_reply(echo, "00"))
        elif not self.laser_on:
            self._emit(t_ns, status_reply(echo, "10"))
        elif self._gd is not None:
            self._emit(t_ns, status_reply(echo, "0B"))
        else:
            self._gd = job

    # ----------------------------------------------------------------- sending
    def _emit(self, ready_ns: int, reply: bytes) -> None:
        """Queue ``reply`` (with injected garbage and corruption) for delivery."""
        if self._corrupt_count > 0:
            self._corrupt_count -= 1
            self.tx_corrupted += 1
            reply = corrupt_last_sum(reply)
        chunk, self._garbage = self._garbage + reply, b""
        delay = self.delivery_delay_ns
        if self.delivery_jitter_ns > 0:
            delay += int(self._jitter_rng.integers(0, self.delivery_jitter_ns + 1))
        deliver = max(ready_ns + delay, self._last_delivery_ns)
        self._last_delivery_ns = deliver
        self._outbox.append((deliver, chunk))

    def poll(self, t_ns: int) -> list[bytes]:
        """The replies that have reached the host by ``t_ns``, in order (one chunk each)."""
        self._advance(t_ns)
        out: list[bytes] = []
        while self._outbox and self._outbox[0][0] <= self._now_ns:
            out.append(self._outbox.popleft()[1])
        return out

    def next_event_ns(self) -> int | None:
        """The earliest time :meth:`poll` may return something; None: wait for input."""
        times = [self._ready_ns(j) for j in (self._gd, self._stream) if j is not None]
        if self._outbox:
            times.append(self._outbox[0][0])
        return min(times) if times else None

    # ----------------------------------------------------------------- faults
    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next reply (add LF to keep it a line of its own)."""
        self._garbage += data

    def corrupt_next(self, n: int) -> None:
        """Give the next ``n`` replies a bad sum on their last line (SC-21)."""
        self._corrupt_count += n

    def stall(self, until_ns: int) -> None:
        """Lose every scan message that would leave before ``until_ns``; commands still work.

        The stream itself runs on (scans are counted off), as when the sensor's USB side
        hangs; after ``until_ns`` the stream resumes, or a re-issued MD starts a new one.
        """
        self._stall_until_ns = max(self._stall_until_ns, until_ns)
