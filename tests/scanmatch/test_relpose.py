"""The test helper's relation metric (``tests/scanmatch/relpose.py``) and the data it scores."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from mkflight.scanmatch.trajectory import read_trajectory

from .relpose import (
    HOVER_100_GT,
    HOVER_100_RELATIONS,
    FloatArray,
    motion,
    read_relations,
    score,
)

#: The anchor's own scorer, relative to the shared folder.
RELPOSE_EVAL = "tools/relpose_eval.py"


def poses(*rows: tuple[float, float, float]) -> FloatArray:
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def test_motion_is_the_end_pose_in_the_start_frame() -> None:
    start = poses((1.0, 2.0, math.pi / 2))
    end = poses((1.0, 3.0, math.pi / 2 + 0.1))  # 1 m ahead of a robot facing +y
    assert motion(start, end) == pytest.approx(poses((1.0, 0.0, 0.1)))
    # Across +-pi the heading change is the short way round.
    assert motion(poses((0.0, 0.0, 3.1)), poses((0.0, 0.0, -3.1)))[0, 2] == pytest.approx(
        2 * math.pi - 6.2
    )


def test_a_known_error_is_scored() -> None:
    """Reference: 1 m straight ahead; estimate: 1.01 m and 2 mrad left."""
    relations = np.array([[0.0, 0.1, 1.0, 0.0, 0.0]])
    got = score(np.array([0.0, 0.1]), poses((5.0, 5.0, 0.0), (6.01, 5.0, 0.002)), relations)
    assert (got.relations, got.matched) == (1, 1)
    assert got.trans_mean_m == pytest.approx(0.01)
    assert got.rot_mean_rad == pytest.approx(0.002)
    # The same error in a turned frame scores the same: the metric compares motions.
    turned = poses((0.0, 0.0, 2.0), (1.01 * math.cos(2.0), 1.01 * math.sin(2.0), 2.002))
    again = score(np.array([0.0, 0.1]), turned, relations)
    assert again.trans_mean_m == pytest.approx(0.01)
    assert again.rot_mean_rad == pytest.approx(0.002)


def test_times_match_within_one_millisecond_only() -> None:
    relations = np.array([[0.0, 0.1, 1.0, 0.0, 0.0], [0.1, 0.2, 1.0, 0.0, 0.0]])
    trajectory = poses((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0))
    near = score(np.array([0.0, 0.1009, 0.2]), trajectory, relations)
    assert near.matched == 2
    assert near.trans_max_m == pytest.approx(0.0, abs=1e-12)
    far = score(np.array([0.0, 0.1011, 0.2]), trajectory, relations)
    assert (far.relations, far.matched) == (2, 0)
    assert math.isnan(far.trans_mean_m)


def test_the_ground_truth_scores_zero_on_every_relation() -> None:
    """The in-project relations agree with the in-project ground truth, to their 6 decimals."""
    t, p = read_trajectory(HOVER_100_GT)
    relations = read_relations(HOVER_100_RELATIONS)
    got = score(t, p, relations)
    assert (got.relations, got.matched) == (189, 189)
    assert got.trans_max_m <= 2e-6
    assert got.rot_max_rad <= 2e-6


def _relpose_eval(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("relpose_eval", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.shared(RELPOSE_EVAL)
def test_same_figures_as_the_shared_scorer(shared_dir: Path, tmp_path: Path) -> None:
    """A noisy copy of the ground truth, scored here and by the anchor's tool."""
    t, p = read_trajectory(HOVER_100_GT)
    rng = np.random.default_rng(3)
    noisy = p + rng.normal(0.0, [0.01, 0.01, 0.01], p.shape)
    noisy[40, 2] += 2 * math.pi  # a heading off by a turn is the same heading
    traj = tmp_path / "traj.txt"
    np.savetxt(traj, np.column_stack((t, noisy)), fmt="%.9f")
    ours = score(*read_trajectory(traj), read_relations(HOVER_100_RELATIONS))
    tool = _relpose_eval(shared_dir / RELPOSE_EVAL)
    tt, tp = tool.load_traj(str(traj))
    theirs = tool.evaluate(tt, tp, tool.load_relations(str(HOVER_100_RELATIONS)))
    assert (theirs["relations"], theirs["matched"]) == (ours.relations, ours.matched)
    for key in ("trans_mean_m", "trans_max_m", "rot_mean_rad", "rot_max_rad"):
        assert theirs[key] == pytest.approx(getattr(ours, key), rel=1e-9), key
