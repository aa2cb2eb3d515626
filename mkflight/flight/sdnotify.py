"""systemd notifications (``sd_notify``) with the standard library only.

Under a ``Type=notify`` unit (``tools/mkflight.service``) systemd passes the path of a
datagram socket in ``NOTIFY_SOCKET`` and, with ``WatchdogSec=``, the watchdog period in
``WATCHDOG_USEC``. SPEC §7: the daemon sends ``READY=1`` after the pre-flight checks,
``WATCHDOG=1`` from the control step (so a stalled loop gets the service killed) and a
``STATUS=`` line. Outside systemd every method is a no-op.

Nothing here raises into the flight: a notification that cannot be sent (socket gone,
receive queue full: the socket is non-blocking so a send never waits) is counted in
:attr:`Notifier.failures` and the first error kept in :attr:`Notifier.error`; the next
call tries again.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from typing import Final, Self

from mkflight.clock import Clock, MonotonicClock
from mkflight.conversions import NS_PER_US, US_PER_S

__all__ = ["Notifier"]

#: Longest STATUS text sent, in UTF-8 bytes (systemd shows one short line anyway).
MAX_STATUS_BYTES: Final = 1024


class Notifier:
    """Sends ``sd_notify`` datagrams to systemd; a no-op without a socket address.

    Args:
        address: the ``NOTIFY_SOCKET`` value: a path, or ``@name`` for an abstract
            socket; None (or empty) disables every notification.
        watchdog_usec: the watchdog period ``WATCHDOG_USEC`` in µs, or None (no
            watchdog: :meth:`watchdog` sends nothing).
        clock: the clock the watchdog rate limit runs on (default monotonic). systemd
            times the watchdog in real time, so the daemon passes no simulated clock here.
    """

    def __init__(
        self,
        address: str | None,
        *,
        watchdog_usec: int | None = None,
        clock: Clock | None = None,
    ) -> None:
        self._clock = clock or MonotonicClock()
        self.sent = 0
        self.failures = 0
        self.error: OSError | None = None
        self._address: str | None = None
        self._socket: socket.socket | None = None
        if address and address[0] in "/@":
            self._address = "\0" + address[1:] if address[0] == "@" else address
        elif address:  # e.g. systemd's "vsock:" addresses: not supported here
            self.error = OSError(f"unsupported NOTIFY_SOCKET address {address!r}")
        #: Seconds between watchdog pings: half the watchdog period (two per period);
        #: None without a watchdog.
        self.watchdog_interval_s: float | None = None
        self._min_ping_gap_ns = 0
        if watchdog_usec is not None and watchdog_usec > 0:
            self.watchdog_interval_s = watchdog_usec / US_PER_S / 2
            self._min_ping_gap_ns = watchdog_usec * NS_PER_US // 4  # interval / 2, in ns
        self._last_ping_ns: int | None = None

    @classmethod
    def from_env(
        cls,
        environ: Mapping[str, str] | None = None,
        *,
        pid: int | None = None,
        clock: Clock | None = None,
    ) -> Self:
        """Build from ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``.

        The watchdog is off when ``WATCHDOG_USEC`` is missing, not a positive integer, or
        when ``WATCHDOG_PID`` is set to another process's id (the variables were meant
        for a parent and leaked into us).

        Args:
            environ: the environment (default ``os.environ``).
            pid: this process's id (default ``os.getpid()``).
            clock: see the constructor.
        """
        env = os.environ if environ is None else environ
        usec: int | None = None
        try:
            usec = int(env.get("WATCHDOG_USEC", ""))
        except ValueError:
            usec = None
        watchdog_pid = env.get("WATCHDOG_PID")
        if watchdog_pid is not None:
            try:
                mine = int(watchdog_pid) == (os.getpid() if pid is None else pid)
            except ValueError:
                mine = False
            if not mine:
                usec = None
        return cls(env.get("NOTIFY_SOCKET"), watchdog_usec=usec, clock=clock)

    @property
    def enabled(self) -> bool:
        """True if notifications go somewhere (a socket address was given)."""
        return self._address is not None

    def ready(self, status: str | None = None) -> bool:
        """Tell systemd start-up is complete (``READY=1``, optionally with a STATUS)."""
        fields = ["READY=1"]
        if status is not None:
            fields.append(_status_field(status))
        return self.notify(*fields)

    def status(self, text: str) -> bool:
        """Set the one-line status ``systemctl status`` shows (newlines become spaces)."""
        return self.notify(_status_field(text))

    def stopping(self) -> bool:
        """Tell systemd the daemon is shutting down (``STOPPING=1``)."""
        return self.notify("STOPPING=1")

    def watchdog(self) -> bool:
        """Ping the watchdog (``WATCHDOG=1``), at most once per ``watchdog_interval_s / 2``.

        Called from every 50 ms control step; only the pings that are due are sent, so
        systemd gets about four per watchdog period (a late step or a lost datagram does
        not trip it). A ping that fails is retried on the next call. Returns True if one
        was sent now.
        """
        if self.watchdog_interval_s is None or self._address is None:
            return False
        now_ns = self._clock.now_ns()
        last_ns = self._last_ping_ns
        if last_ns is not None and 0 <= now_ns - last_ns < self._min_ping_gap_ns:
            return False
        if not self.notify("WATCHDOG=1"):
            return False
        self._last_ping_ns = now_ns
        return True

    def notify(self, *fields: str) -> bool:
        """Send ``KEY=VALUE`` fields in one datagram; True if it was sent.

        Never raises: a failure is counted in :attr:`failures`, the first kept in
        :attr:`error`.
        """
        if self._address is None or not fields:
            return False
        payload = "\n".join(fields).encode("utf-8")
        try:
            if self._socket is None:
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                sock.setblocking(False)
                self._socket = sock
            self._socket.sendto(payload, self._address)
        except OSError as err:
            self.failures += 1
            if self.error is None:
                self.error = err
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        """Close the socket (idempotent); later calls open a new one."""
        sock, self._socket = self._socket, None
        if sock is not None:
            sock.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _status_field(text: str) -> str:
    """``STATUS=text`` on one line (a newline would start a new field), length-capped."""
    line = " ".join(text.replace("\0", " ").splitlines())
    data = line.encode("utf-8")[:MAX_STATUS_BYTES]
    return "STATUS=" + data.decode("utf-8", errors="ignore")
