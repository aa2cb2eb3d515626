"""``fly --live``: the flight as it flies, in Foxglove (a Foxglove SDK WebSocket server).

Three parts, so that the view never delays a step:

* the feed (:class:`~mkflight.ground.live_feed.LiveFeed`) is the flight's observer: on the
  control path it only keeps references to the newest step values and scan and wakes
  the publisher (O(1); no message built, nothing sent);
* the publisher (:class:`LivePublisher`) is an asyncio task of the flight's own loop. It
  wakes after a step - the step's command is out and its rows written, and the next
  DebugOut is ≈ 50 ms away - builds the messages of the newest values
  (:mod:`~mkflight.ground.live_messages`) and logs them, yielding to the loop between
  messages, so that a DebugOut that does come meanwhile waits for one message's
  building (tens of µs), never for the whole set. Values it has not published when newer
  ones come are dropped: it always publishes the newest, at most at the configured
  rates (``live.state_rate_hz``, ``live.scan_rate_hz``); phase changes and failsafe
  events are queued and all published;
* the SDK's server (Rust, its own threads, no GIL) sends to the clients. A client that
  reads slowly loses its oldest queued messages beyond ``live.backlog_messages``; nothing
  waits for it.

Why a task and not a thread. Both publish right after a step, so both rarely meet the
next DebugOut; they differ when they do. A thread that publishes holds the GIL while it
builds a message, and a step that wants it back waits until the thread lets go - at worst
the interpreter's switch interval, 5 ms. A task runs only while the loop has nothing
else to do, in slices of one message (a LaserScan: ≈ 0.1 ms to build and encode), and
it reads the feed's references between two steps, never in the middle of one: a
consistent snapshot without a lock. Measured on the 2-core CI machine under the other
jobs' load (a loop reacting to a byte another process writes every 20 ms, publishing a
step's messages and a scan after each to a subscribed client; 3 x 2480 reactions each):
median reaction 100/96/98 µs with the task, 120/94/110 µs with a thread, 100/117/97 µs
without publishing; the p99s (0.27-2.3 ms without publishing) were the machine's load,
not the publisher's. Whole flights: ``tools/bench.py --only flight --live``. Channels with
no subscriber cost nothing (no message is built for them).

A fault in the publisher never becomes a flight fault: it is logged once as a warning,
the feed stops (later steps tell it nothing) and the flight goes on. The server listens
on loopback unless told otherwise (:mod:`~mkflight.ground.live_address`); the frames and
the topics are :mod:`~mkflight.ground.live_messages`' and :mod:`~mkflight.ground.topics`'.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from functools import partial
from typing import TYPE_CHECKING, Any, Final, Protocol, TypeVar

import foxglove
import structlog
from foxglove.channels import FrameTransformsChannel, LaserScanChannel, PoseInFrameChannel

from mkflight.config import Config, LiveConfig
from mkflight.conversions import NS_PER_S
from mkflight.errors import ConfigError
from mkflight.ground import live_messages as msg
from mkflight.ground import topics
from mkflight.ground.live_address import LiveAddress
from mkflight.ground.live_feed import LiveFeed

if TYPE_CHECKING:
    from mkflight.control.controller import Setpoint
    from mkflight.flight.step import ImuStepOutput
    from mkflight.msgs import Estimate, ImuSample, Scan

log = structlog.get_logger("mkflight.live")

T = TypeVar("T")

RATE_SLACK: Final = 0.9
"""A value is due once this share of its period has passed since the last one published
(the DebugOut's and the scans' own jitter must not halve the rate)."""


STEP_RATE_HZ: Final = 20.0
"""The step values' own rate, at most (a DebugOut every 50 ms; the FC's is ≈ 53 ms)."""
SCAN_RATE_HZ: Final = 10.0
"""The scans' own rate (the URG-04LX scans every 100 ms)."""


