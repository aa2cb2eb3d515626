"""The FC's DebugOut timing: its loop's jitter and late frames, in the pure model."""

from __future__ import annotations

import itertools
import statistics

import pytest

from mkflight.sim.fc import TICK_NS, FcModel
from mkflight.sim.fc_timing import LATE_MAX_S, LATE_MIN_S, DebugJitter, DebugTiming
from mkflight.sim.sources import FixedSource
from tests.sim.fc_helpers import MK_04, MS, SETTINGS, T0, S, run, times_of

RENEW_NS = 1300 * MS  # the daemon renews the subscription every 1.3 s


def debug_times(timing: DebugTiming, duration_ns: int) -> tuple[FcModel, list[int], list[int]]:
    """The DebugOut times of a model subscribed at T0 + 10 ms and renewed every 1.3 s."""
    fc = FcModel(SETTINGS, FixedSource({}), t_ns=T0, timing=timing)
    renewals = list(range(T0 + 10 * MS, T0 + duration_ns, RENEW_NS))
    chunks = run(fc, T0 + duration_ns, [(t, MK_04) for t in renewals])
    return fc, times_of(chunks, "D"), renewals


def steady_intervals_ticks(times: list[int], renewals: list[int]) -> list[float]:
    """Intervals between DebugOuts with no renewal in between (a renewal answers at once)."""
    return [
        (b - a) / TICK_NS
        for a, b in itertools.pairwise(times)
        if not any(a < r <= b for r in renewals)
    ]


def test_exact_timing_draws_nothing_and_keeps_the_52_tick_period() -> None:
    jitter = DebugJitter(DebugTiming())
    assert [jitter.extra_ticks() for _ in range(100)] == [0] * 100
    _, times, renewals = debug_times(DebugTiming(), 10 * S)
    assert set(steady_intervals_ticks(times, renewals)) == {52.0}


def test_each_interval_is_52_ticks_plus_the_seeded_draw() -> None:
    timing = DebugTiming(jitter_ticks=3, late_fraction=0.05, seed=11)
    fc, gaps = one_subscription_gaps(timing)
    again = DebugJitter(timing)
    extras = [again.extra_ticks() for _ in range(len(gaps) + 1)]
    assert gaps == [52 + e for e in extras[: len(gaps)]]  # the period counts from the send
    assert fc.debug_jitter.frames == len(gaps) + 1  # each frame sent draws its successor's


def one_subscription_gaps(timing: DebugTiming) -> tuple[FcModel, list[float]]:
    """The DebugOut intervals (ticks) of one 'd' 5 without renewal (3.5 s)."""
    fc = FcModel(SETTINGS, FixedSource({}), t_ns=T0, timing=timing)
    times = times_of(run(fc, T0 + 3500 * MS, [(T0 + 10 * MS, MK_04)]), "D")
    return fc, [(b - a) / TICK_NS for a, b in itertools.pairwise(times)]


def test_interval_statistics_match_the_airframe() -> None:
    gaps: list[float] = []
    late_frames = 0
    for seed in range(20):  # 20 subscriptions: no renewal biases which intervals are kept
        fc, some = one_subscription_gaps(DebugTiming(jitter_ticks=3, late_fraction=0.05, seed=seed))
        gaps += some
        late_frames += fc.debug_jitter.late_frames
    assert len(gaps) > 1200
    late_ticks = (LATE_MIN_S + LATE_MAX_S) / 2 * 1e9 / TICK_NS
    expected_mean = 52 + 1.5 + 0.05 * late_ticks  # ≈ 54.2 ticks, 55.5 ms
    assert statistics.mean(gaps) == pytest.approx(expected_mean, abs=0.3)
    on_time = [g for g in gaps if g <= 55]
    assert set(on_time) == {52.0, 53.0, 54.0, 55.0}  # 0..3 ticks of jitter, all drawn
    assert statistics.pstdev(on_time) == pytest.approx(1.118, abs=0.1)  # uniform 0..3
    late = [g for g in gaps if g > 55]
    assert 0.03 * len(gaps) < len(late) < 0.075 * len(gaps)
    assert min(late) >= 52 + round(LATE_MIN_S * 1e9 / TICK_NS)
    assert max(late) <= 55 + round(LATE_MAX_S * 1e9 / TICK_NS)
    assert late_frames >= len(late)  # counted by the model (the last frame's may be unsent)


def test_same_seed_same_frames_other_seed_other_frames() -> None:
    def times(seed: int) -> list[int]:
        return debug_times(DebugTiming(jitter_ticks=2, late_fraction=0.02, seed=seed), 5 * S)[1]

    assert times(4) == times(4)
    assert times(4) != times(5)
