"""The asynchronous FlightCtrl link: version, DebugOut subscription, ExternControl, release.

One :class:`MkLink` owns one :class:`~mkflight.io.stream.ByteStream`. A reader task feeds
every received chunk to the sans-I/O :class:`~mkflight.mk.codec.FrameParser` and files
the frames: DebugOut becomes a timestamped :class:`~mkflight.msgs.ImuSample` for the
consumer, 'V' answers the version request, 'B' confirms are matched to the ExternControl
frames they answer (round-trip time). Frames of other addresses (the ``#dk`` compass
frames) and unknown commands are counted and dropped (``mk-serial.md`` §2.1, §7.6).

The link keeps the port, the reader, the version handshake and the lifecycle; behind its
own public methods it delegates the receiving side to
:class:`~mkflight.mk.subscription.DebugSubscription` (the newest sample, renewal,
staleness) and the sending side to :class:`~mkflight.mk.sender.CommandSender` (numbered
ExternControl, confirms, the last gate on limits, the sticky hand-back, frame spacing).

Safety rules (``mk-serial.md`` §7-8; SPEC §2, §5): each side states its own. The link's:
:meth:`MkLink.close` always tries to hand back (Config = 0, ``release_frames`` times)
while the port is writable, also after a crash of the reader, and finishes even if the
task closing it is cancelled; :meth:`MkLink.reopen` hands back before it renews anything.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Coroutine
from typing import Any

import structlog

from mkflight.clock import Clock, MonotonicClock
from mkflight.conversions import NS_PER_S
from mkflight.errors import LinkError, ProtocolError
from mkflight.io.reopen import open_with_backoff
from mkflight.io.stream import ByteStream, PushStream
from mkflight.mk.codec import ADDR_FC, Frame, FrameParser
from mkflight.mk.link_types import LinkSettings, LinkStats, Opener, Tap
from mkflight.mk.messages import (
    CMD_CONFIRM,
    CMD_DEBUG_ANSWER,
    CMD_LABEL_ANSWER,
    CMD_PPM_ANSWER,
    CMD_VERSION_ANSWER,
    Confirm,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
    VersionInfo,
    ppm_request,
    version_request,
)
from mkflight.mk.sender import CommandSender
from mkflight.mk.subscription import DebugSubscription
from mkflight.mk.units import MkCalibration
from mkflight.msgs import ImuSample

__all__ = ["LinkSettings", "LinkStats", "MkLink"]

log = structlog.get_logger("mkflight.mk")


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
        self._clock: Clock = clock or MonotonicClock()
        self._opener = reopen
        self._tap = tap
        self.stats = LinkStats()
        self._parser = FrameParser()
        self.stats.parser = self._parser.stats
        self.port = stream.name
        self.version: VersionInfo | None = None
        self._last_debug_frame: Frame | None = None
        self.last_ppm: Ppm | None = None
        self.labels: dict[int, str] = {}
        self._version_event = asyncio.Event()
        self._error: LinkError | None = None  # what consumers get
        self._port_dead = False  # the stream itself failed: nothing can be written
        self._reader: asyncio.Task[None] | None = None
        self._pushed = False  # the stream hands chunks to _on_chunk (no reader task)
        self._push: PushStream | None = _push_stream(stream)
        self._closing: asyncio.Task[None] | None = None
        self._tx = CommandSender(
            self._write_now,
            settings,
            self.stats,
            self._clock,
            port=self.port,
            check_writable=self._check_writable,
            check_failed=self._raise_if_failed,
        )
        self._rx = DebugSubscription(
            self._tx,
            settings,
            self.stats,
            calibration,
            self._clock,
            port=self.port,
            start=self.start,
            check_failed=self._raise_if_failed,
        )

    # ----- lifecycle -------------------------------------------------------------------

    def start(self) -> None:
        """Start reading (idempotent).

        In the port's own callback if it offers one (:class:`PushStream`), else in a
        reader task.
        """
        if self._closing is not None or self._pushed:
            return
        if self._push is not None:
            self._pushed = True  # each chunk parsed as it arrives: no task woken per chunk
            self._push.deliver_to(self._on_chunk, self._on_end)
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
            self._tx.send("v", version_request())
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
        self._rx.subscribe()

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
        self._tx.block("link closed")
        try:
            if release and not self._port_dead:
                with contextlib.suppress(LinkError):
                    # Nothing answered: still hand back (it may be a half-working FC), but
                    # quickly, so that "no FlightCtrl answered" is not delayed.
                    await self.release(quick=self.version is None)
            if not release:
                self._tx.drop_queued()  # a command still waiting for the line stays unsent
            if not self._port_dead:
                with contextlib.suppress(LinkError):
                    self._rx.unsubscribe()  # stop the stream (it would expire)
                    await self._tx.drained()
        finally:
            self._tx.stop()
            await self._stop_reader()
            with contextlib.suppress(LinkError, OSError):
                await self._stream.close()
            self._port_dead = True
            self._fail(LinkError(f"{self.port}: link closed"))

    async def _stop_reader(self) -> None:
        if self._pushed:
            self._stop_pushing()
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
        self._tx.drop_queued()
        with contextlib.suppress(LinkError, OSError):
            await self._stream.close()
        self._port_dead = True
        self._stream = await open_with_backoff(
            self._opener,
            port=self.port,
            max_wait_s=max_wait_s,
            backoff_s=self._settings.reopen_backoff_s,
            backoff_max_s=self._settings.reopen_backoff_max_s,
            log_event="mk_reopen_retry",
            now_ns=self._clock.now_ns,
        )
        self._push = _push_stream(self._stream)
        self._parser.reset()
        self._error = None
        self._port_dead = False
        self._rx.forget_sample()
        self.stats.reopens += 1
        log.warning("mk_reopened", port=self.port, reopens=self.stats.reopens)
        version = await self.connect()
        await self.release()
        self._tx.block("port re-opened")
        self._rx.resume_renewals()
        self.subscribe()
        return version

    # ----- receiving -------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                self._take(await self._stream.read())
        except LinkError as err:
            self._port_dead = True
            self._fail(err)
        except asyncio.CancelledError:
            raise
        except Exception as err:  # a bug: consumers must not wait forever; close() releases
            log.exception("mk_reader_crashed", port=self.port)
            self._tx.block("the link's reader crashed")
            self._fail(LinkError(f"{self.port}: reader crashed: {err!r}"))

    def _on_chunk(self, data: bytes) -> None:
        """A chunk the port handed over as it arrived: what _read_loop does with one."""
        try:
            self._take(data)
        except Exception as err:  # a bug: as _read_loop's; a later start() reads again
            self._stop_pushing()
            log.exception("mk_reader_crashed", port=self.port)
            self._tx.block("the link's reader crashed")
            self._fail(LinkError(f"{self.port}: reader crashed: {err!r}"))

    def _take(self, data: bytes) -> None:
        """One chunk read: stamped, recorded, its frames filed, a new sample handed on.

        A frame that fell due before the chunk arrived goes out first (see
        :meth:`~mkflight.mk.outbox.Outbox.flush_due`): what the FC said cannot reorder what
        we had already decided to send.
        """
        self._tx.flush_due()
        t_ns = self._clock.now_ns()
        if self._tap is not None:
            self._tap("r", t_ns, data)
        for frame in self._parser.feed(data):
            self._dispatch(frame, t_ns)
        self._rx.deliver()

    def _on_end(self, err: LinkError) -> None:
        """The port handed over its end (it vanished, or it was closed)."""
        self._pushed = False
        self._port_dead = True
        self._fail(err)

    def _stop_pushing(self) -> None:
        self._pushed = False
        if self._push is not None:
            self._push.deliver_to(None, None)

    def _dispatch(self, frame: Frame, t_ns: int) -> None:
        stats = self.stats
        if frame.addr != ADDR_FC:
            stats.foreign_frames += 1
            return
        try:
            if frame.cmd == CMD_DEBUG_ANSWER:
                analog = DebugOut.analog_of(frame)
                self._last_debug_frame = frame  # decoded whole only if asked for
                self._rx.on_debug(analog, t_ns)
            elif frame.cmd == CMD_CONFIRM:
                self._tx.on_confirm(Confirm.decode(frame).frame, t_ns)
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
        self._tx.wake()
        self._rx.wake()

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise self._error

    def _check_writable(self) -> None:
        if self._port_dead:
            raise self._error or LinkError(f"{self.port}: port closed")

    # ----- the consumer's side ---------------------------------------------------------

    @property
    def last_debug(self) -> DebugOut | None:
        """The newest DebugOut received (None before the first)."""
        frame = self._last_debug_frame
        return None if frame is None else DebugOut.decode(frame)

    @property
    def error(self) -> LinkError | None:
        """The error that ended the link, if any."""
        return self._error

    @property
    def closed(self) -> bool:
        """:meth:`close` has stopped the reader: nothing more is read from the port."""
        return self._closing is not None and self._reader is None and not self._pushed

    @property
    def control_blocked(self) -> str | None:
        """Why commands that take control are refused (None: they are allowed)."""
        return self._tx.blocked

    def set_blind_command(self, provider: Callable[[], ExternControl | None] | None) -> None:
        """Who says what the FC should fly if the DebugOut stops (None: nobody).

        Asked once when the data goes stale (the flight: level, the hover gas now), so
        nothing is built on the step's path; its answer (None: nothing) is sent only while
        we have control, numbered for a confirm (see :mod:`mkflight.mk.subscription`).
        """
        self._rx.blind_command = provider

    def stale_for_s(self) -> float:
        """Seconds since the last DebugOut (inf before the first)."""
        return self._rx.stale_for_s()

    def next_sample(self, timeout_s: float | None = None) -> Coroutine[Any, Any, ImuSample]:
        """The newest DebugOut as an :class:`ImuSample`, renewing the subscription as due.

        Older samples the consumer did not pick up are skipped (counted as dropped). While
        waiting: re-subscribe every ``stale_s`` without data; after ``release_after_stale_s``
        with control taken, hand it back (see :mod:`mkflight.mk.subscription`).

        Raises:
            LinkError: the link failed, or nothing arrived within ``timeout_s``.
        """
        return self._rx.next_sample(timeout_s)  # its coroutine: one frame less to resume

    async def serve(
        self, on_sample: Callable[[ImuSample], bool], timeout_s: float | None = None
    ) -> None:
        """Hand every newest DebugOut to ``on_sample`` until it returns True.

        As :meth:`next_sample` in a loop (renewal, staleness, the release, the timeout),
        but while it waits each sample is handed over in the callback that read it: no
        event-loop turn per sample (see :mod:`mkflight.mk.subscription`).

        Raises:
            LinkError: the link failed, or nothing arrived within ``timeout_s``.
            Exception: whatever ``on_sample`` raised.
        """
        await self._rx.serve(on_sample, timeout_s)

    # ----- sending (delegated to the CommandSender, mkflight.mk.sender) -----------------

    def allow_control(self) -> None:
        """Let commands take control again after a release (the flight logic's decision)."""
        if self._closing is None:
            self._tx.allow_control()

    def send_extern_control(self, command: ExternControl, *, confirm: bool = False) -> int:
        """Send one ExternControl; return its Frame number (0: no confirm asked).

        A command that takes control is numbered for a confirm once in
        ``mk.confirm_every`` (each confirm costs a wake-up); one with Config = 0, or with
        ``confirm``, always is (see :mod:`mkflight.mk.sender`). The command is checked
        against mkflight's limits and packed (which range-checks every field) before
        anything is written.

        Raises:
            CommandRangeError: a field is non-finite, non-integral or beyond the limits.
            LinkError: the port is gone, or control was handed back (``control_blocked``).
        """
        return self._tx.send_extern_control(command, confirm=confirm)

    def send_sticks(self, nick: int, roll: int, yaw: int, gas: int, *, take_control: bool) -> int:
        """:meth:`send_extern_control` of the command with these counts (the rest 0).

        Without building an :class:`ExternControl` when they are ints within the limits:
        the flight step's path, one a step. The same frame, checks and errors.
        """
        return self._tx.send_sticks(nick, roll, yaw, gas, take_control=take_control)

    def request_ppm(self) -> None:
        """Ask for the pilot's receiver channels ('p'); the answer lands in ``last_ppm``."""
        self._tx.send("p", ppm_request())

    async def wait_confirm(self, frame_no: int, timeout_s: float) -> bool:
        """Wait until the confirm of ``frame_no`` arrives; False if it did not in time."""
        return await self._tx.wait_confirm(frame_no, timeout_s)

    async def release(self, *, quick: bool = False) -> int:
        """Hand control back: neutral Config = 0 frames; return how many were confirmed.

        Afterwards commands that take control are refused until :meth:`allow_control`.
        ``quick`` sends the frames back to back (spaced by the line only) and does not
        wait for confirms: for a port where no FC ever answered.
        """
        return await self._tx.release(quick=quick)

    async def drain(self) -> None:
        """Wait until every frame sent so far has been written and has left the wire."""
        await self._tx.drained()

    def _write_now(self, kind: str, data: bytes, frame_no: int) -> None:
        """The outbox's writer: one frame to the port, now."""
        t_ns = self._clock.now_ns()
        try:
            self._stream.write(data)
        except LinkError as err:
            self._port_dead = True
            self._fail(err)
            raise
        self._tx.written(frame_no, t_ns)
        self.stats.frames_written += 1
        self.stats.bytes_written += len(data)
        if self._tap is not None:
            self._tap("w", t_ns, data)


def _push_stream(stream: ByteStream) -> PushStream | None:
    """``stream`` if it hands chunks over as they arrive (asked once: a costly check)."""
    return stream if isinstance(stream, PushStream) else None
