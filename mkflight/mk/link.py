"""The asynchronous FlightCtrl link: version, DebugOut subscription, ExternControl, release.

One :class:`MkLink` owns one :class:`~mkflight.io.stream.ByteStream`. A reader task feeds
every received chunk to the sans-I/O :class:`~mkflight.mk.codec.FrameParser` and files
the frames: DebugOut becomes a timestamped :class:`~mkflight.msgs.ImuSample` for the
consumer, 'V' answers the version request, 'B' confirms are matched to the ExternControl
frames they answer (round-trip time). Frames of other addresses (the ``#dk`` compass
frames) and unknown commands are counted and dropped (``mk-serial.md`` §2.1, §7.6).

Timing rules (``mk-serial.md`` §3, §7.2, §8; SPEC §2):

* The subscription is renewed from :meth:`MkLink.next_sample`, i.e. by the consumer
  asking for its next sample. A stalled control step therefore stops refreshing the
  FC's hold on the last extern command, and the FC falls back to the pilot's sticks.
* When DebugOut goes stale (``safety.mk_stale_s``) the link re-subscribes at once and
  asks for the version again, so an FC reboot shows up in the log.
* Frames go out one per write, at least ``mk.min_frame_gap_s`` apart. An ExternControl
  is written in the call that sends it unless a frame left less than the gap ago; then it
  waits only for the rest of the gap, ahead of any other queued frame.
* :meth:`MkLink.close` hands control back: Config = 0 with neutral sticks and gas 0,
  ``mk.release_frames`` times, never just falling silent (the FC would hold the last
  command ~5 s, or forever while 'd' renewals keep coming).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field

import structlog

from mkflight.clock import Clock, MonotonicClock
from mkflight.config import Config
from mkflight.errors import LinkError, ProtocolError
from mkflight.io.stream import ByteStream
from mkflight.mk.codec import ADDR_FC, Frame, FrameParser, ParserStats, encode_frame
from mkflight.mk.messages import (
    CMD_CONFIRM,
    CMD_DEBUG_ANSWER,
    CMD_EXTERN,
    CMD_LABEL_ANSWER,
    CMD_PPM_ANSWER,
    CMD_VERSION_ANSWER,
    EXTERN_FRAME_OFFSET,
    Confirm,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
    VersionInfo,
    debug_request,
    version_request,
)
from mkflight.mk.units import MkCalibration, imu_from_debug
from mkflight.msgs import ImuSample

log = structlog.get_logger("mkflight.mk")

NS_PER_S = 1_000_000_000
SAMPLE_BUFFER = 8  # samples kept for a consumer that fell behind; older ones are dropped
CONFIRM_TIMEOUT_NS = NS_PER_S  # a confirm not back within this is counted lost
RELEASE_CONFIRM_WAIT_S = 0.1  # wait for the last release frame's confirm (behind a DebugOut)

#: A tap on the raw bytes: (direction 'r' or 'w', host t_ns, data). Used for recordings.
Tap = Callable[[str, int, bytes], None]
Opener = Callable[[], Awaitable[ByteStream]]


@dataclass(frozen=True, slots=True)
class LinkSettings:
    """The link's timing and addressing, from ``config.mk`` and ``config.safety``."""

    debug_interval_10ms: int = 5
    resubscribe_s: float = 2.0
    stale_s: float = 0.2
    version_retry_s: float = 0.5
    answer_timeout_s: float = 2.5
    min_frame_gap_s: float = 0.003
    release_frames: int = 5
    release_interval_s: float = 0.05
    reopen_backoff_s: float = 0.1
    reopen_backoff_max_s: float = 2.0

    @classmethod
    def from_config(cls, cfg: Config) -> LinkSettings:
        """Take the settings from a loaded configuration."""
        mk = cfg.mk
        return cls(
            debug_interval_10ms=mk.debug_interval_10ms,
            resubscribe_s=mk.resubscribe_s,
            stale_s=cfg.safety.mk_stale_s,
            version_retry_s=mk.version_retry_s,
            answer_timeout_s=mk.answer_timeout_s,
            min_frame_gap_s=mk.min_frame_gap_s,
            release_frames=mk.release_frames,
            release_interval_s=mk.release_interval_s,
            reopen_backoff_s=mk.reopen_backoff_s,
            reopen_backoff_max_s=mk.reopen_backoff_max_s,
        )


