"""The flight shell's small collaborators: stop latch, laser inbox, attitude, status, taps."""

from __future__ import annotations

import asyncio
import math
import os
import signal
from pathlib import Path

import pytest

from mkflight.clock import ManualClock
from mkflight.conversions import NS_PER_S
from mkflight.flight.laser_inbox import ATTITUDE_HISTORY, AttitudeHistory, LaserInbox
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.stats import StepStats
from mkflight.flight.status import StatusDisplay, status_line
from mkflight.flight.stop import StopDeadlineError, StopLatch, stop_signals
from mkflight.flight.taps import PortTaps
from mkflight.flight.tasks import STATUS_PERIOD_S, WATCH_PERIOD_S, watch_sleep_s
from mkflight.logs.raw import RawRecorder, read_raw
from mkflight.safety.failsafe import StopRequest


def _result(seq: int, compute_s: float = 0.002) -> LaserResult:
    return LaserResult(
        scan_t_ns=seq * 100,
        seq=seq,
        pose=None,
        pose_reason="test",
        height_m=None,
        height_reason="test",
        degenerate=False,
        match_valid=False,
        matched_fraction=math.nan,
        new_keyframe=False,
        n_points=0,
        compute_s=compute_s,
        elapsed_s=compute_s,
    )


def test_the_first_stop_request_wins() -> None:
    stop = StopLatch(deadline_s=9.0)
    assert stop.latch(StopRequest.SIGTERM, "SIGTERM", 5)
    assert not stop.latch(StopRequest.DURATION, "--duration 8 s", 7)
    assert (stop.request, stop.reason, stop.at_ns) == (StopRequest.SIGTERM, "SIGTERM", 5)


def test_the_deadline_counts_from_the_first_request() -> None:
    stop = StopLatch(deadline_s=0.5)
    stop.check_deadline(10 * NS_PER_S)  # no request: no deadline
    stop.latch(StopRequest.SIGINT, "SIGINT", NS_PER_S)
    stop.check_deadline(NS_PER_S + NS_PER_S // 2)  # exactly the deadline: still in time
    with pytest.raises(StopDeadlineError, match=r"did not end within 0\.5 s"):
        stop.check_deadline(NS_PER_S + NS_PER_S // 2 + 1)


def test_a_signal_inside_stop_signals_reaches_the_handler() -> None:
    got: list[tuple[StopRequest, str]] = []

    async def main() -> None:
        arrived = asyncio.Event()

        def handler(request: StopRequest, name: str) -> None:
            got.append((request, name))
            arrived.set()

        with stop_signals(asyncio.get_running_loop(), handler):
            os.kill(os.getpid(), signal.SIGHUP)
            await asyncio.wait_for(arrived.wait(), timeout=10.0)

    asyncio.run(main())
    assert got == [(StopRequest.SIGTERM, "SIGHUP")]


def test_the_inbox_counts_matched_results_and_says_when_each_came() -> None:
    inbox = LaserInbox()
    assert inbox.peek() is None
    inbox.put(_result(1, compute_s=0.5))  # the pre-flight's: neither counted nor timed
    inbox.put_matched(_result(2, compute_s=0.002), got_ns=2_000)
    inbox.put_matched(_result(3, compute_s=0.003), got_ns=3_000)
    assert inbox.matches == 2
    assert inbox.matcher_cpu_s == pytest.approx(0.005)
    peeked = inbox.peek()
    assert peeked is not None
    assert peeked.seq == 1
    taken = [inbox.pop(), inbox.pop(), inbox.pop()]
    assert [(r.seq, got) for r, got in taken] == [(1, None), (2, 2_000), (3, 3_000)]
    assert inbox.peek() is None
    with pytest.raises(IndexError):
        inbox.pop()


def test_the_attitude_at_a_time_is_the_nearest_sample_kept() -> None:
    history = AttitudeHistory()
    assert all(math.isnan(v) for v in history.at(0))
    for k in range(ATTITUDE_HISTORY + 10):
        history.add(k * 50, 0.01 * k, -0.01 * k)
    assert history.at(1_001) == pytest.approx((0.2, -0.2))  # sample 20 at 1000 ns
    assert history.at(0) == pytest.approx((0.1, -0.1))  # the oldest kept: sample 10


def test_the_status_line_before_and_after_the_first_step() -> None:
    assert status_line(None, None, math.nan, 0.0) == "waiting for the FlightCtrl"
    display = StatusDisplay(Notifier(None), tty=False)
    display.show("HOLD")  # no socket, no terminal: nothing to do, nothing raised
    display.terminal_gone()
    display.end()


class _Watching(FlightPolicy):
    def __init__(self) -> None:
        self.seen: list[tuple[str, str, int]] = []

    def on_bytes(self, port: str, direction: str, n_bytes: int) -> None:
        self.seen.append((port, direction, n_bytes))

    def on_mark(self, port: str, kind: str) -> None:
        self.seen.append((port, kind, 0))


def test_taps_record_note_commands_and_tell_the_policy(tmp_path: Path) -> None:
    clock = ManualClock(1_000)
    mk = RawRecorder(tmp_path / "mk.raw", "/dev/mk", clock=clock)
    laser = RawRecorder(tmp_path / "laser.raw", "/dev/urg", clock=clock)
    policy, stats = _Watching(), StepStats()
    taps = PortTaps(mk, laser, clock=clock, policy=policy, stats=stats)
    taps.mark("mk", "o", "/dev/mk")
    taps.mk("r", 2_000, b"#aDxyz\r")
    taps.mk("w", 3_000, b"#bbABC\r")  # an ExternControl frame
    taps.mk("w", 4_000, b"#cdAB\r")  # a DebugOut subscription
    taps.laser("w", 5_000, b"MD0044\n")
    mk.close()
    laser.close()
    assert taps.command_written_ns == 3_000
    stats.on_step(6_000, None, 6_000)
    assert stats.restarted_periods == 1  # the 'd' made the next interval the FC's restart
    assert policy.seen == [
        ("mk", "o", 0),
        ("mk", "r", 7),
        ("mk", "w", 7),
        ("mk", "w", 6),
        ("laser", "w", 7),
    ]
    kinds = [r.kind for r in read_raw(tmp_path / "mk.raw").records]
    assert kinds == ["o", "r", "w", "w"]
    assert [r.data for r in read_raw(tmp_path / "laser.raw").records] == [b"MD0044\n"]


def test_the_watchdog_sleeps_until_the_next_thing_it_watches_is_due() -> None:
    latch = StopLatch(9.0)
    now = 100 * NS_PER_S
    # nothing due soon: the status line's period
    assert watch_sleep_s(now, status_in_s=0.5, duration_end_ns=None, stop=latch) == 0.5
    # --duration ends in 0.2 s: wake then
    end = now + int(0.2 * NS_PER_S)
    assert watch_sleep_s(now, status_in_s=0.5, duration_end_ns=end, stop=latch) == 0.2
    # due (or past): the old 50 ms poll, never a busy loop
    assert watch_sleep_s(end, status_in_s=0.5, duration_end_ns=end, stop=latch) == WATCH_PERIOD_S
    # once a stop is latched --duration no longer matters; its deadline does
    latch.latch(StopRequest.DURATION, "test", now)
    far = now + 60 * NS_PER_S
    assert watch_sleep_s(now, status_in_s=9.9, duration_end_ns=far, stop=latch) == STATUS_PERIOD_S
    late = now + int(8.9 * NS_PER_S)
    assert math.isclose(
        watch_sleep_s(late, status_in_s=0.5, duration_end_ns=far, stop=latch), 0.1, abs_tol=1e-9
    )
