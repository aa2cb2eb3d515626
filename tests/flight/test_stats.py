"""The daemon's timing figures (flight/stats.py): latency, period, jitter, missed steps."""

from __future__ import annotations

import math

import pytest

from mkflight.flight.stats import StepStats, percentile

MS = 1_000_000


def test_percentile_nearest_rank() -> None:
    assert percentile([], 50) != percentile([], 50)  # NaN
    assert percentile([3.0, 1.0, 2.0], 50) == 2.0
    assert percentile(list(map(float, range(1, 101))), 99) == 99.0
    assert percentile([5.0], 99) == 5.0


def test_regular_steps_have_no_jitter_and_latency_is_write_minus_arrival() -> None:
    s = StepStats()
    for k in range(100):
        arrival = k * 53 * MS
        s.on_step(arrival, arrival + MS // 2, arrival + 2 * MS)
    d = s.summary()
    assert d["steps"] == 100
    assert d["latency_median_ms"] == pytest.approx(0.5)
    assert d["period_median_ms"] == pytest.approx(53.0)
    assert d["jitter_p99_ms"] == 0.0
    assert d["added_jitter_p99_ms"] == 0.0
    assert d["missed_steps"] == 0
    assert d["overruns"] == 0


def test_missed_steps_overruns_and_queued_commands_are_counted() -> None:
    s = StepStats()
    t = 0
    for k in range(50):
        t += 106 * MS if k == 20 else 53 * MS  # one DebugOut lost
        written = None if k == 30 else t + MS
        s.on_step(t, written, t + (20 * MS if k == 40 else MS))
    d = s.summary()
    assert d["missed_steps"] == 1
    assert d["delayed_commands"] == 1
    assert d["overruns"] == 1
    assert d["busy_p99_ms"] == pytest.approx(20.0)


def test_resubscription_intervals_are_the_fcs_not_jitter() -> None:
    """After a 'd' the FC answers at once (a short interval): counted apart, not jitter."""
    s = StepStats()
    t = 0
    for k in range(60):
        if k % 20 == 10:
            s.on_resubscribe()
            t += 25 * MS
        else:
            t += 53 * MS
        s.on_step(t, t + MS, t + 2 * MS)
    d = s.summary()
    assert d["restarted_periods"] == 3
    assert d["jitter_p99_ms"] == 0.0
    assert d["missed_steps"] == 0


def test_added_jitter_is_the_change_of_latency() -> None:
    s = StepStats()
    for k in range(100):
        arrival = k * 53 * MS
        lat = 3 * MS if k % 10 == 5 else MS
        s.on_step(arrival, arrival + lat, arrival + lat)
    d = s.summary()
    assert d["added_jitter_p99_ms"] == pytest.approx(2.0)
    assert math.isfinite(s.last_latency_ms())


def test_gc_watch_records_collections_and_pauses() -> None:
    import gc

    from mkflight.flight.monitor import GcWatch

    watch = GcWatch()
    watch.install()
    watch.install()  # idempotent: one callback
    try:
        gc.collect()
        gc.collect(0)
    finally:
        watch.uninstall()
    d = watch.summary()
    assert d["collections"] == 2
    assert d["full_collections"] == 1
    assert d["max_pause_ms"] > 0
    gc.collect()  # after uninstall: not counted
    assert watch.summary()["collections"] == 2


def test_ring_keeps_the_newest_in_order_and_does_not_grow() -> None:
    from mkflight.flight.stats import Ring

    r = Ring(4)
    assert len(r) == 0
    with pytest.raises(IndexError):
        r.last()
    for v in range(3):
        r.append(v)
    assert r.values().tolist() == [0, 1, 2]
    for v in range(3, 10):
        r.append(v)
    assert len(r) == 4
    assert r.last() == 9
    assert r.values().tolist() == [6, 7, 8, 9]


def test_a_long_flight_keeps_the_newest_steps() -> None:
    from mkflight.flight.stats import KEEP

    s = StepStats()
    for k in range(KEEP + 500):
        arrival = k * 53 * MS
        lat = 7 * MS if k < 500 else MS  # only the oldest 500 were slow: dropped
        s.on_step(arrival, arrival + lat, arrival + lat)
    d = s.summary()
    assert d["steps"] == KEEP + 500
    assert d["latency_max_ms"] == pytest.approx(1.0)
    assert len(s.latency_ns) == KEEP
