"""The MK step's dealings with the FlightCtrl beyond DebugOut: :class:`MkCommands`.

* the ExternControl out (SPEC §2), refused once the link handed control back to the
  pilot;
* the pilot's sticks (:mod:`mkflight.safety.pilot`): a 'p' request twice a second, sent
  right behind a command - a request on a timer of its own could take the wire just
  before a command and delay it, and a replay (which has no processing time) would see
  it take the wire at other moments - and each new 'P' answer through the pilot watch;
* the HANDSHAKE's end: :data:`HANDSHAKE_CONFIRMS` confirms of neutral frames.
"""

from __future__ import annotations

import contextlib

from mkflight.control.phases import Phase
from mkflight.conversions import NS_PER_S
from mkflight.errors import FlightError, LinkError
from mkflight.mk.link import MkLink
from mkflight.mk.messages import Ppm
from mkflight.msgs import Command
from mkflight.safety.pilot import PPM_PERIOD_S, PilotWatch

PPM_PERIOD_NS = round(PPM_PERIOD_S * NS_PER_S)
HANDSHAKE_CONFIRMS = 3  # confirms of neutral frames needed before take-off


class MkCommands:
    """Commands and stick requests to the FC, its confirms and stick answers back."""

    __slots__ = ("_confirms0", "_last_ppm", "_link", "_next_ppm_ns", "pilot")

    def __init__(self, link: MkLink, pilot: PilotWatch) -> None:
        self._link = link
        #: the pilot's sticks as the 'P' answers show them (a moved stick: latched)
        self.pilot = pilot
        self._last_ppm: Ppm | None = None
        self._next_ppm_ns = 0
        self._confirms0: int | None = None  # the link's confirms when HANDSHAKE began

    def handshake_ok(self, phase: Phase) -> bool:
        """In HANDSHAKE: whether the FC has confirmed enough frames since it began."""
        if phase is not Phase.HANDSHAKE:
            return False
        confirms = self._link.stats.confirms
        if self._confirms0 is None:
            self._confirms0 = confirms
        return confirms - self._confirms0 >= HANDSHAKE_CONFIRMS

    def override_now(self) -> bool:
        """Feed the newest 'P' answer to the pilot watch; True if that latched the override."""
        ppm = self._link.last_ppm
        if ppm is not None and ppm is not self._last_ppm:
            self._last_ppm = ppm
            was = self.pilot.override
            return self.pilot.update(ppm) and not was
        return False

    def send(self, command: Command) -> None:
        """Write ``command`` as an ExternControl frame.

        Raises:
            FlightError: it takes control, but the link has handed control to the pilot.
        """
        if command.take_control and self._link.control_blocked is not None:
            msg = f"control was handed back to the pilot ({self._link.control_blocked})"
            raise FlightError(msg)
        self._link.send_sticks(
            command.nick_counts,
            command.roll_counts,
            command.yaw_counts,
            command.gas_counts,
            take_control=command.take_control,
        )

    def ask_sticks(self, t_ns: int) -> None:
        """Request the pilot's sticks ('p') if half a second has passed since the last."""
        if t_ns >= self._next_ppm_ns:
            self._next_ppm_ns = t_ns + PPM_PERIOD_NS
            with contextlib.suppress(LinkError):  # a dead port is the MK task's to report
                self._link.request_ppm()
