"""The asynchronous URG-04LX driver: SCIP 2.0 start-up, MD streaming, stamping, recovery.

One :class:`UrgDriver` owns one :class:`~mkflight.io.stream.ByteStream`. A reader task
feeds the sans-I/O :class:`~mkflight.urg.replies.ReplyParser`; replies to requests are
matched by their echo, scan messages of the current stream (recognised by the ``;tag``
the driver puts in every MD) become :class:`~mkflight.msgs.Scan` records.

Start-up follows ``scip2.md`` §6: QT and drain until ~150 ms of silence (the sensor may
still stream from an earlier run), ``SCIP2.0`` (``0`` or ``0E`` both mean success),
``TM2`` if a command is refused with ``0E`` (time-adjust mode), ``RS`` (laser off, timer
to 0), ``VV``/``PP``/``II`` (the seven PP keys are required and used), then ``MD`` over
the steps the configuration needs (scan and hat steps), every scan, until ``QT``.

Stamping (:mod:`mkflight.urg.stamping`): each scan is stamped with the host time at which
its front step (AFRT) was measured, mapped from its unwrapped 24-bit sensor timestamp by
:class:`~mkflight.urg.timesync.SensorClock`, not with the time it arrived.

Recovery (§6 items 3-5, 8): a scan with a bad sum is dropped and counted, a run of them
re-issues MD; no scan for ``stall_s`` re-issues MD (QT, drain, MD with a new tag); error
statuses in a stream re-issue MD and, repeated, fail; a vanished device is a
:class:`~mkflight.errors.LinkError` naming the port, and :meth:`UrgDriver.reopen` tries
again with back-off and the whole start-up. :meth:`UrgDriver.close` sends QT.

Settings: the ``laser`` config section (:class:`~mkflight.config.LaserConfig`); the streamed
steps, start-up information and counters: :mod:`mkflight.urg.driver_types` (re-exported).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable

import structlog

from mkflight.clock import Clock, MonotonicClock
from mkflight.config import LaserConfig
from mkflight.conversions import NS_PER_S
from mkflight.errors import LinkError, ProtocolError
from mkflight.io.reopen import open_with_backoff
from mkflight.io.stream import ByteStream, Opener, PushStream, Tap, resolve_waiter
from mkflight.msgs import Scan
from mkflight.urg.codec import md_command, scip2_command, simple_command, tm_command
from mkflight.urg.driver_types import UrgInfo, UrgStats, streamed_steps
from mkflight.urg.replies import BlockDecoder, InfoReply, Reply, ReplyParser, ScanReply
from mkflight.urg.stamping import ScanStamper
from mkflight.urg.units import URG_04LX, SensorParams, parse_params

__all__ = ["UrgDriver", "UrgInfo", "UrgStats", "streamed_steps"]

log = structlog.get_logger("mkflight.urg")


class UrgDriver:
    """One URG on one byte stream (see the module docstring)."""

    def __init__(
        self,
        stream: ByteStream,
        config: LaserConfig | None = None,
        clock: Clock | None = None,
        *,
        reopen: Opener | None = None,
        tap: Tap | None = None,
    ) -> None:
        self._stream = stream
        self._cfg = config if config is not None else LaserConfig()
        self._first_step, self._last_step = streamed_steps(self._cfg)
        self._clock: Clock = clock or MonotonicClock()
        self._opener = reopen
        self._tap = tap
        self.port = stream.name
        self.stats = UrgStats()
        self._parser = ReplyParser()
        self.stats.parser = self._parser.stats
        self.params: SensorParams = URG_04LX
        self.info: UrgInfo | None = None
        self._stamper = ScanStamper(self._cfg.transport_delay_s)
        self._reader: asyncio.Task[None] | None = None
        self._pushed = False  # the stream hands chunks to _on_chunk (no reader task)
        self._push: PushStream | None = _push_stream(stream)
        self._error: LinkError | None = None
        self._waiters: list[tuple[bytes, asyncio.Future[Reply]]] = []
        self._last_rx_ns = 0
        self._generation = 0
        self._md: bytes | None = None
        self._latest: Scan | None = None
        self._scan_waiter: asyncio.Future[None] | None = None
        self._scan_timer: asyncio.TimerHandle | None = None  # ends the wait (a stall)
        self._inline: Callable[[Scan], None] | None = None  # next_scan's, while it waits
        self._inline_error: Exception | None = None  # what it raised, for next_scan
        self._wait_started = 0.0  # loop time the current wait's timeout counts from
        self._inline_timeout_s: float | None = None
        self._last_scan_ns: int | None = None
        self._sum_errors_seen = 0
        self._restarts_in_a_row = 0
        self._closed = False

    # ----- lifecycle -------------------------------------------------------------------

    def start(self) -> None:
        """Start reading (idempotent).

        In the port's own callback if it offers one (:class:`PushStream`): a scan's
        chunks are parsed as they arrive, with no reader task woken per chunk; else in a
        reader task.
        """
        if self._closed or self._pushed:
            return
        if self._push is not None:
            self._pushed = True
            self._push.deliver_to(self._on_chunk, self._on_end)
            return
        if self._reader is None or self._reader.done():
            self._reader = asyncio.get_running_loop().create_task(
                self._read_loop(), name=f"urg-reader {self.port}"
            )

    def decode_blocks_with(self, decoder: BlockDecoder | None) -> None:
        """Decode scans' data blocks with ``decoder`` (see :class:`ReplyParser`; None: numpy)."""
        self._parser.decode_blocks = decoder

    async def connect(self) -> UrgInfo:
        """The start-up sequence of ``scip2.md`` §6 (without the stream).

        Raises:
            LinkError: the sensor does not answer.
            ProtocolError: it refuses a command or its parameters are incomplete.
        """
        self.start()
        await self._quiet()
        switch = await self._request(scip2_command())
        if switch.status not in ("0", "0E", "00"):
            raise ProtocolError(self._refused(switch))
        reset = await self._request(simple_command("RS"))
        if reset.status == "0E":  # stuck in time-adjust mode (§6 step 4)
            await self._request(tm_command(2))
            reset = await self._request(simple_command("RS"))
        self._check(reset)
        self._stamper.reset()
        try:
            version_info = (await self._info("VV")).info
        except LinkError as err:
            # Some URG-04LX firmware sends a VV line with a wrong sum (scip2.md §6 item 9):
            # the whole reply is dropped. VV is only logged, so go on without it.
            if self._error is not None:
                raise
            log.warning("urg_no_version", port=self.port, error=str(err))
            version_info = {}
        params = parse_params((await self._info("PP")).info)
        status = await self._info("II")
        self.params = params
        self.info = UrgInfo(version_info, params, status.info)
        if not params.amin_step <= self._first_step <= self._last_step <= params.amax_step:
            msg = (
                f"{self.port}: steps {self._first_step}-{self._last_step} outside the "
                f"sensor's {params.amin_step}-{params.amax_step}"
            )
            raise ProtocolError(msg)
        log.info("urg_info", port=self.port, info=self.info.summary)
        return self.info

    async def start_stream(self) -> None:
        """Start MD streaming of every scan (10 Hz) until QT (§6 step 7)."""
        self._generation = (self._generation % 9999) + 1
        self._md = md_command(
            self._first_step, self._last_step, 1, 0, 0, tag=f"g{self._generation}"
        )
        ack = await self._request(self._md)
        self._check(ack)
        self._last_scan_ns = self._clock.now_ns()
        self._sum_errors_seen = self._parser.stats.sum_errors

    async def _restart_stream(self, why: str) -> None:
        """QT, drain, MD with a new tag (§6 items 3-5)."""
        self.stats.restarts += 1
        self._restarts_in_a_row += 1
        if self._restarts_in_a_row > self._cfg.max_restarts:
            msg = (
                f"the laser on {self.port} sends no usable scans: "
                f"{self._cfg.max_restarts} stream restarts in a row ({why})"
            )
            err = LinkError(msg)
            self._fail(err)
            raise err
        log.warning("urg_restart", port=self.port, why=why, restarts=self.stats.restarts)
        self._write(simple_command("QT"))
        await self._quiet()
        await self.start_stream()

    async def close(self) -> None:
        """Stop the stream and the laser (QT), stop the reader, close the port."""
        if self._closed:
            return
        self._closed = True
        if self._error is None:
            with contextlib.suppress(LinkError, ProtocolError, TimeoutError):
                await self._request(simple_command("QT"), timeout_s=0.3)
        self._stop_pushing()
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await reader
        with contextlib.suppress(LinkError, OSError):
            await self._stream.close()
        self._fail(LinkError(f"{self.port}: driver closed"))

    async def reopen(self, max_wait_s: float = 30.0) -> UrgInfo:
        """Re-open a vanished device with exponential back-off, start up and stream again.

        Raises:
            LinkError: closed, no opener, or the device did not come back in ``max_wait_s``.
        """
        if self._closed or self._opener is None:
            msg = f"{self.port}: cannot re-open (closed, or no opener)"
            raise LinkError(msg)
        self._stop_pushing()
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reader
        with contextlib.suppress(LinkError, OSError):
            await self._stream.close()
        self._stream = await open_with_backoff(
            self._opener,
            port=self.port,
            max_wait_s=max_wait_s,
            backoff_s=self._cfg.reopen_backoff_s,
            backoff_max_s=self._cfg.reopen_backoff_max_s,
            log_event="urg_reopen_retry",
        )
        self._push = _push_stream(self._stream)
        self._parser.reset()
        self._error = None
        self._latest = None
        self._restarts_in_a_row = 0
        self.stats.reopens += 1
        info = await self.connect()
        await self.start_stream()
        return info

    async def __aenter__(self) -> UrgDriver:
        self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # ----- requests --------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            self._stream.write(data)
        except LinkError as err:
            self._fail(err)
            raise
        if self._tap is not None:
            self._tap("w", self._clock.now_ns(), data)

    async def _request(self, command: bytes, timeout_s: float | None = None) -> Reply:
        """Send ``command`` and wait for the reply whose echo matches it."""
        if self._error is not None:
            raise self._error
        future: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        entry = (command, future)
        self._waiters.append(entry)
        try:
            self._write(command)
            wait = timeout_s if timeout_s is not None else self._cfg.request_timeout_s
            try:
                return await asyncio.wait_for(future, wait)
            except TimeoutError as err:
                name = command.rstrip(b"\n").decode("ascii", "replace")
                msg = f"no answer to {name} from the laser on {self.port} within {wait:g} s"
                raise LinkError(msg) from err
        finally:
            with contextlib.suppress(ValueError):
                self._waiters.remove(entry)

    async def _info(self, cmd: str) -> InfoReply:
        reply = await self._request(simple_command(cmd))
        self._check(reply)
        if not isinstance(reply, InfoReply):
            msg = f"{self.port}: {cmd} answered without information lines"
            raise ProtocolError(msg)
        return reply

    def _refused(self, reply: Reply) -> str:
        return f"laser on {self.port}: {reply.echo} -> {reply.status} ({reply.message})"

    def _check(self, reply: Reply) -> None:
        if not reply.ok:
            raise ProtocolError(self._refused(reply))

    async def _quiet(self) -> None:
        """Send QT, wait for ``drain_silence_s`` of silence (``drain_max_s`` at most), forget."""
        self._write(simple_command("QT"))
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self._cfg.drain_max_s
        self._last_rx_ns = self._clock.now_ns()
        while loop.time() < deadline:
            silent_s = (self._clock.now_ns() - self._last_rx_ns) / NS_PER_S
            if silent_s >= self._cfg.drain_silence_s:
                break
            await asyncio.sleep(self._cfg.drain_silence_s - silent_s)
        self._parser.reset()

    # ----- receiving -------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                self._take(await self._stream.read())
        except LinkError as err:
            self._fail(err)
        except asyncio.CancelledError:
            raise
        except Exception as err:  # a bug: consumers must not wait forever
            log.exception("urg_reader_crashed", port=self.port)
            self._fail(LinkError(f"{self.port}: laser reader crashed: {err!r}"))

    def _on_chunk(self, data: bytes) -> None:
        """A chunk the port handed over as it arrived: what _read_loop does with one."""
        try:
            self._take(data)
        except Exception as err:  # a bug: as _read_loop's; consumers must not wait forever
            self._stop_pushing()
            log.exception("urg_reader_crashed", port=self.port)
            self._fail(LinkError(f"{self.port}: laser reader crashed: {err!r}"))

    def _take(self, data: bytes) -> None:
        """One chunk read: stamped, recorded, its replies parsed, a new scan handed on."""
        t_ns = self._clock.now_ns()
        self._last_rx_ns = t_ns
        if self._tap is not None:
            self._tap("r", t_ns, data)
        for reply in self._parser.feed(data):
            self._dispatch(reply, t_ns)
        self._deliver()

    def _on_end(self, err: LinkError) -> None:
        """The port handed over its end (it vanished, or it was closed)."""
        self._pushed = False
        self._fail(err)

    def _stop_pushing(self) -> None:
        if self._pushed:
            self._pushed = False
            if self._push is not None:
                self._push.deliver_to(None, None)

    def _dispatch(self, reply: Reply, t_ns: int) -> None:
        if isinstance(reply, ScanReply) and reply.status != "00":
            self._on_stream_message(reply, t_ns)
            return
        for command, future in self._waiters:
            if not future.done() and reply.answers(command):
                future.set_result(reply)
                return
        if self._md is not None and reply.command in ("MD", "MS") and reply.answers(self._md):
            self._on_stream_message(reply, t_ns)  # a stream error status (21-98)

    def _on_stream_message(self, reply: Reply, t_ns: int) -> None:
        if self._md is None or not reply.answers(self._md):
            self.stats.stale_stream_scans += 1  # a scan of a stream we replaced
            return
        if reply.status != "99" or not isinstance(reply, ScanReply):
            self.stats.stream_errors += 1
            log.warning("urg_stream_error", port=self.port, status=reply.status)
            self._last_scan_ns = None  # next_sample restarts the stream
            self._wake()
            return
        self._on_scan(reply, t_ns)

    def _on_scan(self, reply: ScanReply, t_ns: int) -> None:
        scan = self._stamper.stamp(reply, t_ns, self.params, seq=self.stats.scans + 1)
        self.stats.scans += 1
        if self._latest is not None:
            self.stats.scans_dropped += 1
        self._latest = scan
        self._last_scan_ns = t_ns
        self._sum_errors_seen = self._parser.stats.sum_errors
        self._restarts_in_a_row = 0
        if self._inline is None:
            self._wake()  # else _deliver() hands it over once the chunk is parsed

    def _deliver(self) -> None:
        """A chunk is parsed: a new scan goes to :meth:`next_scan`'s ``inline`` now.

        What the task would do with it a loop turn later, without that turn; then the
        wait goes on as :meth:`next_scan`'s next call would begin it (its stall timer
        from now). An error of ``inline`` is raised by :meth:`next_scan`.
        """
        if self._latest is None:
            return
        handler, waiter = self._inline, self._scan_waiter
        if handler is None or waiter is None or waiter.done():
            self._wake()
            return
        scan, self._latest = self._latest, None
        self._inline = None
        try:
            handler(scan)
        except Exception as err:  # the task raises it (a matcher failure lands)
            self._inline_error = err
            self._wake()
            return
        if waiter.done():
            return  # woken meanwhile: the task goes on from there
        last = self._last_scan_ns
        stalled_s = 0.0 if last is None else (self._clock.now_ns() - last) / NS_PER_S
        sum_run = self._parser.stats.sum_errors - self._sum_errors_seen
        if last is None or stalled_s >= self._cfg.stall_s or sum_run >= self._cfg.sum_error_run:
            self._wake()  # a restart is due: the task's loop does it
            return
        loop = asyncio.get_running_loop()
        self._wait_started = loop.time()
        wait_s = self._cfg.stall_s - stalled_s
        if self._inline_timeout_s is not None:
            wait_s = min(wait_s, self._inline_timeout_s)
        if self._scan_timer is not None:
            self._scan_timer.cancel()
        self._scan_timer = loop.call_later(max(wait_s, 0.001), resolve_waiter, waiter)
        self._inline = handler

    def _wake(self) -> None:
        waiter = self._scan_waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _fail(self, err: LinkError) -> None:
        if self._error is None:
            self._error = err
        for _, future in self._waiters:
            if not future.done():
                future.set_exception(err)
        self._wake()

    # ----- the consumer's side ---------------------------------------------------------

    @property
    def error(self) -> LinkError | None:
        """The error that ended the driver, if any."""
        return self._error

    @property
    def closed(self) -> bool:
        """:meth:`close` has stopped the reader: nothing more is read from the port."""
        return self._closed and self._reader is None and not self._pushed

    async def next_scan(
        self, timeout_s: float | None = None, inline: Callable[[Scan], None] | None = None
    ) -> Scan:
        """The newest scan (older ones not picked up are dropped and counted).

        Restarts a stalled, erroring or checksum-failing stream on the way. With
        ``inline``, each scan that arrives while this waits goes to ``inline`` in the
        callback that read it (no loop turn to wake the caller) and the wait goes on;
        ``timeout_s`` then counts from the last scan.

        Raises:
            LinkError: the device failed or vanished, or no scan within ``timeout_s``.
            Exception: whatever ``inline`` raised.
        """
        loop = asyncio.get_running_loop()
        self._wait_started = loop.time()
        self._inline_timeout_s = timeout_s
        while self._latest is None:
            if self._error is not None:
                raise self._error
            now = self._clock.now_ns()
            sum_run = self._parser.stats.sum_errors - self._sum_errors_seen
            if self._last_scan_ns is None:
                await self._restart_stream("stream error status")
                continue
            stalled_s = (now - self._last_scan_ns) / NS_PER_S
            if stalled_s >= self._cfg.stall_s:
                self.stats.stalls += 1
                await self._restart_stream(f"no scan for {stalled_s:.2f} s")
                continue
            if sum_run >= self._cfg.sum_error_run:
                await self._restart_stream(f"{sum_run} checksum errors in a row")
                continue
            wait_s = self._cfg.stall_s - stalled_s
            if timeout_s is not None:
                left_s = timeout_s - (loop.time() - self._wait_started)
                if left_s <= 0:
                    msg = f"no scan from the laser on {self.port} for {timeout_s:g} s"
                    raise LinkError(msg)
                wait_s = min(wait_s, left_s)
            waiter = self._scan_waiter = loop.create_future()
            self._scan_timer = loop.call_later(max(wait_s, 0.001), resolve_waiter, waiter)
            self._inline = inline
            try:
                await waiter
            finally:
                if self._scan_timer is not None:
                    self._scan_timer.cancel()
                self._scan_timer = None
                self._scan_waiter = None
                self._inline = None
            err, self._inline_error = self._inline_error, None
            if err is not None:
                raise err
        scan, self._latest = self._latest, None
        return scan


def _push_stream(stream: ByteStream) -> PushStream | None:
    """``stream`` if it hands chunks over as they arrive (asked once: a costly check)."""
    return stream if isinstance(stream, PushStream) else None
