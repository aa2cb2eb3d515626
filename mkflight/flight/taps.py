"""The byte taps of the daemon's two ports: :class:`PortTaps` (SPEC §6 raw recordings).

Every chunk a link reads or writes goes into its port's raw recording, then to the
policy (a replay's feeder counts what was consumed). The MK tap also notes when an
ExternControl frame (``#bb...``) reached the port - the end of a step's command latency
(SPEC §9) - and when a DebugOut subscription ('d') went out, which makes the FC answer
at once and restart its period (:class:`~mkflight.flight.stats.StepStats`).
"""

from __future__ import annotations

from mkflight.clock import Clock
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.stats import StepStats
from mkflight.logs.raw import RawRecorder


class PortTaps:
    """Both ports' taps and 'o'/'c' marks, recorded and told to the policy."""

    __slots__ = (
        "_clock",
        "_laser_raw",
        "_mk_raw",
        "_on_bytes",
        "_policy",
        "_recorders",
        "_stats",
        "command_written_ns",
    )

    def __init__(
        self,
        mk_raw: RawRecorder,
        laser_raw: RawRecorder,
        *,
        clock: Clock,
        policy: FlightPolicy,
        stats: StepStats,
    ) -> None:
        self._recorders = {"mk": mk_raw, "laser": laser_raw}
        self._mk_raw, self._laser_raw = mk_raw, laser_raw
        self._clock = clock
        self._policy = policy
        # The flight's policy ignores byte counts (a replay's counts them): no call then.
        counts = type(policy).on_bytes is not FlightPolicy.on_bytes
        self._on_bytes = policy.on_bytes if counts else None
        self._stats = stats
        #: when the newest ExternControl frame was written to the MK port (0: none yet)
        self.command_written_ns = 0

    def mk(self, direction: str, t_ns: int, data: bytes) -> None:
        """The MK port's tap: record, note a command or a subscription written."""
        self._mk_raw(direction, t_ns, data)
        if direction == "w":
            if data[1:3] == b"bb":
                self.command_written_ns = t_ns
            elif data[2:3] == b"d":
                self._stats.on_resubscribe()  # the FC answers at once and restarts its period
        if self._on_bytes is not None:
            self._on_bytes("mk", direction, len(data))

    def laser(self, direction: str, t_ns: int, data: bytes) -> None:
        """The laser port's tap: record."""
        self._laser_raw(direction, t_ns, data)
        if self._on_bytes is not None:
            self._on_bytes("laser", direction, len(data))

    def mark(self, port: str, kind: str, text: str) -> None:
        """An 'o' (opened) or 'c' (lost) record in ``port``'s raw recording."""
        self._recorders[port].mark(kind, self._clock.now_ns(), text)
        self._policy.on_mark(port, kind)
