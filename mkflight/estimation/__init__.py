"""State estimation (SPEC §3, §H): per-axis filters and latency compensation.

§ and eq are those of the 2011 QUT CyPhy MikroKopter documentation. :mod:`.filter` holds
the pure per-axis laws of the complementary filter and the laser's velocity (eq 15-20),
:mod:`.kalman` the per-axis Kalman filter (the default), :mod:`.vertical` the height and
vertical speed without the hat;
:mod:`.estimator` the stateful :class:`Estimator` that the flight step feeds with IMU
samples, laser poses and hat heights.
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
