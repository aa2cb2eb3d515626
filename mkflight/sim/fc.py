"""The FlightCtrl 0.84a as a pure, sans-I/O model (``protocols/mk-serial.md`` §3-7).

:class:`FcModel` is what the emulator on a pty (:mod:`mkflight.sim.fc_server`) and a
lock-step simulation drive: bytes from the host go in with :meth:`FcModel.receive`, the
frames the FC has finished sending come out of :meth:`FcModel.poll`, and
:meth:`FcModel.next_event_ns` says when to look again. It never reads a clock: time is
passed in as integer nanoseconds, so a test can step it by hand.

How time is modelled (§7.1): the FC counts ticks of 1.024 ms from its boot. Its main loop
is modelled as running once on every tick boundary; in that pass it first lets timers
expire (subscription, extern-control hold), then handles the one received frame, then
starts at most one frame if the line is free (§7.5). So answers leave on tick boundaries
(§10: "the emulator sends on tick boundaries") and a frame arrives at the host when its
last byte has left, ``len*10/57600`` s after it started (§1). Both directions run at wire
speed: what the host writes arrives byte by byte (:class:`~mkflight.sim.fc_uart.HostLine`)
and the receiver rules apply at each byte's arrival time; a frame whose last byte arrives
is handled at the first tick after it (a byte arriving exactly on a tick comes after it).
A subscribed DebugOut is due 52 ticks after the last one; an airframe's busy main loop
(:class:`~mkflight.sim.fc_timing.DebugTiming`, seeded) sends some a few ticks, or 5-25
ms, later than due, and the period counts from when it really left.

Parts live beside it: :mod:`~mkflight.sim.fc_uart` (the FC's receiver rules, wire
timing), :mod:`~mkflight.sim.fc_control` (pilot sticks, ExternControl, the hold counter),
:mod:`~mkflight.sim.fc_timing` (DebugOut jitter) and :mod:`~mkflight.sim.fc_answers`
(frame contents). Written from ``mk-serial.md``; no
firmware code is reproduced.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import replace
from typing import Final, Protocol

from mkflight.config import SimFcConfig
from mkflight.conversions import NS_PER_S
from mkflight.errors import ProtocolError
from mkflight.mk.codec import ADDR_FC, Frame, encode_frame
from mkflight.mk.messages import (
    ANALOG_COUNT,
    ANALOG_LABELS_084A,
    FORBIDDEN_COMMANDS,
    DebugOut,
    ExternControl,
    Label,
    Ppm,
)
from mkflight.sim.fc_answers import DEFAULT_STATUS, build_debug_out, mk3mag_frame, parse_version
from mkflight.sim.fc_control import FcCommand, FcControls
from mkflight.sim.fc_timing import TICK_NS as TICK_NS  # one FC tick (re-exported)
from mkflight.sim.fc_timing import DebugJitter, DebugTiming
from mkflight.sim.fc_uart import FcReceiver, FcTransmitter, HostLine, UartCounters, WireChunk

DELAY_OVERSHOOT_TICKS: Final = 2  # an FC delay of t ticks expires after t+1 or t+2 (§7.1)
SUBSCRIPTION_TICKS: Final = 4000  # 'd' expires 4000 ticks after the last renewal (§7.2)
MK3MAG_PERIOD_TICKS: Final = 99  # the unsolicited '#dk' frame (§7.6)
DEFAULT_BOOT_NS: Final = NS_PER_S  # how long a rebooting FC stays deaf and mute

# Frames that reload the hold counter. A real FC also reloads on 't' (motor test), but
# the emulator never acts on 't' (§4: a client must not send it).
_HOLD_COMMANDS: Final = frozenset("abdhlp")


class AnalogSource(Protocol):
    """Where the DebugOut values come from: a fixed table, a resting vehicle, a simulation."""

    def analog(self, t_ns: int, fc: FcModel) -> Mapping[int, int]:
        """Raw s16 DebugOut values by index (0..31) at ``t_ns``; missing indexes read 0.

        Indexes 7 (Gas), 9 (Voltage) and 10 (Receiver Level) are filled by the model
        unless the source gives them: the source always wins.
        """
        ...


class FcModel(UartCounters):
    """A FlightCtrl 0.84a seen from its serial port, driven by explicit time.

    Its state is advanced lazily: properties (``extern_active``, ``hold_counts``,
    counters...) describe the FC at :attr:`now_ns`, so call :meth:`poll` with the current
    time before reading them. Counters (``rx_*``, ``tx_*``, ``forbidden_requests``) are
    the FC's and restart at a :meth:`reboot`; ``reboots`` does not. See the module
    docstring for the time model.
    """

    def __init__(
        self,
        settings: SimFcConfig,
        source: AnalogSource,
        *,
        t_ns: int = 0,
        timing: DebugTiming | None = None,
    ) -> None:
        """Boot at ``t_ns``; ``timing``: the airframe's DebugOut jitter (default: exact)."""
        self.settings = settings
        self.debug_jitter = DebugJitter(timing if timing is not None else DebugTiming())
        self.source = source
        self.version = parse_version(settings.version)
        self.hardware_error = bytes(5)
        self.status: tuple[int, int] = DEFAULT_STATUS
        self.receiver_level = settings.receiver_level
        self.battery_v = settings.battery_v
        self.reboots = 0
        self.controls = FcControls(settings)
        self.line = HostLine()  # the host's side: not reset when the FC reboots
        self.tx = FcTransmitter(t_ns)
        self._now_ns = t_ns
        self._reset(t_ns)

    def _reset(self, boot_ns: int) -> None:
        """The state of an FC that finishes booting at ``boot_ns`` (tick 0)."""
        self._boot_ns = boot_ns
        self._tick = -1  # every tick up to and including this one has been processed
        self.rx = FcReceiver()
        self._rx_tick = 0  # when the main loop handles the pending frame
        self.tx.restart(boot_ns)
        self._want_version = False
        self._want_debug = False
        self._want_label: int | None = None
        self._want_ppm = False
        self._confirm_frame = 0
        self._debug_period_ticks = 0
        self._debug_due_tick = 0
        self._renew_tick = 0
        self._mag_due_tick = MK3MAG_PERIOD_TICKS
        self.controls.reset()
        self.rx_frames = 0
        self.rx_unknown = 0
        self.rx_malformed = 0
        self.rx_by_cmd: Counter[str] = Counter()
        self.forbidden_requests = 0

    # ----------------------------------------------------------------- time
    @property
    def boot_ns(self) -> int:
        """When the FC (last) finished booting: its tick 0."""
        return self._boot_ns

    @property
    def now_ns(self) -> int:
        """The latest time the model has been advanced to."""
        return self._now_ns

    @property
    def booting(self) -> bool:
        """True while a rebooting FC neither receives nor sends."""
        return self._now_ns < self._boot_ns

    def _tick_ns(self, k: int) -> int:
        return self._boot_ns + k * TICK_NS

    def _first_tick_at(self, t_ns: int) -> int:
        """The first tick at or after ``t_ns``."""
        return -((self._boot_ns - t_ns) // TICK_NS)

    def _advance(self, t_ns: int) -> None:
        """Run the receiver and the main loop, in time order, over everything up to ``t_ns``.

        Bytes are received up to (not including) the next tick with work in it, then that
        tick runs; a byte arriving exactly on a tick comes after it.
        """
        t_ns = max(t_ns, self._now_ns)
        while True:
            k = self._next_tick()
            tick_ns = None if k is None else self._tick_ns(k)
            if tick_ns is not None and tick_ns > t_ns:
                k = tick_ns = None
            if self._receive_until(t_ns if tick_ns is None else tick_ns - 1):
                continue
            if k is None:
                break
            self._process_tick(k)
            self._tick = k
        self._now_ns = t_ns
        self._tick = max(self._tick, (t_ns - self._boot_ns) // TICK_NS)

    def _receive_until(self, t_ns: int) -> bool:
        """Receive the bytes arrived by ``t_ns``, stopping after a good frame; any taken?"""
        data = self.line.arrived(t_ns)
        if not data:
            return False
        next_ns = self.line.next_ns()
        if next_ns is not None and next_ns < self._boot_ns:  # a booting FC hears nothing
            self.line.consume(len(self.line.arrived(min(t_ns, self._boot_ns - 1))))
            return True
        used, completed = self.rx.feed_until_frame(data)
        t_last = self.line.consume(used)
        if completed:  # handled at the first tick after its '\r' arrived
            self._rx_tick = (t_last - self._boot_ns) // TICK_NS + 1
        return True

    def _next_tick(self) -> int | None:
        """The earliest unprocessed tick at which the main loop has something to do."""
        ticks: list[int] = []
        if self.rx.pending:
            ticks.append(self._rx_tick)
        if self._debug_period_ticks or self._want_debug:
            ticks.append(self._renew_tick + SUBSCRIPTION_TICKS)
        if self.controls.extern_requested:
            ticks.append(self.controls.hold_zero_tick())
        free = self._first_tick_at(self.tx.free_ns)
        if (
            self._want_version
            or self._want_debug
            or self._want_label is not None
            or self._confirm_frame
            or self._want_ppm
        ):
            ticks.append(free)
        if self._debug_period_ticks:
            ticks.append(max(free, self._debug_due_tick))
        if self.settings.mk3mag_frames:
            ticks.append(max(free, self._mag_due_tick))
        return max(min(ticks), self._tick + 1) if ticks else None

    def _process_tick(self, k: int) -> None:
        """One pass of the main loop: timers, then the received frame, then the sender."""
        if (self._debug_period_ticks or self._want_debug) and (
            k >= self._renew_tick + SUBSCRIPTION_TICKS
        ):
            self._debug_period_ticks = 0
            self._want_debug = False
        self.controls.expire(k)
        if self.rx.pending and k >= self._rx_tick:
            frame = self.rx.take()
            if frame is not None:
                self._handle(frame, k)
        if self._tick_ns(k) >= self.tx.free_ns:
            self._send_one(k)

    # ----------------------------------------------------------------- receiving
    def receive(self, data: bytes, t_ns: int) -> WireChunk:
        r"""The host writes ``data`` at ``t_ns``; it arrives at wire speed (§1, §3).

        The chunk starts at ``t_ns`` or when the previous byte written has arrived,
        whichever is later, and its bytes follow back to back; the returned chunk says
        when. At each byte's arrival: a '#' starts a frame only when the receiver is idle
        and the last frame has been handled (at the first tick after its '\r'), else
        the frame is lost (:attr:`rx_lost_frames`); inside a frame every byte is kept
        until '\r'. A bad checksum is dropped and counted; a frame reaching 170 bytes
        resets the receiver. A booting FC hears nothing.
        """
        self._advance(t_ns)
        return self.line.write(data, self._now_ns)

    def _handle(self, frame: Frame, k: int) -> None:
        """Act on one received frame at tick ``k`` (§4, §7.2-7.4)."""
        cmd = frame.cmd
        self.rx_frames += 1
        self.rx_by_cmd[cmd] += 1
        if cmd in FORBIDDEN_COMMANDS:
            self.forbidden_requests += 1  # a real FC would reset, spin motors or rewrite
            return
        if cmd == "p" and frame.addr != ADDR_FC:
            return  # 'p' is answered on the FC's own address only (§5.4)
        if cmd in _HOLD_COMMANDS:
            self.controls.reload_hold(k)
        if cmd == "v":
            self._want_version = True
        elif cmd == "d":
            if not frame.payload:
                self.rx_malformed += 1
                return
            self._debug_period_ticks = 10 * frame.payload[0]
            self._want_debug = self._debug_period_ticks > 0
            self._renew_tick = k
        elif cmd == "b":
            try:
                ec = ExternControl.decode(frame)
            except ProtocolError:
                self.rx_malformed += 1
                return
            self.controls.receive(ec)
            self._confirm_frame = int(ec.frame)  # 0 cancels a confirm not yet sent (§5.3)
        elif cmd == "a":
            if frame.payload and frame.payload[0] < ANALOG_COUNT:
                self._want_label = frame.payload[0]
            else:
                self.rx_malformed += 1
        elif cmd == "p":
            self._want_ppm = True
        elif cmd in "hc":
            self._renew_tick = k  # display / 3D requests renew the subscription (§7.2)
        elif cmd != "l":
            self.rx_unknown += 1

    # ----------------------------------------------------------------- sending
    def poll(self, t_ns: int) -> list[bytes]:
        """The chunks whose last byte has left by ``t_ns``, in order.

        Each chunk is one frame, preceded by injected garbage if any, or the start of a
        frame cut off by a :meth:`reboot`.
        """
        self._advance(t_ns)
        return self.tx.take_sent(self._now_ns)

    def next_event_ns(self) -> int | None:
        r"""The earliest time at which :meth:`poll` may return something or state changes.

        Besides ticks and frames leaving, that is when the next '\r' written by the host
        (or the end of a chunk) arrives. None means nothing will happen until more bytes
        are written.
        """
        times: list[int] = []
        if (line_ns := self.line.next_event_ns()) is not None:
            times.append(line_ns)
        if self._now_ns < self._boot_ns:
            times.append(self._boot_ns)  # the end of a reboot
        if (sent_ns := self.tx.next_end_ns()) is not None:
            times.append(sent_ns)
        k = self._next_tick()
        if k is not None:
            times.append(self._tick_ns(k))
        return min(times) if times else None

    def _send_one(self, k: int) -> None:
        """Start at most one frame, by priority V, #dk, D, A, B, P (§7.5)."""
        t_ns = self._tick_ns(k)
        if self._want_version:
            self._want_version = False
            version = replace(self.version, hardware_error=self.hardware_error)
            self.tx.emit(t_ns, version.encode(), "V")
        elif self.settings.mk3mag_frames and k >= self._mag_due_tick:
            self._mag_due_tick = k + MK3MAG_PERIOD_TICKS
            self.tx.emit(t_ns, mk3mag_frame(self.source.analog(t_ns, self)), "k")
        elif self._want_debug or (self._debug_period_ticks and k >= self._debug_due_tick):
            self._want_debug = False
            extra = self.debug_jitter.extra_ticks()  # the FC's loop was busy (fc_timing)
            self._debug_due_tick = k + self._debug_period_ticks + DELAY_OVERSHOOT_TICKS + extra
            self.tx.emit(t_ns, self.debug_out(t_ns).encode(), "D")
        elif self._want_label is not None:
            index, self._want_label = self._want_label, None
            self.tx.emit(t_ns, Label(index, ANALOG_LABELS_084A[index]).encode(), "A")
        elif self._confirm_frame:
            frame, self._confirm_frame = self._confirm_frame, 0
            self.tx.emit(t_ns, encode_frame(ADDR_FC, "B", bytes((frame,))), "B")
        elif self._want_ppm:
            self._want_ppm = False
            self.tx.emit(t_ns, Ppm(self.controls.ppm_channels).encode(), "P")

    def debug_out(self, t_ns: int) -> DebugOut:
        """The DebugOut the FC would send at ``t_ns`` (§6): source values win."""
        return build_debug_out(
            self.source.analog(t_ns, self),
            gas=self.effective_command().gas,
            battery_v=self.battery_v,
            receiver_level=self.receiver_level,
            status=self.status,
        )

    # ----------------------------------------------------------------- control state
    @property
    def last_extern(self) -> ExternControl | None:
        """The stored ExternControl (Config set to 0 once the hold ran out), or None."""
        return self.controls.last_extern

    @property
    def extern_active(self) -> bool:
        """ExternControl is being applied (Config bit 0, setting > 128, hold not run out)."""
        return self.controls.extern_active

    @property
    def hold_counts(self) -> int:
        """PcZugriff now: 255 after a hold frame, 0 means extern control has ended."""
        return self.controls.hold_counts_at(self._tick)

    def effective_command(self) -> FcCommand:
        """The sticks the FC flies now; the pilot's sticks are set on :attr:`controls`."""
        return self.controls.effective_command()

    # ----------------------------------------------------------------- faults
    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` on the wire just before the next frame."""
        self.tx.garbage += data

    def corrupt_next(self, n: int) -> None:
        """Give the next ``n`` frames sent a bad checksum."""
        self.tx.corrupt_count += n

    def silence(self, until_ns: int) -> None:
        """Lose every frame that would start before ``until_ns`` (a dead TX line).

        The FC does not notice: its timers and flags run on, receiving still works.
        """
        self.tx.silent_until_ns = max(self.tx.silent_until_ns, until_ns)

    def reboot(self, t_ns: int, *, boot_ns: int = DEFAULT_BOOT_NS) -> None:
        """Reset the FC at ``t_ns`` (brown-out, watchdog): §8 item 7.

        A frame on the wire is cut off; for ``boot_ns`` the FC neither hears nor sends;
        then it runs with a fresh state: no subscription, no extern command (Config 0),
        hold counter 100, counters at zero. The pilot's sticks are not the FC's state.
        """
        self._advance(t_ns)
        self.tx.cut(self._now_ns)
        self.reboots += 1
        self._reset(self._now_ns + boot_ns)
