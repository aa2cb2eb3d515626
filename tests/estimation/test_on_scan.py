"""``Estimator.on_scan``: a scan's pose and height in one replay, bit for bit ``on_pose`` then
``on_height`` (every knot, the estimate, the TABLE III values and the counters)."""

from __future__ import annotations

import math
import random

import pytest

from mkflight.config import EstimationConfig
from mkflight.estimation import Estimator
from mkflight.msgs import ImuSample, Pose2D

G = 9.80665
T_NS = 53_000_000


def _imu(rng: random.Random, t_ns: int) -> ImuSample:
    pitch, roll = rng.gauss(0.0, 0.03), rng.gauss(0.0, 0.03)
    acc = (rng.gauss(0.0, 0.3), rng.gauss(0.0, 0.3), -G + rng.gauss(0.0, 0.3))
    return ImuSample(t_ns, pitch, roll, rng.gauss(0.2, 0.01), *acc, 12.0)


def _scan(rng: random.Random, i: int, t_ns: int) -> tuple[Pose2D | None, int, float | None]:
    """A scan ~60-110 ms old: some at a sample's own time, some missing or absurd."""
    t = t_ns - (T_NS if i % 5 == 0 else rng.randrange(60_000_000, 110_000_000))
    pose: Pose2D | None = Pose2D(t, rng.gauss(0.0, 0.05), rng.gauss(0.0, 0.05), 0.1)
    height: float | None = 0.8 + rng.gauss(0.0, 0.01)
    if i % 7 == 3:
        pose = None
    if i % 11 == 4:
        height = None
    if i % 13 == 6 and pose is not None:
        pose = Pose2D(t, math.nan, 0.0, 0.0)
    if i % 17 == 8:
        height = math.inf
    return pose, t, height


def _state(est: Estimator) -> str:
    """Every knot, the estimate, the TABLE III values, the counters: a float's repr is its
    bits (and a NaN, which no ``==`` matches, compares as one)."""
    knots = est._knots  # the whole history, not only its last knot
    return repr((knots, est.estimate(), est.laser_step, est.counters))


@pytest.mark.parametrize(
    "cfg",
    [
        EstimationConfig(),
        EstimationConfig(latency_compensation=False),
        EstimationConfig(tilt_acceleration=False),
        EstimationConfig(filter="complementary"),
    ],
    ids=["kalman", "no-compensation", "kalman-no-tilt", "complementary"],
)
def test_one_replay_gives_the_two_replays_bits(
    cfg: EstimationConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    joint, apart = Estimator(cfg, G), Estimator(cfg, G)
    replays = {id(joint): 0, id(apart): 0}
    replay = Estimator._replay

    def counted(self: Estimator, start: int, saved: list[object]) -> bool:
        replays[id(self)] += 1
        return replay(self, start, saved)  # type: ignore[arg-type]

    monkeypatch.setattr(Estimator, "_replay", counted)
    rng = random.Random(21)
    joint_scans = 0
    for i in range(400):
        t_ns = (i + 1) * T_NS
        imu = _imu(rng, t_ns)
        thrust = G + rng.gauss(0.0, 0.2) if i > 40 else None
        assert joint.on_imu(imu, thrust) == apart.on_imu(imu, thrust)
        if i == 150:  # the learner's figures arrive: the history is re-filtered with them
            for est in (joint, apart):
                est.set_acc_bias((0.05, -0.03, 0.1))
                est.set_acc_noise((0.2, 0.25, 0.3))
        if i % 2 == 1:
            pose, t_scan, height = _scan(rng, i, t_ns)
            joint.on_scan(pose, t_scan, height)
            if pose is not None:
                apart.on_pose(pose)
            apart.on_height(t_scan, height)
            joint_scans += pose is not None and height is not None
            assert _state(joint) == _state(apart), i
    assert joint_scans > 100
    if cfg.filter == "kalman":  # one replay for most scans, where on_pose, on_height make two
        assert replays[id(joint)] < replays[id(apart)] - joint_scans * 3 // 4
    else:
        assert replays[id(joint)] == replays[id(apart)]
    assert joint.counters.pose_rejected > 0
    assert joint.counters.height_rejected > 0
