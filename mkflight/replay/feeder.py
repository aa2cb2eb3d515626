"""The mock devices of a replay: recorded bytes into real ptys, on the lock-step clock.

:class:`Feeder` owns one :class:`~mkflight.io.pty.PtyDevice` per port (behind a stable
symlink, so a recorded unplug and replug can be played: the pty vanishes, a fresh one
appears at the same path) and the time-ordered :class:`~mkflight.replay.inputs.Input`
list. It is the :class:`~mkflight.replay.vloop.Idle` of the lock-step loop: whenever the
daemon has nothing left to do, the feeder either

* waits (real time) for bytes it wrote that the daemon has not read yet - the kernel
  moves pty bytes asynchronously, and the daemon must see each chunk at its own time;
* delivers the next input, the clock set to its recorded time: bytes to the port, a port
  lost or back, an operator's stop request;
* or moves the clock to the daemon's next timer, if that comes first.

A recorded chunk for a port the replayed daemon does not have open (it has not re-opened
it yet after a loss, or it has closed it on the way out) is lost, as it would be on the
wire; such chunks are counted.
``speed`` paces the clock to real time (``--speed X``); None runs as fast as the daemon
consumes (``--fast``). ``memory`` plays each port through a
:class:`~mkflight.replay.memport.MemoryDevice` instead of a pty: no kernel round trip and
no real-time wait per chunk (``--fast``, unless ``--ptys``).

A port may instead be served by an emulated device (``models``: the simulator's pure FC
or URG model, :class:`~mkflight.sim.pty_server.EmulatedDevice`), which is how the original
system's tables are replayed: it receives what the daemon writes at the lock-step time it was
written and its replies go out at the times it says.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mkflight.conversions import NS_PER_S
from mkflight.errors import LinkError, PortNotFoundError, ReplayError
from mkflight.io.pty import PtyDevice
from mkflight.io.stream import ByteStream
from mkflight.replay.inputs import PORTS, Input
from mkflight.replay.memport import MemoryDevice
from mkflight.replay.vloop import VirtualClock, seconds_to_ns_ceil
from mkflight.safety.failsafe import StopRequest
from mkflight.sim.pty_server import EmulatedDevice

#: Real time to wait for delivered bytes to be read before giving up on them.
IN_FLIGHT_MAX_S = 2.0
#: A poll of the real selector while bytes are in flight (returns as soon as I/O is ready).
IN_FLIGHT_POLL_S = 0.05
#: The daemon's writes to a played port are dropped every this many inputs (it writes
#: ~30 bytes a step; the pty holds kilobytes).
DRAIN_EVERY = 16
#: A recorded replug is played this long before the original daemon's re-open. That
#: re-open was one of its back-off polls (``*.reopen_backoff_s``, 0.1 s doubling), late by
#: the real sleeps' overshoot; the replayed daemon's same poll comes on time, so the device
#: must be back a little before it - but after the poll before (>= 0.1 s earlier).
REPLUG_LEAD_NS = 50_000_000
#: Recorded time the daemon may run on after the last recorded input: then it is asked to
#: stop (as by SIGTERM), and one more such span later the replay gives up (ReplayError).
#: A replayed flight ends by itself well within it (its devices vanish with the
#: recording's end: the FC is lost within seconds); a damaged recording must not hang.
END_GRACE_NS = 60 * NS_PER_S


@dataclass(slots=True)
class FeedStats:
    """What the feeder did (for the replay report)."""

    delivered: int = 0
    delivered_bytes: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PORTS, 0))
    dropped: int = 0
    late_ns_max: int = 0
    never_read_bytes: int = 0
    pty_dropped_bytes: int = 0


class _ModelDevice(PtyDevice):
    """A pty whose master's input goes straight to a callback (an emulated device's)."""

    def __init__(self, name: str, link: Path, on_data: Callable[[bytes], None]) -> None:
        self._on_data = on_data
        super().__init__(name, link=link)

    def _on_readable(self) -> None:
        try:
            data = os.read(self._master, 65536)
        except OSError:  # EAGAIN, or EIO with no client: nothing to take
            return
        self._on_data(data)


def replug_times(inputs: list[Input]) -> list[Input]:
    """Move each re-open after a loss ``REPLUG_LEAD_NS`` earlier (not before the loss)."""
    out: list[Input] = []
    lost_at: dict[str, int] = {}
    for inp in inputs:
        if inp.kind == "c":
            lost_at[inp.port] = inp.t_ns
        elif inp.kind == "o" and inp.port in lost_at:
            t = max(lost_at.pop(inp.port), inp.t_ns - REPLUG_LEAD_NS)
            inp = Input(t, inp.port, "o", inp.data)
        out.append(inp)
    out.sort(key=lambda i: i.t_ns)
    return out


class Feeder:
    """Plays :class:`Input` records into ptys when the lock-step loop is idle."""

    def __init__(
        self,
        inputs: list[Input],
        clock: VirtualClock,
        link_dir: Path,
        *,
        speed: float | None = None,
        on_stop: Callable[[StopRequest, str], None] | None = None,
        on_progress: Callable[[int], None] | None = None,
        models: dict[str, EmulatedDevice] | None = None,
        memory: bool = False,
    ) -> None:
        self._inputs = replug_times(inputs)
        #: ports are memory devices (no ptys): see :mod:`mkflight.replay.memport`
        self.memory = memory
        #: ports served by an emulated device (the original's tables' replay) instead of bytes
        self.models = dict(models or {})
        self.written: dict[str, int] = dict.fromkeys(PORTS, 0)
        self.received: dict[str, int] = dict.fromkeys(PORTS, 0)
        self._next = 0
        self._clock = clock
        self._speed = speed
        self._on_stop = on_stop
        self._on_progress = on_progress
        self._links = {p: link_dir / p for p in PORTS}
        self.devices: dict[str, PtyDevice | MemoryDevice] = {}
        self.stats = FeedStats()
        #: bytes the daemon has read per port (its raw-recording tap counts them)
        self.consumed: dict[str, int] = dict.fromkeys(PORTS, 0)
        #: the daemon has the port open (set by its 'o' marks, cleared on a loss)
        self.daemon_open: dict[str, bool] = dict.fromkeys(PORTS, False)
        #: the daemon closed the port for good (its way out)
        self.closed: dict[str, Callable[[], bool]] = {p: (lambda: False) for p in PORTS}
        self._lost: set[str] = set()
        #: losses the daemon declared by itself that no recorded 'c' has matched yet
        self._own_losses: dict[str, int] = dict.fromkeys(PORTS, 0)
        self._wait_started: float | None = None
        self._pace0: tuple[int, float] | None = None
        self._seen_open: set[str] = set()
        self._overrun_stop = False

    # ----- set-up -------------------------------------------------------------------------

    def set_stop(self, on_stop: Callable[[StopRequest, str], None]) -> None:
        """Where the recorded operator stops go (the daemon's ``request_stop``)."""
        self._on_stop = on_stop

    def open_devices(self) -> None:
        """Create the ptys (call inside the running loop: they read their master ends)."""
        for p in PORTS:
            if self.memory:
                sink = self._sink(p) if p in self.models else None
                self.devices[p] = MemoryDevice(str(self._links[p]), sink)
            elif p in self.models:
                self.devices[p] = _ModelDevice(f"replay-{p}", self._links[p], self._sink(p))
            else:
                self.devices[p] = PtyDevice(f"replay-{p}", link=self._links[p])
                self.devices[p].detach()  # what the daemon writes is dropped as we go

    def path(self, port: str) -> str:
        """The path the daemon opens for ``port`` (a stable symlink)."""
        return str(self._links[port])

    def open_memory(self, path: str) -> ByteStream:
        """The daemon opens ``path`` (memory mode): its device's stream.

        Raises:
            PortNotFoundError: no such port, or its device is unplugged.
        """
        for dev in self.devices.values():
            if isinstance(dev, MemoryDevice) and dev.path == path:
                return dev.open()
        msg = f"serial port {path!r} does not exist"
        raise PortNotFoundError(msg)

    def close_devices(self) -> None:
        """Remove the ptys and their links."""
        for dev in self.devices.values():
            self.stats.pty_dropped_bytes += dev.dropped_bytes
            dev.vanish()

    @property
    def remaining(self) -> int:
        """Inputs not yet delivered."""
        return len(self._inputs) - self._next

    @property
    def total(self) -> int:
        """All inputs."""
        return len(self._inputs)

    # ----- what the daemon tells us -------------------------------------------------------

    def on_read(self, port: str, n: int) -> None:
        """The daemon read ``n`` bytes from ``port``."""
        self.consumed[port] += n

    def on_wrote(self, port: str, n: int) -> None:
        """The daemon wrote ``n`` bytes to ``port`` (an emulated device must see them)."""
        self.written[port] += n

    def _sink(self, port: str) -> Callable[[bytes], None]:
        return lambda data: self._to_model(port, data)

    def _to_model(self, port: str, data: bytes) -> None:
        self.received[port] += len(data)
        self.models[port].receive(data, self._clock.now_ns())

    def on_open(self, port: str) -> None:
        """The daemon (re)opened ``port``."""
        self.daemon_open[port] = True
        self._lost.discard(port)

    def on_lost(self, port: str) -> None:
        """The daemon marked ``port`` lost, by itself or because we pulled the device.

        By itself: a protocol failure, after which it re-opens the port.
        """
        self.daemon_open[port] = False
        if port not in self._lost:
            self._own_losses[port] += 1

    def _usable(self, port: str) -> bool:
        return self.daemon_open[port] and port not in self._lost and not self.closed[port]()

    # ----- the idle hook ------------------------------------------------------------------

    def on_idle(self, timer_in_s: float | None) -> float | None:
        """See :class:`~mkflight.replay.vloop.Idle`."""
        wait = self._in_flight()
        if wait is not None:
            return wait
        now = self._clock.now_ns()
        timer_ns = None if timer_in_s is None else now + seconds_to_ns_ceil(timer_in_s)
        model_port, model_ns = self._next_model_event()
        if (
            model_ns is not None
            and (timer_ns is None or model_ns <= timer_ns)
            and (self._next >= len(self._inputs) or model_ns <= self._inputs[self._next].t_ns)
        ):
            self._move(model_ns)
            self._serve(model_port)
            return None
        if self._next < len(self._inputs):
            inp = self._inputs[self._next]
            if timer_ns is None or inp.t_ns <= timer_ns:
                if inp.kind == "r" and not self._usable(inp.port):
                    # The daemon does not have the port open (not re-opened yet after a
                    # loss, or closed on its way out): as on the wire, the bytes are lost.
                    self.stats.dropped += 1
                    self._next += 1
                    return None
                self._move(inp.t_ns)
                self._next += 1
                self._apply(inp, now)
                # Wait for the bytes right here: one loop turn per chunk, not two (in
                # memory they are queued already: the loop runs the reader next).
                return IN_FLIGHT_POLL_S if inp.kind == "r" and not self.memory else None
        if timer_ns is not None:
            self._check_overrun(timer_ns)
            self._move(timer_ns)
            return None
        # No input left and nothing scheduled: the recording is over and the daemon waits
        # for bytes that will not come; the devices go away, as on the vehicle.
        for p, dev in self.devices.items():
            if dev.is_open:
                dev.vanish()
                self._lost.add(p)
                return None
        msg = "replay: the daemon waits with no timer after the recording ended"
        raise RuntimeError(msg)

    def _check_overrun(self, t_ns: int) -> None:
        """After the recording: ask the daemon to stop, then give up (END_GRACE_NS)."""
        if self._next < len(self._inputs) or self.models:
            return
        last_ns = self._inputs[-1].t_ns if self._inputs else 0
        over_ns = t_ns - last_ns
        if over_ns > 2 * END_GRACE_NS:
            msg = (
                f"replay: the daemon still ran {over_ns / NS_PER_S:.0f} s of recorded time "
                "after the recording ended, and after it was asked to stop: given up"
            )
            raise ReplayError(msg)
        if over_ns > END_GRACE_NS and not self._overrun_stop and self._on_stop is not None:
            self._overrun_stop = True
            self._on_stop(
                StopRequest.SIGTERM,
                f"replay: the recording ended {END_GRACE_NS // NS_PER_S} s ago",
            )

    def _next_model_event(self) -> tuple[str, int | None]:
        best: tuple[str, int | None] = ("", None)
        for p, model in self.models.items():
            t = model.next_event_ns()
            if t is not None and self.devices[p].is_open and (best[1] is None or t < best[1]):
                best = (p, max(t, self._clock.now_ns()))
        return best

    def _serve(self, port: str) -> None:
        """What an emulated device has sent by now, onto its pty."""
        dev = self.devices[port]
        for chunk in self.models[port].poll(self._clock.now_ns()):
            with contextlib.suppress(LinkError):
                before = dev.dropped_bytes
                dev.write(chunk)
                self.stats.delivered_bytes[port] += len(chunk) - (dev.dropped_bytes - before)

    def _in_flight(self) -> float | None:
        pending = [
            p
            for p in PORTS
            if (
                self.stats.delivered_bytes[p] > self.consumed[p]
                or (p in self.models and self.written[p] > self.received[p])
            )
            and self._usable(p)
        ]
        if not pending:
            self._wait_started = None
            return None
        if self.memory:
            # Nothing is in flight in memory: bytes still queued while the loop is idle
            # are bytes the daemon is not reading now (a pty would wait, then give up).
            self._give_up(pending)
            return None
        now = time.perf_counter()
        if self._wait_started is None:
            self._wait_started = now
        if now - self._wait_started < IN_FLIGHT_MAX_S:
            return IN_FLIGHT_POLL_S
        self._give_up(pending)
        return None

    def _give_up(self, pending: list[str]) -> None:
        """The daemon will not read these bytes now: count them, do not wait again."""
        for p in pending:
            self.stats.never_read_bytes += self.stats.delivered_bytes[p] - self.consumed[p]
            self.consumed[p] = self.stats.delivered_bytes[p]
            self.received[p] = self.written[p]
        self._wait_started = None

    def _move(self, t_ns: int) -> None:
        now = self._clock.now_ns()
        if t_ns <= now:
            return
        if self._speed is not None:
            if self._pace0 is None:
                self._pace0 = (now, time.perf_counter())
            v0, r0 = self._pace0
            ahead_s = r0 + (t_ns - v0) / NS_PER_S / self._speed - time.perf_counter()
            if ahead_s > 0:
                time.sleep(ahead_s)
        self._clock.advance_to(t_ns)

    def _apply(self, inp: Input, was_ns: int) -> None:
        self.stats.delivered += 1
        if self._on_progress is not None and self.stats.delivered % 500 == 0:
            self._on_progress(self._next)
        if was_ns > inp.t_ns:
            self.stats.late_ns_max = max(self.stats.late_ns_max, was_ns - inp.t_ns)
        if inp.kind == "s":
            if self._on_stop is not None and inp.stop is not None:
                self._on_stop(inp.stop, inp.reason)
            return
        dev = self.devices[inp.port]
        if inp.kind == "r":
            if self.stats.delivered % DRAIN_EVERY == 0:
                dev.drop_client_bytes()  # what the daemon wrote: its own recording keeps it
            with contextlib.suppress(LinkError):
                before = dev.dropped_bytes
                dev.write(inp.data)
                self.stats.delivered_bytes[inp.port] += len(inp.data) - (dev.dropped_bytes - before)
        elif inp.kind == "c" and self._own_losses[inp.port] > 0:
            # The original's own mark, which the replayed daemon has made already (it may
            # have re-opened the port since, as fast as the original did a little later).
            self._own_losses[inp.port] -= 1
        elif inp.kind == "c":
            # The original lost the port here; the replayed daemon has not (so it was the
            # device that went, not a failure the same bytes reproduce): pull the plug.
            dev.vanish()
            self._lost.add(inp.port)
        elif inp.kind == "o":
            if inp.port in self._seen_open and not dev.is_open:
                dev.replug()
                if inp.port not in self.models:
                    dev.detach()
            self._seen_open.add(inp.port)
