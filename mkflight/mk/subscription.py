"""The receiving side of the FlightCtrl link: DebugOut samples, renewal, staleness.

:class:`~mkflight.mk.link.MkLink` owns one :class:`DebugSubscription` and delegates
``subscribe()``, ``next_sample()`` and ``stale_for_s()`` to it; the link's reader hands it
every DebugOut. Each becomes a timestamped :class:`~mkflight.msgs.ImuSample`; only the
newest waits for the consumer (latest-value sharing), the ones it replaced are counted as
dropped.

Safety rules (``mk-serial.md`` §7-8; SPEC §2, §5):

* The subscription is renewed from :meth:`DebugSubscription.next_sample`, i.e. by the
  consumer asking for its next sample: a stalled control step stops refreshing the FC's
  hold on the last extern command, and the FC falls back to the pilot's sticks.
* No DebugOut for ``stale_s``: send the blind command once if the flight set one (level,
  the hover gas: the FC holds the last command it got, and the last one of a hover can
  be a noisy 77 counts that drops the vehicle before the release), re-subscribe (and ask
  the version again). Still none after
  ``release_after_stale_s`` while we had control: hand control back (Config = 0) and stop
  renewing for the FC's hold time, so that even an FC whose transmitter died but whose
  receiver works ends extern control.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable

import structlog

from mkflight.clock import Clock
from mkflight.conversions import NS_PER_S
from mkflight.errors import CommandRangeError, LinkError
from mkflight.mk.link_types import LinkSettings, LinkStats
from mkflight.mk.messages import ExternControl, debug_request, version_request
from mkflight.mk.sender import CommandSender
from mkflight.mk.units import MkCalibration, imu_from_analog
from mkflight.msgs import ImuSample

__all__ = ["FC_HOLD_S", "DebugSubscription"]

log = structlog.get_logger("mkflight.mk")

FC_HOLD_S = 5.5  # the FC drops extern control ~5.2 s after the last hold frame (§7.4)
_OFF = -(10**18)


class DebugSubscription:
    """DebugOut in, the newest ImuSample out; renews the subscription, watches staleness."""

    def __init__(
        self,
        sender: CommandSender,
        settings: LinkSettings,
        stats: LinkStats,
        calibration: MkCalibration,
        clock: Clock,
        *,
        port: str,
        start: Callable[[], None],
        check_failed: Callable[[], None],
    ) -> None:
        """Build the receiving side of one link.

        Args:
            sender: the link's sending side ('d' and 'v' requests, the stale-data release).
            settings: the link's settings (renewal and staleness times).
            stats: the link's counters; this fills in those of samples and staleness.
            calibration: converts DebugOut counts to SI.
            clock: the injected clock that stamps samples and times staleness.
            port: the port's name, for messages.
            start: starts the link's reader task if it is not running (idempotent).
            check_failed: raises the link's error if the link failed.
        """
        self._tx = sender
        self._settings = settings
        # in ns once here: each sample compares against them
        self._gap_ns = int(settings.release_after_stale_s * NS_PER_S)
        self._resubscribe_ns = int(settings.resubscribe_s * NS_PER_S)
        self._stats = stats
        self._cal = calibration
        self._clock = clock
        self._port = port
        self._start = start
        self._check_failed = check_failed
        self._latest: ImuSample | None = None
        self._sample_waiter: asyncio.Future[None] | None = None
        self._timer: asyncio.TimerHandle | None = None  # ends a wait (_wait_until)
        self._timer_slack_s = settings.stale_s / 2  # it may end a wait this much early
        self._last_subscribe_ns = _OFF
        self._last_sample_ns: int | None = None
        self._stale = False
        self._want_version = False
        self._renew_after_ns = _OFF  # no 'd' before this (after a stale-data release)
        self._inline: Callable[[ImuSample], bool] | None = None  # serve()'s, while it waits
        self._served: BaseException | bool = False  # what an inline call ended serve() with
        self._started_ns = 0  # the current wait's start (its timeout counts from here)
        self._served_timeout_s: float | None = None
        self.blind_command: Callable[[], ExternControl | None] | None = None
        """Asked once when the data goes stale while we have control: what to send then."""

    def subscribe(self) -> None:
        """Send the DebugOut subscription 'd' (also renews it and the FC's hold)."""
        self._start()
        if self._clock.now_ns() < self._renew_after_ns:
            return  # after a stale-data release: no hold refresh yet (_release_stale)
        self._tx.send("d", debug_request(self._settings.debug_interval_10ms))
        self._last_subscribe_ns = self._clock.now_ns()
        self._stats.subscriptions += 1

    def unsubscribe(self) -> None:
        """Stop the DebugOut stream ('d' with interval 0): the link is closing."""
        self._tx.send("d", debug_request(0))

    def resume_renewals(self) -> None:
        """Renew again from now on (the port was re-opened and control handed back)."""
        self._renew_after_ns = _OFF

    def forget_sample(self) -> None:
        """Drop the sample the consumer has not picked up (it came from an old port)."""
        self._latest = None

    def on_debug(self, analog: tuple[int, ...], t_ns: int) -> None:
        """A DebugOut (its analog values) arrived at ``t_ns``: the newest sample, wake.

        One that comes ``release_after_stale_s`` or more after the one before, with control
        taken, is not taken: the stale-data release was due before it was read (the
        process was frozen, SIGSTOP or a stalled host, so the release timer could not
        fire). The consumer is woken to release as the timer would have; the samples after
        the release are taken again.
        """
        last = self._last_sample_ns
        if last is not None and self._tx.engaged and t_ns - last >= self._gap_ns:
            self._stats.samples_dropped += 1
            log.warning("mk_data_gap", port=self._port, gap_s=(t_ns - last) / NS_PER_S)
            self.wake()
            return
        self._last_sample_ns = t_ns
        self._stats.samples += 1
        if self._latest is not None:
            self._stats.samples_dropped += 1  # the consumer fell behind: newest wins
        sample = imu_from_analog(analog, t_ns, self._cal)
        if self._stale:
            self._stale = False
            self._renew_after_ns = _OFF
            # Ask who is there now (an FC that rebooted was deaf to the stale-time 'v'),
            # from the consumer's next call so that it cannot delay this sample's command.
            self._want_version = True
            log.info("mk_data_resumed", port=self._port)
        self._latest = sample
        if self._inline is None:
            self.wake()  # else the link calls deliver() once the chunk's frames are filed

    def deliver(self) -> None:
        """The link filed a chunk's frames: a new sample goes to :meth:`serve` now.

        After the whole chunk, so that the step sees the confirms that came with the
        sample, as it did when it ran a loop turn later.
        """
        if self._latest is None:
            return
        handler, waiter = self._inline, self._sample_waiter
        if handler is not None and waiter is not None and not waiter.done():
            sample, self._latest = self._latest, None
            self._serve_inline(handler, sample)
        else:
            self.wake()

    def _serve_inline(self, handler: Callable[[ImuSample], bool], sample: ImuSample) -> None:
        """:meth:`serve`'s step on ``sample``, in the callback that read it.

        What :meth:`serve` would do a loop turn later (the handler, then what
        :meth:`next_sample` does before it waits again), without that turn. A sample
        that arrives inside the handler (a fake that answers in the write) waits as
        usual. An error or the end is handed to :meth:`serve` through its waiter.
        """
        self._inline = None
        try:
            done = handler(sample)
        except Exception as err:  # the serving task raises it (a crash ends the flight)
            self._served = err
            self.wake()
            return
        waiter = self._sample_waiter
        if done:
            self._served = True
            self.wake()
            return
        if waiter is None or waiter.done():
            return  # woken meanwhile (a failure, a sample): the task goes on from there
        self._before_wait()
        now = self._clock.now_ns()
        self._started_ns = now
        wait_s = self._wait_s(now, sample.t_ns, self._served_timeout_s)
        loop = asyncio.get_running_loop()
        self._wait_until(loop, loop.time() + max(wait_s, 0.001))
        self._inline = handler

    def wake(self) -> None:
        """Wake a waiting :meth:`next_sample` (a sample arrived, or the link failed)."""
        waiter = self._sample_waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def stale_for_s(self) -> float:
        """Seconds since the last DebugOut (inf before the first)."""
        if self._last_sample_ns is None:
            return float("inf")
        return (self._clock.now_ns() - self._last_sample_ns) / NS_PER_S

    async def next_sample(self, timeout_s: float | None = None) -> ImuSample:
        """The newest DebugOut as an :class:`ImuSample` (see ``MkLink.next_sample``)."""
        self._before_wait()
        sample = await self._wait_sample(timeout_s, None)
        assert sample is not None  # no handler: only a sample ends the wait
        return sample

    async def serve(self, on_sample: Callable[[ImuSample], bool], timeout_s: float | None) -> None:
        """Hand every newest sample to ``on_sample`` until it returns True (``MkLink.serve``).

        While this waits, a DebugOut is handed over in the callback that read it, not a
        loop turn later in this task: each turn of the event loop costs ~0.1 ms of CPU
        before any work. The subscription is renewed and the staleness watched as for
        :meth:`next_sample`; ``on_sample``'s exceptions are raised here.
        """
        self._served_timeout_s = timeout_s
        self._before_wait()
        while True:
            sample = await self._wait_sample(timeout_s, on_sample)
            if sample is None or on_sample(sample):
                return
            self._before_wait()

    def _before_wait(self) -> None:
        """Renew the subscription if due, ask the version if wanted: before each wait."""
        if self._clock.now_ns() - self._last_subscribe_ns >= self._resubscribe_ns:
            self.subscribe()
        if self._want_version:
            self._want_version = False
            self._tx.send("v", version_request())

    def _wait_s(self, now: int, last: int, timeout_left_s: float | None) -> float:
        """How long the wait may last: until the next renewal, release or timeout is due."""
        s = self._settings
        since_renewal_s = (now - max(last, self._last_subscribe_ns)) / NS_PER_S
        wait_s = s.stale_s - since_renewal_s
        if self._tx.engaged:
            wait_s = min(wait_s, s.release_after_stale_s - (now - last) / NS_PER_S)
        if timeout_left_s is not None:
            wait_s = min(wait_s, timeout_left_s)
        return wait_s

    async def _wait_sample(
        self, timeout_s: float | None, inline: Callable[[ImuSample], bool] | None
    ) -> ImuSample | None:
        """The next sample; with ``inline``, samples meanwhile go to it (None: it ended)."""
        s = self._settings
        self._started_ns = self._clock.now_ns()
        while self._latest is None:
            self._check_failed()
            now = self._clock.now_ns()
            started = self._started_ns
            last = self._last_sample_ns if self._last_sample_ns is not None else started
            stale_s = (now - last) / NS_PER_S
            since_renewal_s = (now - max(last, self._last_subscribe_ns)) / NS_PER_S
            if self._tx.engaged and stale_s >= s.release_after_stale_s:
                await self._release_stale()
                continue
            if since_renewal_s >= s.stale_s and now >= self._renew_after_ns:
                self._on_stale()
            left_s = None
            if timeout_s is not None:
                left_s = timeout_s - (now - started) / NS_PER_S
                if left_s <= 0:
                    msg = f"no DebugOut from {self._port} for {timeout_s:g} s"
                    raise LinkError(msg)
            wait_s = self._wait_s(now, last, left_s)
            # Await the bare future, here rather than in a helper coroutine (asyncio.wait_for
            # would add an event-loop turn to every sample's path, a helper a frame to
            # resume); the wake-up timer resolves it when the wait is over.
            loop = asyncio.get_running_loop()
            waiter = self._sample_waiter = loop.create_future()
            self._wait_until(loop, loop.time() + max(wait_s, 0.001))
            self._inline = inline
            try:
                await waiter
            finally:
                self._sample_waiter = None
                self._inline = None
            served, self._served = self._served, False
            if isinstance(served, BaseException):
                raise served
            if served:
                return None
        sample, self._latest = self._latest, None
        return sample

    def _wait_until(self, loop: asyncio.AbstractEventLoop, due: float) -> None:
        """Have the waiter resolved at loop time ``due`` unless a sample comes first.

        The timer is re-armed for the waits it would not end in time, and kept for
        those it ends at most ``stale_s / 2`` early: such an early end only makes the
        wait look again (it is not stale yet) and wait for the rest. While samples flow,
        every other sample re-arms it (~20 us of cancel and re-arm in a flight, caches
        cold) and it never fires. A timer left armed and moved only when it fires before
        the wait's end fires every ``stale_s``, each time a loop turn of its own (~0.15 ms
        of CPU before any work): measured, that costs more.
        """
        timer = self._timer
        if timer is not None:
            if due - self._timer_slack_s <= timer.when() <= due:
                return  # it fires at most the slack early, and the wait then looks again
            timer.cancel()
        self._timer = loop.call_at(due, self._on_timer)

    def _on_timer(self) -> None:
        """The wake-up timer fired: the wait is over."""
        self._timer = None
        waiter = self._sample_waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _on_stale(self) -> None:
        if not self._stale:
            self._stale = True
            self._stats.stale_events += 1
            log.warning("mk_data_stale", port=self._port, stale_s=self._settings.stale_s)
            blind = self.blind_command() if self.blind_command is not None else None
            if blind is not None and self._tx.engaged:
                # nothing may keep the re-subscription below from going out
                with contextlib.suppress(LinkError, CommandRangeError):
                    self._tx.send_extern_control(blind, confirm=True)
                    self._stats.blind_commands += 1
                    log.warning("mk_blind_hold", port=self._port, gas=blind.gas)
            self._tx.send("v", version_request())
        self.subscribe()

    async def _release_stale(self) -> None:
        """No data for ``release_after_stale_s`` with control taken: the pilot's sticks rule."""
        self._stats.stale_releases += 1
        log.error("mk_stale_release", port=self._port, stale_s=self.stale_for_s())
        await self._tx.release()
        self._tx.block(f"no DebugOut for {self._settings.release_after_stale_s:g} s")
        # Renewing 'd' would reload the FC's hold on a command our release may not have
        # reached: stay quiet until the FC has certainly dropped it.
        self._renew_after_ns = self._clock.now_ns() + int(FC_HOLD_S * NS_PER_S)
