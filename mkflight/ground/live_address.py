"""``fly --live [HOST:]PORT``: where the live view listens, checked where it is parsed.

Loopback unless a host is given: the view shows the vehicle's position and is not meant
for every network the vehicle is on (README: reach it over ``ssh -L``). An IPv6 host is
written in brackets (``[::1]:8765``). Port 0 lets the system choose; the command prints
the port it got.
"""

from __future__ import annotations

import argparse
from typing import Final, NamedTuple


class LiveAddress(NamedTuple):
    """A host to bind and a TCP port (0: any free one)."""

    host: str
    port: int

    def url(self) -> str:
        """The WebSocket URL Foxglove's "Open connection" takes."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"


MAX_PORT: Final = 65535

DEFAULT_LIVE: Final = LiveAddress("127.0.0.1", 8765)
"""``--live`` without a value: loopback, Foxglove's usual port."""


def parse_live_address(text: str) -> LiveAddress:
    """``PORT``, ``HOST:PORT`` or ``[IPV6]:PORT`` as a :class:`LiveAddress`.

    Raises:
        argparse.ArgumentTypeError: not one of those, or a port outside 0-65535.
    """
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host = DEFAULT_LIVE.host
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if sep and (not host or (":" in host and not text.startswith("["))):
        msg = f"expected [HOST:]PORT, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    if not (port_text.isascii() and port_text.isdigit()) or int(port_text) > MAX_PORT:
        msg = f"expected [HOST:]PORT with a port 0-65535, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    return LiveAddress(host, int(port_text))
