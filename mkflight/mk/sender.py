"""The sending side of the FlightCtrl link: numbered ExternControl, confirms, hand-back.

:class:`~mkflight.mk.link.MkLink` owns one :class:`CommandSender` and delegates its
sending methods to it; the link keeps the port. Every frame goes out through the
sender's :class:`~mkflight.mk.outbox.Outbox`, whose writer is the link's (it writes to the
port, counts and taps) and reports each frame that left through :meth:`CommandSender.written`.

A numbered ExternControl carries a Frame number 1..255, rolling over the numbered frames;
its 'B' confirm gives the round-trip time. Not every frame is numbered
(``mk.confirm_every``): a confirm is a frame the daemon wakes up for, ~0.18 ms of CPU on
the development VM with its handling. Of the commands that take control (Config bit 0),
the first and then every ``confirm_every``-th is numbered; the others carry Frame 0,
which asks the FC for no confirm (``mk-serial.md`` §5.3), and save that wake-up. The
numbered ones still measure the round trip and show lost confirms. A Config = 0 frame
(the handshake's neutral stream, a release) and the blind command are always numbered:
whether the FC heard them is checked, or worth knowing. A confirm not back within
``CONFIRM_TIMEOUT_NS`` is counted lost (when the next command goes out); a command that a
newer one replaced in the outbox, or that a release or re-open dropped from it, is not
waited for.

Safety rules (``mk-serial.md`` §7-8; SPEC §2, §5):

* Handing back is sticky: after :meth:`CommandSender.release` (the link's ``release()``,
  a stale-data release, a re-open or ``close()``), a command that takes control raises
  until the flight logic calls the link's ``allow_control()`` (SPEC §5: never re-engage
  just because data came back).
* The link is the last gate on commands: gas in [0, gas_max], nick/roll/yaw within
  +-127, address 1, whatever the caller computed; packing raises, never wraps.
* Frames are spaced by the :class:`~mkflight.mk.outbox.Outbox` (one per write, >= 3 ms
  after the previous frame left the wire).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable

import structlog

from mkflight.clock import Clock
from mkflight.conversions import NS_PER_S
from mkflight.errors import CommandRangeError, LinkError
from mkflight.mk.codec import ADDR_FC, FrameEncoder
from mkflight.mk.link_types import LinkSettings, LinkStats
from mkflight.mk.messages import (
    CMD_EXTERN,
    EC_VALID,
    EXTERN_CONFIG_OFFSET,
    EXTERN_FRAME_OFFSET,
    ExternControl,
    pack_sticks,
)
from mkflight.mk.outbox import Outbox, Writer

__all__ = ["CONFIRM_TIMEOUT_NS", "RELEASE_CONFIRM_WAIT_S", "CommandSender"]

log = structlog.get_logger("mkflight.mk")

CONFIRM_TIMEOUT_NS = NS_PER_S  # a confirm not back within this is counted lost
RELEASE_CONFIRM_WAIT_S = 0.1  # wait for the last release frame's confirm (behind a DebugOut)
#: Time left below this is none: a timer that short is due at once (the loop's clock
#: resolution), so a replay's lock-step clock, which moves only when the loop idles,
#: would never move past a deadline a rounding error away.
TIME_EPS_S = 1e-6
_encode_extern = FrameEncoder(ADDR_FC, CMD_EXTERN)
_FRAME_BYTES = tuple(bytes((n,)) for n in range(256))  # the Frame byte of each number


class CommandSender:
    """Frames out of one link: ExternControl numbering, confirms, limits, hand-back."""

    def __init__(
        self,
        writer: Writer,
        settings: LinkSettings,
        stats: LinkStats,
        clock: Clock,
        *,
        port: str,
        check_writable: Callable[[], None],
        check_failed: Callable[[], None],
    ) -> None:
        """Build the sender of one link.

        Args:
            writer: the link's writer: one frame to the port now (raises LinkError).
            settings: the link's settings (limits, release frames, line speed).
            stats: the link's counters; the sender fills in those of commands.
            clock: stamps send times for the round-trip time.
            port: the port's name, for messages.
            check_writable: raises LinkError if nothing can be written (the port died).
            check_failed: raises the link's error if the link failed.
        """
        self._settings = settings
        self._stats = stats
        self._clock = clock
        self._port = port
        self._check_writable = check_writable
        self._check_failed = check_failed
        self._frame_no = 0  # the last Frame number given (1..255)
        self._confirm_every = settings.confirm_every
        #: Commands taking control sent with Frame 0 since the last numbered one (the
        #: first that takes control after a Config = 0 frame is numbered).
        self._unnumbered = settings.confirm_every
        #: Frame number -> send time (ns) of the commands whose confirm is awaited.
        self.pending_confirms: dict[int, int] = {}
        self._confirm_event = asyncio.Event()
        self._engaged = False  # a command with Config bit 0 went out since the last release
        self._blocked: str | None = None  # why taking control is refused, if it is
        self._outbox = Outbox(writer, baudrate=settings.baudrate, gap_s=settings.min_frame_gap_s)
        self._outbox.on_superseded = self._on_superseded

    # ----- the sticky hand-back --------------------------------------------------------

    @property
    def blocked(self) -> str | None:
        """Why commands that take control are refused (None: they are allowed)."""
        return self._blocked

    @property
    def engaged(self) -> bool:
        """A command that takes control went out since the last release."""
        return self._engaged

    def block(self, reason: str) -> None:
        """Refuse commands that take control until :meth:`allow_control`, for ``reason``."""
        self._blocked = reason

    def allow_control(self) -> None:
        """Let commands take control again (the flight logic's decision)."""
        self._blocked = None

    # ----- frames out ------------------------------------------------------------------

    def send(self, kind: str, data: bytes, frame_no: int = 0) -> None:
        """Send one encoded frame through the outbox (now, or queued for the line)."""
        self._outbox.send(kind, data, frame_no)
        self._stats.delayed_writes = self._outbox.delayed

    def flush_due(self) -> None:
        """Write a queued frame whose time came while the loop was busy (before input)."""
        self._outbox.flush_due()

    def written(self, frame_no: int, t_ns: int) -> None:
        """The link wrote frame ``frame_no`` (0: not a numbered command) at ``t_ns``."""
        if frame_no:
            self.pending_confirms[frame_no] = t_ns

    async def drained(self) -> None:
        """Wait until every frame sent so far has been written and has left the wire."""
        await self._outbox.drained()

    def drop_queued(self) -> None:
        """Drop the frames waiting for the line; their confirms are not waited for."""
        for no in self._outbox.cancel():
            self.pending_confirms.pop(no, None)

    def stop(self) -> None:
        """Drop the frames waiting for the line (the link is closing)."""
        self._outbox.cancel()

    def send_extern_control(self, command: ExternControl, *, confirm: bool = False) -> int:
        """Check, number and send one ExternControl; return its Frame number (see MkLink).

        Numbered (1..255) if ``confirm``, if it does not take control (Config = 0), if it
        is the first that takes control after such a frame, or the ``confirm_every``-th
        since the last numbered one; else Frame 0 (no confirm asked), and 0 returned.
        """
        self._check_writable()
        packed = command.pack()  # range-checks every field, or raises
        self._check_limits(command)
        takes_control = bool(packed[EXTERN_CONFIG_OFFSET] & EC_VALID)
        if takes_control and self._blocked is not None:
            msg = f"{self._port}: not taking control: {self._blocked}"
            raise LinkError(msg)
        frame_no = self._number(takes_control, confirm)
        return self._send_extern(
            packed[:EXTERN_FRAME_OFFSET]
            + _FRAME_BYTES[frame_no]
            + packed[EXTERN_FRAME_OFFSET + 1 :],
            frame_no,
            takes_control,
        )

    def send_sticks(self, nick: int, roll: int, yaw: int, gas: int, *, take_control: bool) -> int:
        """:meth:`send_extern_control` of the command with these counts, without building it.

        The command is ``ExternControl(nick=nick, roll=roll, yaw=yaw, gas=gas, config=1 if
        take_control else 0)``; it is not built when the counts are ints within the limits
        (the flight step's command, one a step). Anything else takes the checking path,
        which names the field it refuses.
        """
        s = self._settings
        m = s.stick_max_counts
        if not (
            type(nick) is int
            and type(roll) is int
            and type(yaw) is int
            and type(gas) is int
            and -m <= nick <= m
            and -m <= roll <= m
            and -m <= yaw <= m
            and 0 <= gas <= s.gas_max
        ):
            command = ExternControl(
                nick=nick, roll=roll, yaw=yaw, gas=gas, config=1 if take_control else 0
            )
            return self.send_extern_control(command)
        self._check_writable()
        if take_control and self._blocked is not None:
            msg = f"{self._port}: not taking control: {self._blocked}"
            raise LinkError(msg)
        frame_no = self._number(take_control, False)
        packed = pack_sticks(nick, roll, yaw, gas, frame_no, 1 if take_control else 0)
        return self._send_extern(packed, frame_no, take_control)

    def _number(self, takes_control: bool, confirm: bool) -> int:
        """The Frame number of the next ExternControl (0: none; see send_extern_control).

        A command is numbered too while a confirm is still awaited: the FC keeps one confirm
        flag, and a Frame 0 command before it answered would cancel the confirm (counted lost
        although nothing was lost), as two commands close together under load would.
        """
        if self.pending_confirms:
            self._expire_confirms(self._clock.now_ns())  # a lost one is no longer awaited
        if not takes_control:
            self._unnumbered = self._confirm_every  # the next that takes control: numbered
        elif (
            not confirm and not self.pending_confirms and self._unnumbered + 1 < self._confirm_every
        ):
            self._unnumbered += 1
            return 0
        else:
            self._unnumbered = 0
        frame_no = self._frame_no = self._frame_no % 255 + 1
        return frame_no

    def _send_extern(self, packed: bytes, frame_no: int, takes_control: bool) -> int:
        """The checked, numbered payload ``packed`` as a frame to the outbox."""
        data = _encode_extern(packed)  # lost confirms were expired in _number
        self.send("b", data, frame_no)
        self._engaged = self._engaged or takes_control
        self._stats.commands_sent += 1
        return frame_no

    def _check_limits(self, command: ExternControl) -> None:
        s = self._settings
        stick_max = s.stick_max_counts
        nick, roll, yaw, gas = command.nick, command.roll, command.yaw, command.gas
        if (
            -stick_max <= nick <= stick_max
            and -stick_max <= roll <= stick_max
            and -stick_max <= yaw <= stick_max
            and 0 <= gas <= s.gas_max
        ):
            return  # the common case: pack() has checked that they are whole numbers
        for name in ("nick", "roll", "yaw"):
            value = getattr(command, name)
            if abs(value) > stick_max:
                msg = f"ExternControl.{name} = {value} beyond +-{stick_max}"
                raise CommandRangeError(msg)
        if not 0 <= gas <= s.gas_max or not math.isfinite(gas):
            msg = f"ExternControl.gas = {gas} outside 0..{s.gas_max} (control.gas_max)"
            raise CommandRangeError(msg)

    async def release(self, *, quick: bool = False) -> int:
        """Hand control back: neutral Config = 0 frames; return how many were confirmed."""
        s = self._settings
        self._blocked = self._blocked or "control released"
        self.drop_queued()  # no queued command may follow
        before = self._stats.confirms
        for i in range(s.release_frames):
            self.send_extern_control(ExternControl.neutral())
            await self._outbox.drained()  # each frame on the wire (none superseded)
            if not quick and i + 1 < s.release_frames:
                await asyncio.sleep(s.release_interval_s)
        self._engaged = False
        if not quick:
            # The last confirm may queue behind a DebugOut (up to ~16 ms on the wire).
            await self.wait_confirm(self._frame_no, RELEASE_CONFIRM_WAIT_S)
        confirmed = self._stats.confirms - before
        log.info("mk_released", port=self._port, frames=s.release_frames, confirmed=confirmed)
        return confirmed

    # ----- confirms --------------------------------------------------------------------

    def on_confirm(self, frame_no: int, t_ns: int) -> None:
        """The FC confirmed ``frame_no`` (received at ``t_ns``): count it and its RTT."""
        sent_ns = self.pending_confirms.pop(frame_no, None)
        if sent_ns is None:
            return
        self._stats.confirms += 1
        self._stats.rtt_ns.append(t_ns - sent_ns)
        self._confirm_event.set()

    def wake(self) -> None:
        """Wake :meth:`wait_confirm` (the link failed: it raises)."""
        self._confirm_event.set()

    async def wait_confirm(self, frame_no: int, timeout_s: float) -> bool:
        """Wait until the confirm of ``frame_no`` arrives; False if it did not in time."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while frame_no in self.pending_confirms or self._outbox.pending:
            self._check_failed()
            self._confirm_event.clear()
            left_s = deadline - loop.time()
            if left_s <= TIME_EPS_S:  # less is float rounding: a lock-step loop never gets there
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._confirm_event.wait(), min(left_s, 0.01))
        return True

    def _expire_confirms(self, now_ns: int) -> None:
        horizon = now_ns - CONFIRM_TIMEOUT_NS
        for no, t_sent in list(self.pending_confirms.items()):
            if t_sent < horizon:
                del self.pending_confirms[no]
                self._stats.confirms_lost += 1

    def _on_superseded(self, frame_no: int) -> None:
        self._stats.superseded_commands += 1
        self.pending_confirms.pop(frame_no, None)