class _Channel(Protocol):
    """What the publisher uses of a Foxglove channel."""

    def has_sinks(self) -> bool: ...

    def log(self, message: Any, *, log_time: int | None = None) -> None: ...


class LiveChannels:
    """One Foxglove channel per topic (:mod:`~mkflight.ground.topics`), on ``context``."""

    def __init__(self, context: foxglove.Context) -> None:
        def json_channel(topic: str) -> foxglove.Channel:
            return foxglove.Channel(topic, schema=msg.SCHEMAS[topic], context=context)

        self.scan: _Channel = LaserScanChannel(topics.SCAN, context=context)
        self.pose: _Channel = PoseInFrameChannel(topics.POSE, context=context)
        self.setpoint: _Channel = PoseInFrameChannel(topics.SETPOINT, context=context)
        self.tf: _Channel = FrameTransformsChannel(topics.TF, context=context)
        self.height: _Channel = json_channel(topics.HEIGHT)
        self.attitude: _Channel = json_channel(topics.ATTITUDE)
        self.velocity: _Channel = json_channel(topics.VELOCITY)
        self.command: _Channel = json_channel(topics.COMMAND)
        self.battery: _Channel = json_channel(topics.BATTERY)
        self.phase: _Channel = json_channel(topics.PHASE)
        self.failsafe: _Channel = json_channel(topics.FAILSAFE)


def _put(channel: _Channel, t_ns: int, build: Callable[[], Any]) -> None:
    """Build and log one message, only if someone is subscribed to ``channel``."""
    if channel.has_sinks():
        channel.log(build(), log_time=t_ns)


def period_ns(rate_hz: float, own_rate_hz: float) -> int:
    """The shortest interval between two published values at ``rate_hz``, with slack.

    0 at the values' own rate (or above): every one is published, however it jitters.
    """
    return 0 if rate_hz >= own_rate_hz else int(RATE_SLACK * NS_PER_S / rate_hz)


class LivePublisher:
    """Publishes the feed's newest values after each step (see the module docstring)."""

    def __init__(
        self, feed: LiveFeed, channels: LiveChannels, cfg: LiveConfig, scan_steps: tuple[int, int]
    ) -> None:
        self.feed = feed
        self._ch = channels
        self._scan_steps = scan_steps
        self._state_period_ns = period_ns(cfg.state_rate_hz, STEP_RATE_HZ)
        self._scan_period_ns = period_ns(cfg.scan_rate_hz, SCAN_RATE_HZ)
        self._state_ns: int | None = None  # the last published step's time
        self._scan_ns: int | None = None
        self.rounds = 0  #: wake-ups so far
        self.error: BaseException | None = None  #: what stopped it (None: nothing)

    async def run(self) -> None:
        """Publish after every step until cancelled, or until publishing fails."""
        feed = self.feed
        try:
            while True:
                await feed.wake.wait()
                feed.wake.clear()
                await self.publish_newest()
        except Exception as err:  # a fault of the view is never the flight's
            self.error = err
            feed.stop()
            log.warning("live view failed: no more publishing; the flight goes on", error=repr(err))

    async def publish_newest(self) -> None:
        """The queued events, then the newest step's values and scan, when due."""
        self._events()
        feed = self.feed
        sample, out, sp, scan = feed.sample, feed.out, feed.setpoint, feed.scan
        if sample is not None and out is not None:
            t = sample.t_ns
            if _due(t, self._state_ns, self._state_period_ns):
                self._state_ns = t
                self._poses(sample, out.estimate, sp)
                await asyncio.sleep(0)  # a DebugOut that came meanwhile goes first
                self._values(sample, out)
                await asyncio.sleep(0)
        if scan is not None and _due(scan.t_ns, self._scan_ns, self._scan_period_ns):
            self._scan_ns = scan.t_ns
            self._scan(scan)
        self.rounds += 1

    def _events(self) -> None:
        """Every queued phase change and failsafe event, at its own time."""
        ch, events = self._ch, self.feed.events
        while events:
            out = events.popleft()
            for pe in out.phase_events:
                _put(ch.phase, pe.t_ns, partial(msg.phase_change_json, pe))
            for fe in out.failsafe_events:
                _put(ch.failsafe, fe.t_ns, partial(msg.failsafe_json, fe))

    def _poses(self, sample: ImuSample, est: Estimate, sp: Setpoint | None) -> None:
        """``/tf``, ``/pose`` and ``/setpoint`` of one step."""
        ch, t = self._ch, sample.t_ns
        _put(ch.tf, t, lambda: msg.transforms_message(est, sample))
        _put(ch.pose, t, lambda: msg.pose_message(est, sample))
        if sp is not None:
            _put(ch.setpoint, t, lambda: msg.setpoint_message(t, sp))

    def _values(self, sample: ImuSample, out: ImuStepOutput) -> None:
        """The JSON topics of one step."""
        ch, t, est = self._ch, sample.t_ns, out.estimate
        _put(ch.height, t, lambda: msg.height_json(est))
        _put(ch.attitude, t, lambda: msg.attitude_json(sample))
        _put(ch.velocity, t, lambda: msg.velocity_json(est))
        _put(ch.command, t, lambda: msg.command_json(out.command))
        _put(ch.battery, t, lambda: msg.battery_json(sample))
        _put(ch.phase, t, lambda: msg.phase_json(out.phase.name))

    def _scan(self, scan: Scan) -> None:
        """``/scan``: its wall beams."""
        if self._ch.scan.has_sinks():
            laser = msg.scan_message(scan, self._scan_steps)
            if laser is not None:
                self._ch.scan.log(laser, log_time=scan.t_ns)


