from __future__ import annotations

import os
import socket
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from mkflight.clock import ManualClock
from mkflight.flight.sdnotify import MAX_STATUS_BYTES, Notifier

MS_NS = 1_000_000
_SUN_PATH_MAX = 107  # sockaddr_un.sun_path holds 108 bytes with the NUL


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A bound unix datagram socket standing in for systemd, and its NOTIFY_SOCKET value."""
    folder = tmp_path
    short: tempfile.TemporaryDirectory[str] | None = None
    if len(str(tmp_path / "notify").encode()) > _SUN_PATH_MAX:
        short = tempfile.TemporaryDirectory(dir="/tmp")
        folder = Path(short.name)
    path = str(folder / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5.0)  # a guard only: every datagram is queued before send returns
    yield sock, path
    sock.close()
    if short is not None:
        short.cleanup()


def _pending(sock: socket.socket) -> list[str]:
    """Every datagram already queued on ``sock`` (without waiting)."""
    out: list[str] = []
    sock.setblocking(False)
    try:
        while True:
            out.append(sock.recv(4096).decode())
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(5.0)
    return out


def test_ready_status_stopping_datagrams(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    with Notifier.from_env({"NOTIFY_SOCKET": path}) as n:
        assert n.enabled
        assert n.watchdog_interval_s is None
        assert n.ready(status="pre-flight ok")
        assert n.status("hold h=0.60 m\nREADY=1 err=0.03 m")
        assert n.stopping()
        assert not n.watchdog()  # no WATCHDOG_USEC: nothing to ping
        assert (n.sent, n.failures, n.error) == (3, 0, None)
    assert _pending(sock) == [
        "READY=1\nSTATUS=pre-flight ok",
        "STATUS=hold h=0.60 m READY=1 err=0.03 m",  # a newline cannot inject a field
        "STOPPING=1",
    ]


def test_status_is_capped(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    with Notifier(path) as n:
        assert n.status("é" * MAX_STATUS_BYTES)
    (got,) = _pending(sock)
    assert got == "STATUS=" + "é" * (MAX_STATUS_BYTES // 2)


@pytest.mark.skipif(sys.platform != "linux", reason="abstract sockets are Linux only")
def test_abstract_socket() -> None:
    name = f"mkflight-test-{uuid.uuid4().hex}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(5.0)
        with Notifier.from_env({"NOTIFY_SOCKET": "@" + name}) as n:
            assert n.ready()
        assert sock.recv(4096) == b"READY=1"


def test_watchdog_is_rate_limited(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    clock = ManualClock(1_000 * MS_NS)
    env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}
    n = Notifier.from_env(env, clock=clock)
    assert n.watchdog_interval_s == pytest.approx(1.0)
    sent_at_ms = []
    for step in range(41):  # 2 s of 50 ms control steps
        if n.watchdog():
            sent_at_ms.append(step * 50)
        clock.advance(50 * MS_NS)
    assert sent_at_ms == [0, 500, 1000, 1500, 2000]  # one per interval / 2
    assert _pending(sock) == ["WATCHDOG=1"] * 5
    n.close()


def test_watchdog_pid_of_another_process_disables_the_watchdog(
    listener: tuple[socket.socket, str],
) -> None:
    sock, path = listener
    env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}
    n = Notifier.from_env(env, pid=4242)
    assert n.watchdog_interval_s is None
    assert not n.watchdog()
    assert n.ready()  # READY still goes out: NOTIFY_SOCKET is not PID-bound
    assert _pending(sock) == ["READY=1"]
    n.close()


@pytest.mark.parametrize("usec", ["", "0", "-5", "2s", "1.5"])
def test_bad_watchdog_usec_means_no_watchdog(usec: str) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": "/nonexistent/notify", "WATCHDOG_USEC": usec})
    assert n.watchdog_interval_s is None
    assert not n.watchdog()
    assert n.failures == 0


def test_no_socket_is_a_no_op() -> None:
    n = Notifier.from_env({})
    assert not n.enabled
    assert not n.ready()
    assert not n.status("x")
    assert not n.stopping()
    assert (n.sent, n.failures, n.error) == (0, 0, None)
    unsupported = Notifier.from_env({"NOTIFY_SOCKET": "vsock:2:1234"})
    assert not unsupported.enabled
    assert not unsupported.ready()
    assert unsupported.error is not None
    assert "vsock:2:1234" in str(unsupported.error)


def test_send_failures_are_counted_not_raised(tmp_path: Path) -> None:
    clock = ManualClock()
    n = Notifier(str(tmp_path / "gone"), watchdog_usec=2_000_000, clock=clock)
    assert not n.ready()
    assert not n.watchdog()
    assert not n.watchdog()  # a failed ping is retried at once, not rate-limited
    assert n.failures == 3
    assert isinstance(n.error, FileNotFoundError)
    n.close()


def test_full_receive_queue_does_not_block(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    with Notifier(path) as n:
        for _ in range(100_000):
            if not n.status("x" * 512):
                break
        assert n.failures == 1
        assert isinstance(n.error, BlockingIOError)
        assert _pending(sock)  # the queue was full
        assert n.status("after")  # and the next send works again
    assert _pending(sock) == ["STATUS=after"]
