"""HoldMonitor's precision: running sums that match numpy's std, in constant memory."""

from __future__ import annotations

import sys

import numpy as np

from mkflight.control.controller import Setpoint
from mkflight.control.phases import Phase
from mkflight.flight.monitor import SETTLE_S, HoldMonitor
from mkflight.msgs import Estimate


def _estimate(x: float, y: float, h: float) -> Estimate:
    return Estimate(
        t_ns=0, x_m=x, y_m=y, yaw_rad=0.0, height_m=h, vx_mps=0.0, vy_mps=0.0, vz_up_mps=0.0
    )


def test_precision_equals_numpy_std_and_memory_stays_flat() -> None:
    rng = np.random.default_rng(4)
    errors = rng.normal([0.01, -0.02, 0.0], [0.02, 0.03, 0.005], (3000, 3))
    sp = Setpoint(x_m=1.0, y_m=2.0, height_m=0.6, yaw_rad=0.0)
    mon = HoldMonitor()
    settle_steps = int(SETTLE_S * 20)  # t < SETTLE_S: not counted
    t_ns = 0
    size_after_first = 0
    for i in range(settle_steps + len(errors)):
        e = errors[i - settle_steps] if i >= settle_steps else (9.0, 9.0, 9.0)  # settling: ignored
        est = _estimate(1.0 + e[0], 2.0 + e[1], 0.6 + e[2])
        mon.on_step(t_ns, Phase.HOLD, est, sp, False, matcher_cpu_s=0.0)
        t_ns += 50_000_000
        if i == settle_steps:
            size_after_first = sys.getsizeof(mon._mean) + sys.getsizeof(mon._m2)
    p = mon.precision()
    assert p is not None
    std = np.std(errors, axis=0)
    assert p["samples"] == len(errors)
    assert abs(p["std_x_m"] - std[0]) < 1e-5
    assert abs(p["std_y_m"] - std[1]) < 1e-5
    assert abs(p["std_z_m"] - std[2]) < 1e-5
    assert sys.getsizeof(mon._mean) + sys.getsizeof(mon._m2) == size_after_first


def test_no_precision_without_two_samples() -> None:
    assert HoldMonitor().precision() is None
