"""Sensor-to-host clock mapping: offset from the smallest delays, drift from their slope."""

from __future__ import annotations

import numpy as np
import pytest

from mkflight.urg.timesync import SensorClock

NS_PER_MS = 1_000_000


def simulate(
    drift_ppm: float, offset_ms: float, seconds: float, seed: int = 0
) -> tuple[SensorClock, float, float]:
    """Scans every 100 ms with 0-20 ms random extra delay (USB, scheduling)."""
    rng = np.random.default_rng(seed)
    clock = SensorClock()
    true_offset_ns = offset_ms * NS_PER_MS
    sensor_ms = 0.0
    for _ in range(int(seconds * 10)):
        sensor_ms += 100.0
        happened_ns = sensor_ms * NS_PER_MS * (1 + drift_ppm * 1e-6) + true_offset_ns
        arrival_ns = happened_ns + rng.exponential(3.0) * NS_PER_MS
        clock.observe(sensor_ms, int(arrival_ns))
    truth_ns = sensor_ms * NS_PER_MS * (1 + drift_ppm * 1e-6) + true_offset_ns
    return clock, truth_ns, sensor_ms


@pytest.mark.parametrize("drift_ppm", [0.0, 50.0, -80.0, 150.0])
def test_maps_sensor_time_to_host_time_within_a_millisecond(drift_ppm: float) -> None:
    clock, truth_ns, sensor_ms = simulate(drift_ppm, offset_ms=123_456.0, seconds=300)
    assert abs(clock.to_host_ns(sensor_ms) - truth_ns) < 1 * NS_PER_MS
    assert clock.drift_ppm == pytest.approx(drift_ppm, abs=20.0)


def test_large_delays_do_not_pull_the_estimate_up() -> None:
    clock = SensorClock()
    clock.observe(0.0, 5 * NS_PER_MS)  # offset 5 ms, no delay
    for k in range(1, 50):
        clock.observe(k * 100.0, (k * 100 + 5 + 40) * NS_PER_MS)  # 40 ms late each time
    # Rises at most 200 ppm of 4.9 s = ~1 ms, not the 40 ms of the late samples.
    assert clock.to_host_ns(4900.0) - 4905 * NS_PER_MS < 1.1 * NS_PER_MS


def test_known_minimum_delay_is_removed() -> None:
    clock = SensorClock()
    clock.observe(1000.0, 2071 * NS_PER_MS, min_delay_ns=71 * NS_PER_MS)
    assert clock.to_host_ns(1000.0) == 2000 * NS_PER_MS


def test_unsynced_clock_raises_and_reset_forgets() -> None:
    clock = SensorClock()
    with pytest.raises(RuntimeError, match="not synchronised"):
        clock.to_host_ns(0.0)
    clock.observe(0.0, 10)
    assert clock.synced
    clock.reset()
    assert not clock.synced