def _due(t_ns: int, last_ns: int | None, period: int) -> bool:
    """Whether a value at ``t_ns`` is due, the last one published at ``last_ns``."""
    return last_ns is None or t_ns < last_ns or t_ns - last_ns >= max(period, 1)


class LiveView:
    """The live view of one flight: server, channels, feed and publisher.

    :func:`start_live_view` makes it; the flight gets :attr:`feed` as its observer and
    runs inside :meth:`during`; :meth:`close` stops the server.
    """

    def __init__(
        self, context: Any, server: Any, publisher: LivePublisher, address: LiveAddress
    ) -> None:
        self._context = context  # the channels' sink binding lives as long as this reference
        self._server = server
        self.publisher = publisher
        self.feed = publisher.feed
        self.address = address  #: where it listens (the port the system chose, if 0 was asked)

    async def during(self, flight: Awaitable[T]) -> T:
        """Await ``flight`` with the publisher running beside it; then stop publishing."""
        task = asyncio.create_task(self.publisher.run(), name="live-view")
        try:
            return await flight
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            self.feed.stop()

    def close(self) -> None:
        """Stop the server (its clients are disconnected)."""
        with contextlib.suppress(Exception):  # the flight is over: nothing to fail for
            self._server.stop()


def start_live_view(cfg: Config, address: LiveAddress) -> LiveView:
    """Listen on ``address`` and advertise the topics; nothing is published yet.

    Raises:
        ConfigError: the address cannot be listened on (in use, not this host's).
    """
    context = foxglove.Context()
    try:
        server = foxglove.start_server(
            name="mkflight",
            host=address.host,
            port=address.port,
            context=context,
            message_backlog_size=cfg.live.backlog_messages,
        )
    except RuntimeError as err:
        reason = str(err).removeprefix("FoxgloveError: ")
        hint = (
            "; another live view or Foxglove bridge? choose another port"
            if "in use" in reason
            else ""
        )
        text = f"{address.host}:{address.port}"
        message = f"--live {text}: cannot listen: {reason}{hint}"
        raise ConfigError(message) from err
    publisher = LivePublisher(LiveFeed(), LiveChannels(context), cfg.live, cfg.laser.scan_steps)
    return LiveView(context, server, publisher, LiveAddress(address.host, server.port))
