"""State estimation (SPEC §3, seed §H): the complementary filter and latency compensation.

:mod:`.filter` holds the pure per-axis laws (eq 15-20); :mod:`.estimator` the stateful
:class:`Estimator` that the flight step feeds with IMU samples, laser poses and hat heights.
"""

from __future__ import annotations

from mkflight.estimation.estimator import Estimator
from mkflight.estimation.filter import (
    LaserVelocity,
    complementary_step,
    laser_velocity,
    predict_pose,
    rate_of_change,
)
from mkflight.estimation.records import EstimatorCounters, LaserStep

__all__ = [
    "Estimator",
    "EstimatorCounters",
    "LaserStep",
    "LaserVelocity",
    "complementary_step",
    "laser_velocity",
    "predict_pose",
    "rate_of_change",
]
