"""The asynchronous FlightCtrl link: version, DebugOut subscription, ExternControl, release.

One :class:`MkLink` owns one :class:`~mkflight.io.stream.ByteStream`. A reader task feeds
every received chunk to the sans-I/O :class:`~mkflight.mk.codec.FrameParser` and files
the frames: DebugOut becomes a timestamped :class:`~mkflight.msgs.ImuSample` for the
consumer, 'V' answers the version request, 'B' confirms are matched to the ExternControl
frames they answer (round-trip time). Frames of other addresses (the ``#dk`` compass
frames) and unknown commands are counted and dropped (``mk-serial.md`` §2.1, §7.6).

Safety rules (``mk-serial.md`` §7-8; SPEC §2, §5):

* The subscription is renewed from :meth:`MkLink.next_sample`, i.e. by the consumer
  asking for its next sample: a stalled control step stops refreshing the FC's hold on
  the last extern command, and the FC falls back to the pilot's sticks.
* No DebugOut for ``stale_s``: re-subscribe (and ask the version again). Still none after
  ``release_after_stale_s`` while we had control: hand control back (Config = 0) and stop
  renewing for the FC's hold time, so that even an FC whose transmitter died but whose
  receiver works ends extern control.
* Handing back is sticky: after :meth:`MkLink.release`, a stale-data release, a re-open or
  :meth:`MkLink.close`, a command that takes control raises until the flight logic calls
  :meth:`MkLink.allow_control` (SPEC §5: never re-engage just because data came back).
* The link is the last gate on commands: gas in [0, gas_max], nick/roll/yaw within
  +-127, address 1, whatever the caller computed; packing raises, never wraps.
* :meth:`MkLink.close` always tries to hand back (Config = 0, ``release_frames`` times)
  while the port is writable, also after a crash of the reader, and finishes even if the
  task closing it is cancelled.
* Frames are spaced by :class:`~mkflight.mk.outbox.Outbox` (one per write, >= 3 ms after
  the previous frame left the wire).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator

import structlog

from mkflight.clock import Clock, MonotonicClock
from mkflight.errors import CommandRangeError, LinkError, ProtocolError
from mkflight.io.stream import ByteStream
from mkflight.mk.codec import ADDR_FC, Frame, FrameParser, encode_frame
from mkflight.mk.link_types import NS_PER_S, LinkSettings, LinkStats, Opener, Tap
from mkflight.mk.messages import (
    CMD_CONFIRM,
    CMD_DEBUG_ANSWER,
    CMD_EXTERN,
    CMD_LABEL_ANSWER,
    CMD_PPM_ANSWER,
    CMD_VERSION_ANSWER,
    EC_VALID,
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
from mkflight.mk.outbox import Outbox
from mkflight.mk.units import MkCalibration, imu_from_debug
from mkflight.msgs import ImuSample

__all__ = ["NS_PER_S", "LinkSettings", "LinkStats", "MkLink"]

log = structlog.get_logger("mkflight.mk")

CONFIRM_TIMEOUT_NS = NS_PER_S  # a confirm not back within this is counted lost
RELEASE_CONFIRM_WAIT_S = 0.1  # wait for the last release frame's confirm (behind a DebugOut)
FC_HOLD_S = 5.5  # the FC drops extern control ~5.2 s after the last hold frame (§7.4)
_OFF = -(10**18)


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
        self._latest: ImuSample | None = None
        self._sample_waiter: asyncio.Future[None] | None = None
        self._version_event = asyncio.Event()
        self._confirm_event = asyncio.Event()
        self._error: LinkError | None = None  # what consumers get
        self._port_dead = False  # the stream itself failed: nothing can be written
        self._reader: asyncio.Task[None] | None = None
        self._frame_no = 0
        self._pending_confirms: dict[int, int] = {}
        self._last_subscribe_ns = _OFF
        self._last_sample_ns: int | None = None
        self._stale = False
        self._want_version = False
        self._engaged = False  # a command with Config bit 0 went out since the last release
        self._blocked: str | None = None  # why taking control is refused, if it is
        self._renew_after_ns = _OFF  # no 'd' before this (after a stale-data release)
        self._closing: asyncio.Task[None] | None = None
        self._outbox = Outbox(
            self._write_now, baudrate=settings.baudrate, gap_s=settings.min_frame_gap_s
        )
        self._outbox.on_superseded = self._on_superseded

    # ----- lifecycle -------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader task (idempotent)."""
        if self._closing is not None:
            return
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
        """Send the DebugOut subscription 'd' (also renews it and the FC's hold)."""
        self.start()
        if self._clock.now_ns() < self._renew_after_ns:
            return  # after a stale-data release: no hold refresh yet (_release_stale)
        self._send("d", debug_request(self._settings.debug_interval_10ms))
        self._last_subscribe_ns = self._clock.now_ns()
        self.stats.subscriptions += 1

    async def close(self, *, release: bool = True) -> None:
        """Hand control back (Config = 0, several times), stop the stream, close the port.

        The work runs in its own task: cancelling the caller does not cut it short.
        """
        if self._closing is None:
            self._closing = asyncio.get_running_loop().create_task(
                self._shutdown(release), name=f"mk-close {self.port}"
            )
        await asyncio.shield(self._closing)

    async def _shutdown(self, release: bool) -> None:
        self._blocked = "link closed"
        try:
            if release and not self._port_dead:
                with contextlib.suppress(LinkError):
                    # Nothing answered: still hand back (it may be a half-working FC), but
                    # quickly, so that "no FlightCtrl answered" is not delayed.
                    await self.release(quick=self.version is None)
            if not self._port_dead:
                with contextlib.suppress(LinkError):
                    self._send("d", debug_request(0))  # stop the stream (it would expire)
                    await self._outbox.drained()
        finally:
            self._outbox.cancel()
            await self._stop_reader()
            with contextlib.suppress(LinkError, OSError):
                await self._stream.close()
            self._port_dead = True
            self._fail(LinkError(f"{self.port}: link closed"))

    async def _stop_reader(self) -> None:
        reader, self._reader = self._reader, None
        if reader is not None and not reader.done():
            reader.cancel()
        if reader is not None:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await reader

    async def __aenter__(self) -> MkLink:
        self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def reopen(self, max_wait_s: float = 30.0) -> VersionInfo:
        """Re-open a vanished port with exponential back-off, then version + subscription.

        The FC may still hold the command from before the loss: the link hands control
        back before it renews anything, and taking control needs :meth:`allow_control`.

        Raises:
            LinkError: closed, no opener, or the port did not come back in ``max_wait_s``.
        """
        if self._closing is not None:
            msg = f"{self.port}: link closed"
            raise LinkError(msg)
        if self._opener is None:
            msg = f"{self.port}: no way to re-open this link"
            raise LinkError(msg)
        await self._stop_reader()
        self._drop_confirms(self._outbox.cancel())
        with contextlib.suppress(LinkError, OSError):
            await self._stream.close()
        self._port_dead = True
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
        self._port_dead = False
        self._latest = None
        self.stats.reopens += 1
        log.warning("mk_reopened", port=self.port, reopens=self.stats.reopens)
        version = await self.connect()
        await self.release()
        self._blocked = "port re-opened"
        self._renew_after_ns = _OFF
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
            self._port_dead = True
            self._fail(err)
        except asyncio.CancelledError:
            raise
        except Exception as err:  # a bug: consumers must not wait forever; close() releases
            log.exception("mk_reader_crashed", port=self.port)
            self._blocked = "the link's reader crashed"
            self._fail(LinkError(f"{self.port}: reader crashed: {err!r}"))

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
        if self._latest is not None:
            self.stats.samples_dropped += 1  # the consumer fell behind: newest wins
        self._latest = imu_from_debug(debug, t_ns, self._cal)
        if self._stale:
            self._stale = False
            self._renew_after_ns = _OFF
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
        self.stats.rtt_ns.append(t_ns - sent_ns)
        self._confirm_event.set()

    def _expire_confirms(self, now_ns: int) -> None:
        horizon = now_ns - CONFIRM_TIMEOUT_NS
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

    @property
    def control_blocked(self) -> str | None:
        """Why commands that take control are refused (None: they are allowed)."""
        return self._blocked

    def stale_for_s(self) -> float:
        """Seconds since the last DebugOut (inf before the first)."""
        if self._last_sample_ns is None:
            return float("inf")
        return (self._clock.now_ns() - self._last_sample_ns) / NS_PER_S

    async def next_sample(self, timeout_s: float | None = None) -> ImuSample:
        """The newest DebugOut as an :class:`ImuSample`, renewing the subscription as due.

        Older samples the consumer did not pick up are skipped (counted as dropped). While
        waiting: re-subscribe every ``stale_s`` without data; after ``release_after_stale_s``
        with control taken, hand it back (see the module docstring).

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
        while self._latest is None:
            self._raise_if_failed()
            now = self._clock.now_ns()
            last = self._last_sample_ns if self._last_sample_ns is not None else started
            stale_s = (now - last) / NS_PER_S
            since_renewal_s = (now - max(last, self._last_subscribe_ns)) / NS_PER_S
            if self._engaged and stale_s >= s.release_after_stale_s:
                await self._release_stale()
                continue
            if since_renewal_s >= s.stale_s and now >= self._renew_after_ns:
                self._on_stale()
                since_renewal_s = 0.0
            wait_s = s.stale_s - since_renewal_s
            if self._engaged:
                wait_s = min(wait_s, s.release_after_stale_s - stale_s)
            if timeout_s is not None:
                left_s = timeout_s - (now - started) / NS_PER_S
                if left_s <= 0:
                    msg = f"no DebugOut from {self.port} for {timeout_s:g} s"
                    raise LinkError(msg)
                wait_s = min(wait_s, left_s)
            await self._wait_for_sample(max(wait_s, 0.001))
        sample, self._latest = self._latest, None
        return sample

    async def _wait_for_sample(self, wait_s: float) -> None:
        # Await the bare future (asyncio.wait_for would add an event-loop turn to every
        # sample's path); a timer resolves it when the wait is over.
        loop = asyncio.get_running_loop()
        waiter = self._sample_waiter = loop.create_future()
        timer = loop.call_later(wait_s, _resolve, waiter)
        try:
            await waiter
        finally:
            timer.cancel()
            self._sample_waiter = None

    def _on_stale(self) -> None:
        if not self._stale:
            self._stale = True
            self.stats.stale_events += 1
            log.warning("mk_data_stale", port=self.port, stale_s=self._settings.stale_s)
            self._send("v", version_request())
        self.subscribe()

    async def _release_stale(self) -> None:
        """No data for ``release_after_stale_s`` with control taken: the pilot's sticks rule."""
        self.stats.stale_releases += 1
        log.error("mk_stale_release", port=self.port, stale_s=self.stale_for_s())
        await self.release()
        self._blocked = "no DebugOut: control handed back to the pilot"
        # Renewing 'd' would reload the FC's hold on a command our release may not have
        # reached: stay quiet until the FC has certainly dropped it.
        self._renew_after_ns = self._clock.now_ns() + int(FC_HOLD_S * NS_PER_S)

    async def samples(self, timeout_s: float | None = None) -> AsyncIterator[ImuSample]:
        """Iterate over DebugOut samples (see :meth:`next_sample`)."""
        while True:
            yield await self.next_sample(timeout_s)

    # ----- sending ---------------------------------------------------------------------

    def allow_control(self) -> None:
        """Let commands take control again after a release (the flight logic's decision)."""
        if self._closing is None:
            self._blocked = None

    def send_extern_control(self, command: ExternControl) -> int:
        """Send one ExternControl, numbered for a confirm; return its Frame number.

        The command is checked against mkflight's limits and packed (which range-checks
        every field) before anything is written.

        Raises:
            CommandRangeError: a field is non-finite, non-integral or beyond the limits.
            LinkError: the port is gone, or control was handed back (``control_blocked``).
        """
        if self._port_dead:
            raise self._error or LinkError(f"{self.port}: port closed")
        payload = bytearray(command.pack())  # range-checks every field, or raises
        self._check_limits(command)
        takes_control = bool(payload[10] & EC_VALID)
        if takes_control and self._blocked is not None:
            msg = f"{self.port}: not taking control: {self._blocked}"
            raise LinkError(msg)
        self._frame_no = self._frame_no % 255 + 1
        payload[EXTERN_FRAME_OFFSET] = self._frame_no
        data = encode_frame(ADDR_FC, CMD_EXTERN, bytes(payload))
        self._expire_confirms(self._clock.now_ns())
        self._send("b", data, self._frame_no)
        self._engaged = self._engaged or takes_control
        self.stats.commands_sent += 1
        return self._frame_no

    def _check_limits(self, command: ExternControl) -> None:
        s = self._settings
        for name in ("nick", "roll", "yaw"):
            value = getattr(command, name)
            if abs(value) > s.stick_max_counts:
                msg = f"ExternControl.{name} = {value} beyond +-{s.stick_max_counts}"
                raise CommandRangeError(msg)
        if not 0 <= command.gas <= s.gas_max or not math.isfinite(command.gas):
            msg = f"ExternControl.gas = {command.gas} outside 0..{s.gas_max} (control.gas_max)"
            raise CommandRangeError(msg)

    async def wait_confirm(self, frame_no: int, timeout_s: float) -> bool:
        """Wait until the confirm of ``frame_no`` arrives; False if it did not in time."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while frame_no in self._pending_confirms or self._outbox.pending:
            self._raise_if_failed()
            self._confirm_event.clear()
            left_s = deadline - loop.time()
            if left_s <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._confirm_event.wait(), min(left_s, 0.01))
        return True

    async def release(self, *, quick: bool = False) -> int:
        """Hand control back: neutral Config = 0 frames; return how many were confirmed.

        Afterwards commands that take control are refused until :meth:`allow_control`.
        ``quick`` sends the frames back to back (spaced by the line only) and does not
        wait for confirms: for a port where no FC ever answered.
        """
        s = self._settings
        self._blocked = self._blocked or "control released"
        self._drop_confirms(self._outbox.cancel())  # no queued command may follow
        before = self.stats.confirms
        for i in range(s.release_frames):
            self.send_extern_control(ExternControl.neutral())
            await self._outbox.drained()  # each frame on the wire (none superseded)
            if not quick and i + 1 < s.release_frames:
                await asyncio.sleep(s.release_interval_s)
        self._engaged = False
        if not quick:
            # The last confirm may queue behind a DebugOut (up to ~16 ms on the wire).
            await self.wait_confirm(self._frame_no, RELEASE_CONFIRM_WAIT_S)
        confirmed = self.stats.confirms - before
        log.info("mk_released", port=self.port, frames=s.release_frames, confirmed=confirmed)
        return confirmed

    async def drain(self) -> None:
        """Wait until every frame sent so far has been written and has left the wire."""
        await self._outbox.drained()

    def _send(self, kind: str, data: bytes, frame_no: int = 0) -> None:
        self._outbox.send(kind, data, frame_no)
        self.stats.delayed_writes = self._outbox.delayed

    def _write_now(self, kind: str, data: bytes, frame_no: int) -> None:
        """The outbox's writer: one frame to the port, now."""
        t_ns = self._clock.now_ns()
        try:
            self._stream.write(data)
        except LinkError as err:
            self._port_dead = True
            self._fail(err)
            raise
        if frame_no:
            self._pending_confirms[frame_no] = t_ns
        self.stats.frames_written += 1
        self.stats.bytes_written += len(data)
        if self._tap is not None:
            self._tap("w", t_ns, data)

    def _on_superseded(self, frame_no: int) -> None:
        self.stats.superseded_commands += 1
        self._pending_confirms.pop(frame_no, None)

    def _drop_confirms(self, frame_numbers: list[int]) -> None:
        for no in frame_numbers:
            self._pending_confirms.pop(no, None)