@dataclass(slots=True)
class LinkStats:
    """What the link saw and did; ends up in ``flight.json``."""

    parser: ParserStats = field(default_factory=ParserStats)
    samples: int = 0
    samples_dropped: int = 0
    foreign_frames: int = 0
    unknown_frames: int = 0
    bad_messages: int = 0
    versions: int = 0
    subscriptions: int = 0
    stale_events: int = 0
    commands_sent: int = 0
    confirms: int = 0
    confirms_lost: int = 0
    frames_written: int = 0
    bytes_written: int = 0
    delayed_writes: int = 0
    reopens: int = 0
    rtt_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))

    def summary(self) -> dict[str, int | float | None]:
        """Flat counters for logs and ``flight.json``."""
        rtts = sorted(self.rtt_ns)
        median = rtts[len(rtts) // 2] / 1e6 if rtts else None
        return {
            "bytes_in": self.parser.bytes_in,
            "frames_in": self.parser.frames,
            "crc_errors": self.parser.crc_errors,
            "garbage_bytes": self.parser.discarded_bytes,
            "malformed_frames": self.parser.malformed + self.bad_messages,
            "overflows": self.parser.overflows,
            "samples": self.samples,
            "samples_dropped": self.samples_dropped,
            "foreign_frames": self.foreign_frames,
            "stale_events": self.stale_events,
            "subscriptions": self.subscriptions,
            "commands_sent": self.commands_sent,
            "confirms": self.confirms,
            "confirms_lost": self.confirms_lost,
            "reopens": self.reopens,
            "rtt_median_ms": median,
        }


def _resolve(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


class MkLink:
    """One FlightCtrl on one byte stream (see the module docstring for the rules)."""

    def __init__(
        self,
        stream: ByteStream,
        settings: LinkSettings,
        calibration: MkCalibration,
        clock: Clock | None = None,
        *,
        reopen: Opener | None = None,
        tap: Tap | None = None,
    ) -> None:
        self._stream = stream
        self._settings = settings
        self._cal = calibration
        self._clock: Clock = clock or MonotonicClock()
        self._opener = reopen
        self._tap = tap
        self.stats = LinkStats()
        self._parser = FrameParser()
        self.stats.parser = self._parser.stats
        self.port = stream.name
        self.version: VersionInfo | None = None
        self.last_debug: DebugOut | None = None
        self.last_ppm: Ppm | None = None
        self.labels: dict[int, str] = {}
        self._samples: deque[ImuSample] = deque(maxlen=SAMPLE_BUFFER)
        self._sample_waiter: asyncio.Future[None] | None = None
        self._version_event = asyncio.Event()
        self._confirm_event = asyncio.Event()
        self._error: LinkError | None = None
        self._reader: asyncio.Task[None] | None = None
        self._frame_no = 0
        self._pending_confirms: dict[int, int] = {}
        self._last_write_ns = -(10**18)
        self._last_subscribe_ns = -(10**18)
        self._last_sample_ns: int | None = None
        self._outbox: deque[tuple[str, bytes, int]] = deque()  # (kind, frame, Frame no.)
        self._outbox_timer: asyncio.TimerHandle | None = None
        self._stale = False
        self._want_version = False
        self._closed = False

    # ----- lifecycle -------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader task (idempotent)."""
        if self._reader is None or self._reader.done():
            self._reader = asyncio.get_running_loop().create_task(
                self._read_loop(), name=f"mk-reader {self.port}"
            )

    async def connect(self) -> VersionInfo:
        """Ask for the version until the FC answers (``mk-serial.md`` §8.3).

        Raises:
            LinkError: no 'V' within ``answer_timeout_s`` ("no FlightCtrl answered").
        """
        self.start()
        s = self._settings
        deadline = self._clock.now_ns() + int(s.answer_timeout_s * NS_PER_S)
        tries = 0
        while True:
            self._raise_if_failed()
            self._version_event.clear()
            self._send("v", version_request())
            tries += 1
            left_ns = deadline - self._clock.now_ns()
            wait_s = min(s.version_retry_s, max(left_ns, 0) / NS_PER_S)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._version_event.wait(), wait_s)
            if self._version_event.is_set() and self.version is not None:
                log.info("fc_version", port=self.port, version=self.version.text, tries=tries)
                return self.version
            self._raise_if_failed()
            if self._clock.now_ns() >= deadline:
                p = self.stats.parser
                msg = (
                    f"no FlightCtrl answered on {self.port} within {s.answer_timeout_s:g} s "
                    f"('v' sent {tries} times; received {p.bytes_in} bytes, {p.frames} valid "
                    f"frames, {p.crc_errors} CRC errors, {p.discarded_bytes} garbage bytes)"
                )
                raise LinkError(msg)

    def subscribe(self) -> None:
        """Send the DebugOut subscription 'd' now (also renews it)."""
        self.start()
        self._send("d", debug_request(self._settings.debug_interval_10ms))
        self._last_subscribe_ns = self._clock.now_ns()
        self.stats.subscriptions += 1

    async def close(self, *, release: bool = True) -> None:
        """Hand control back (Config = 0, several times), stop the stream, close the port."""
        if self._closed:
            return
        if release and self._error is None:
            with contextlib.suppress(LinkError):
                # Nothing answered: still hand back (it may be a half-working FC), but
                # quickly, so that "no FlightCtrl answered" is not delayed.
                await self.release(quick=self.version is None)
        if self._error is None:
            # Stop the DebugOut stream (it would expire in ~4 s anyway), after the gap.
            await asyncio.sleep(self._settings.min_frame_gap_s)
            with contextlib.suppress(LinkError):
                self._write_now("d", debug_request(0))
        self._closed = True
        self._cancel_outbox()
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, LinkError):
                await self._reader
        await self._stream.close()
        self._fail(LinkError(f"{self.port}: link closed"))

    async def __aenter__(self) -> MkLink:
        self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def reopen(self, max_wait_s: float = 30.0) -> VersionInfo:
        """Re-open a vanished port with exponential back-off, then version + subscription.

        Raises:
            LinkError: no opener was given, or the port did not come back in ``max_wait_s``.
        """
        if self._opener is None:
            msg = f"{self.port}: no way to re-open this link"
            raise LinkError(msg)
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, LinkError):
                await self._reader
        self._cancel_outbox()
        with contextlib.suppress(LinkError):
            await self._stream.close()
        s = self._settings
        delay_s = s.reopen_backoff_s
        deadline = self._clock.now_ns() + int(max_wait_s * NS_PER_S)
        while True:
            try:
                stream = await self._opener()
                break
            except LinkError as err:
                if self._clock.now_ns() + int(delay_s * NS_PER_S) > deadline:
                    msg = f"{self.port}: did not come back within {max_wait_s:g} s ({err})"
                    raise LinkError(msg) from err
                log.warning("mk_reopen_retry", port=self.port, error=str(err), wait_s=delay_s)
                await asyncio.sleep(delay_s)
                delay_s = min(delay_s * 2, s.reopen_backoff_max_s)
        self._stream = stream
        self._parser.reset()
        self._error = None
        self._samples.clear()
        self._last_write_ns = -(10**18)
        self.stats.reopens += 1
        log.warning("mk_reopened", port=self.port, reopens=self.stats.reopens)
        version = await self.connect()
        self.subscribe()
        return version

    # ----- receiving -------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                data = await self._stream.read()
                t_ns = self._clock.now_ns()
                if self._tap is not None:
                    self._tap("r", t_ns, data)
                for frame in self._parser.feed(data):
                    self._dispatch(frame, t_ns)
        except LinkError as err:
            if not self._closed:
                log.error("mk_link_lost", port=self.port, error=str(err))
            self._fail(err)
        except asyncio.CancelledError:
            raise
        except Exception as err:  # a bug must not leave consumers waiting forever
            self._fail(LinkError(f"{self.port}: reader crashed: {err!r}"))
            raise

    def _dispatch(self, frame: Frame, t_ns: int) -> None:
        stats = self.stats
        if frame.addr != ADDR_FC:
            stats.foreign_frames += 1
            return
        try:
            if frame.cmd == CMD_DEBUG_ANSWER:
                self._on_debug(DebugOut.decode(frame), t_ns)
            elif frame.cmd == CMD_CONFIRM:
                self._on_confirm(Confirm.decode(frame).frame, t_ns)
            elif frame.cmd == CMD_VERSION_ANSWER:
                self._on_version(VersionInfo.decode(frame))
            elif frame.cmd == CMD_PPM_ANSWER:
                self.last_ppm = Ppm.decode(frame)
            elif frame.cmd == CMD_LABEL_ANSWER:
                label = Label.decode(frame)
                self.labels[label.index] = label.label
            else:
                stats.unknown_frames += 1
        except ProtocolError:
            stats.bad_messages += 1

    def _on_debug(self, debug: DebugOut, t_ns: int) -> None:
        self.last_debug = debug
        self._last_sample_ns = t_ns
        self.stats.samples += 1
        if len(self._samples) == self._samples.maxlen:
            self.stats.samples_dropped += 1
        self._samples.append(imu_from_debug(debug, t_ns, self._cal))
        if self._stale:
            self._stale = False
            # Ask who is there now (an FC that rebooted was deaf to the stale-time 'v'),
            # from the consumer's next call so that it cannot delay this sample's command.
            self._want_version = True
            log.info("mk_data_resumed", port=self.port)
        waiter = self._sample_waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _on_confirm(self, frame_no: int, t_ns: int) -> None:
        sent_ns = self._pending_confirms.pop(frame_no, None)
        if sent_ns is None:
            return
        self.stats.confirms += 1
        self._confirm_event.set()
        self.stats.rtt_ns.append(t_ns - sent_ns)
        horizon = t_ns - CONFIRM_TIMEOUT_NS
        for no, t_sent in list(self._pending_confirms.items()):
            if t_sent < horizon:
                del self._pending_confirms[no]
                self.stats.confirms_lost += 1

    def _on_version(self, version: VersionInfo) -> None:
        previous = self.version
        self.version = version
        self.stats.versions += 1
        self._version_event.set()
        if previous is not None and self.stats.stale_events:
            log.warning("fc_version_again", port=self.port, version=version.text)

    def _fail(self, err: LinkError) -> None:
        if self._error is None:
            self._error = err
        self._version_event.set()
        self._confirm_event.set()
        waiter = self._sample_waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise self._error

    # ----- the consumer's side ---------------------------------------------------------

    @property
    def error(self) -> LinkError | None:
        """The error that ended the link, if any."""
        return self._error

    def stale_for_s(self) -> float:
        """Seconds since the last DebugOut (inf before the first)."""
        if self._last_sample_ns is None:
            return float("inf")
        return (self._clock.now_ns() - self._last_sample_ns) / NS_PER_S

    async def next_sample(self, timeout_s: float | None = None) -> ImuSample:
        """The next DebugOut as an :class:`ImuSample`, renewing the subscription as due.

        While waiting, re-subscribes every ``stale_s`` without data (and asks for the
        version again once per stale episode).

        Raises:
            LinkError: the link failed, or nothing arrived within ``timeout_s``.
        """
        s = self._settings
        now = self._clock.now_ns()
        if now - self._last_subscribe_ns >= int(s.resubscribe_s * NS_PER_S):
            self.subscribe()
        if self._want_version:
            self._want_version = False
            self._send("v", version_request())
        started = now
        while not self._samples:
            self._raise_if_failed()
            now = self._clock.now_ns()
            last = self._last_sample_ns if self._last_sample_ns is not None else started
            since_data = (now - max(last, self._last_subscribe_ns)) / NS_PER_S
            if since_data >= s.stale_s:
                self._on_stale()
                since_data = 0.0
            wait_s = s.stale_s - since_data
            if timeout_s is not None:
                left_s = timeout_s - (now - started) / NS_PER_S
                if left_s <= 0:
                    msg = f"no DebugOut from {self.port} for {timeout_s:g} s"
                    raise LinkError(msg)
                wait_s = min(wait_s, left_s)
            # Await the bare future (asyncio.wait_for would add an event-loop turn to
            # every sample's path); a timer resolves it when the wait is over.
            loop = asyncio.get_running_loop()
            waiter = self._sample_waiter = loop.create_future()
            timer = loop.call_later(max(wait_s, 0.001), _resolve, waiter)
            try:
                await waiter
            finally:
                timer.cancel()
                self._sample_waiter = None
        return self._samples.popleft()

    def _on_stale(self) -> None:
        if not self._stale:
            self._stale = True
            self.stats.stale_events += 1
            log.warning("mk_data_stale", port=self.port, stale_s=self._settings.stale_s)
            self._send("v", version_request())
        self.subscribe()

    async def samples(self, timeout_s: float | None = None) -> AsyncIterator[ImuSample]:
        """Iterate over DebugOut samples (see :meth:`next_sample`)."""
        while True:
            yield await self.next_sample(timeout_s)

    # ----- sending ---------------------------------------------------------------------

    def send_extern_control(self, command: ExternControl) -> int:
        """Send one ExternControl now, numbered for a confirm; return its Frame number.

        The command is encoded (and so range-checked: :class:`CommandRangeError`) before
        anything is written. Raises :class:`LinkError` if the port is gone.
        """
        self._raise_if_failed()
        payload = bytearray(command.pack())  # range-checks every field, or raises
        self._frame_no = self._frame_no % 255 + 1
        payload[EXTERN_FRAME_OFFSET] = self._frame_no
        data = encode_frame(command.addr, CMD_EXTERN, bytes(payload))
        t_ns = self._send("b", data, self._frame_no)
        self._pending_confirms[self._frame_no] = t_ns
        self.stats.commands_sent += 1
        return self._frame_no

    async def wait_confirm(self, frame_no: int, timeout_s: float) -> bool:
        """Wait until the confirm of ``frame_no`` arrives; False if it did not in time."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while frame_no in self._pending_confirms:
            self._raise_if_failed()
            self._confirm_event.clear()
            left_s = deadline - loop.time()
            if left_s <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._confirm_event.wait(), left_s)
        return True

    async def release(self, *, quick: bool = False) -> int:
        """Hand control back: neutral Config = 0 frames; return how many were confirmed.

        ``quick`` spaces the frames by the minimum gap only and does not wait for the
        confirms (for a port where no FC ever answered).
        """
        s = self._settings
        before = self.stats.confirms
        interval_s = s.min_frame_gap_s + 0.001 if quick else s.release_interval_s
        for i in range(s.release_frames):
            self.send_extern_control(ExternControl.neutral())
            if i + 1 < s.release_frames:
                await asyncio.sleep(interval_s)
        if not quick:
            # The last confirm may queue behind a DebugOut (up to ~16 ms on the wire).
            await self.wait_confirm(self._frame_no, RELEASE_CONFIRM_WAIT_S)
        confirmed = self.stats.confirms - before
        log.info("mk_released", port=self.port, frames=s.release_frames, confirmed=confirmed)
        return confirmed

    def _send(self, kind: str, data: bytes, frame_no: int = 0) -> int:
        """Write one frame now if the gap allows, else queue it; return the write time."""
        now = self._clock.now_ns()
        gap_ns = int(self._settings.min_frame_gap_s * NS_PER_S)
        if not self._outbox and now - self._last_write_ns >= gap_ns:
            self._write_now(kind, data)
            return now
        if kind == "b":
            # A newer command supersedes a queued one, and goes ahead of requests.
            for old_kind, _, old_no in self._outbox:
                if old_kind == "b":
                    self._pending_confirms.pop(old_no, None)
            self._outbox = deque(item for item in self._outbox if item[0] != "b")
            self._outbox.appendleft((kind, data, frame_no))
        else:
            self._outbox.append((kind, data, frame_no))
        self.stats.delayed_writes += 1
        self._arm_outbox()
        return max(now, self._last_write_ns + gap_ns)

    def _write_now(self, kind: str, data: bytes) -> None:
        t_ns = self._clock.now_ns()
        try:
            self._stream.write(data)
        except LinkError as err:
            self._fail(err)
            raise
        self._last_write_ns = t_ns
        self.stats.frames_written += 1
        self.stats.bytes_written += len(data)
        if self._tap is not None:
            self._tap("w", t_ns, data)

    def _arm_outbox(self) -> None:
        if self._outbox_timer is not None or not self._outbox:
            return
        gap_ns = int(self._settings.min_frame_gap_s * NS_PER_S)
        delay_s = max(0.0, (self._last_write_ns + gap_ns - self._clock.now_ns()) / NS_PER_S)
        self._outbox_timer = asyncio.get_running_loop().call_later(delay_s, self._flush_outbox)

    def _flush_outbox(self) -> None:
        self._outbox_timer = None
        if not self._outbox or self._error is not None:
            self._outbox.clear()
            return
        kind, data, _ = self._outbox.popleft()
        with contextlib.suppress(LinkError):
            self._write_now(kind, data)
        self._arm_outbox()

    def _cancel_outbox(self) -> None:
        if self._outbox_timer is not None:
            self._outbox_timer.cancel()
            self._outbox_timer = None
        self._outbox.clear()
