"""The emulated FlightCtrl on a pseudo-terminal: :class:`FcModel` behind a :class:`PtyDevice`.

Clients open :attr:`FcEmulator.path` like the FC's USB-serial adapter, so the MK link is
exercised exactly as in flight (SPEC §8). The serving itself (the read and send tasks,
stamped with ``time.monotonic_ns``, no periodic tick; ``wait_for``; crash surfacing) is
:class:`~mkflight.sim.pty_server.PtyEmulator`'s; this module builds the :class:`FcModel`
and passes its faults through.

Faults: :meth:`FcEmulator.vanish`/:meth:`FcEmulator.replug` pull and reinsert the USB
adapter (the FC itself keeps running, as it does when only the adapter is unplugged);
the model's own faults are passed through with times relative to now.

A crash of either task (an :class:`~mkflight.sim.fc.AnalogSource` raising, a failing pty
read) is not swallowed: it is kept in :attr:`FcEmulator.error`, makes
:meth:`FcEmulator.wait_for` raise at once, and is re-raised by :meth:`FcEmulator.stop`.
"""

from __future__ import annotations

import time
from pathlib import Path

from mkflight.config import SimFcConfig
from mkflight.conversions import NS_PER_S
from mkflight.sim.fc import DEFAULT_BOOT_NS, AnalogSource, FcModel
from mkflight.sim.pty_server import PtyEmulator


class FcEmulator(PtyEmulator[FcModel]):
    """A FlightCtrl 0.84a answering on a pty (``mk-serial.md``), for tests and ``--sim``."""

    def __init__(
        self,
        settings: SimFcConfig,
        source: AnalogSource,
        *,
        link: str | Path | None = None,
        name: str = "fc",
    ) -> None:
        """Prepare the emulator; nothing runs before :meth:`start`.

        Args:
            settings: the emulated FC's settings (``sim.fc``).
            source: where the DebugOut values come from.
            link: a stable symlink to the pty (survives :meth:`replug`), else none.
            name: a label for messages.
        """
        super().__init__(link=link, name=name)
        self._settings = settings
        self._source = source

    def _new_model(self, t_ns: int) -> FcModel:
        """The FC, booting at ``t_ns``."""
        return FcModel(self._settings, self._source, t_ns=t_ns)

    # ----------------------------------------------------------------- faults
    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` just before the next frame."""
        self.model.inject_garbage(data)
        self._poke()

    def corrupt_next(self, n: int) -> None:
        """Give the next ``n`` frames a bad checksum."""
        self.model.corrupt_next(n)
        self._poke()

    def silence_for(self, duration_s: float) -> None:
        """Lose every frame the FC starts in the next ``duration_s`` (a dead TX line)."""
        self.model.silence(time.monotonic_ns() + round(duration_s * NS_PER_S))
        self._poke()

    def reboot(self, boot_s: float = DEFAULT_BOOT_NS / NS_PER_S) -> None:
        """Reboot the FC now; it is deaf and mute for ``boot_s``."""
        self.model.reboot(time.monotonic_ns(), boot_ns=round(boot_s * NS_PER_S))
        self._poke()
