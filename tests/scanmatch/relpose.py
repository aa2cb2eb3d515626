"""The relation error of a 2D trajectory (Kümmerle et al. 2009), as a test helper.

The same metric as ``../shared/tools/relpose_eval.py`` (the scan-matching anchor's scorer,
``../shared/data/laser/README.md`` "Relations and the error metric"), written again here so
the scan-matcher's accuracy test runs on a clone without the shared folder; a test marked
``shared`` checks that both give the same figures. Kümmerle, Steder, Dornhege, Ruhnke,
Grisetti, Stachniss, Kleiner, "On measuring the accuracy of SLAM algorithms", Autonomous
Robots 27(4), 2009: a relation ``(t1, t2, d_ref)`` is the reference motion from the pose at
``t1`` to the pose at ``t2``, expressed in the frame of the first; the estimate's motion is
``d_est = x(t1)^-1 (+) x(t2)`` and its error ``e = d_ref^-1 (+) d_est``, scored by its
translation ``|(e_x, e_y)|`` (m) and its rotation ``|e_theta|`` (rad, wrapped to (-pi, pi]).
Comparing motions, not poses, keeps one early mistake from counting against every later pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]

#: The small in-project laser set (``tests/data/README.md``): the first 100 scans of the shared
#: ``synth_roomA_hover`` sequence, its exact relations and its ground truth.
LASER_DATA = Path(__file__).resolve().parents[1] / "data" / "laser"
HOVER_100_CLF = LASER_DATA / "synth_roomA_hover_100.clf.gz"
HOVER_100_RELATIONS = LASER_DATA / "synth_roomA_hover_100.relations"
HOVER_100_GT = LASER_DATA / "synth_roomA_hover_100.gt.txt"

#: Two timestamps name the same scan when they are this close (the tool's default ``--tol``).
MATCH_TOL_S = 1e-3


@dataclass(frozen=True, slots=True)
class RelationScore:
    """The errors over the relations whose two times both found a pose."""

    relations: int
    matched: int
    trans_mean_m: float
    trans_max_m: float
    rot_mean_rad: float
    rot_max_rad: float


def read_relations(path: Path) -> FloatArray:
    """Rows ``t1 t2 x y yaw`` of a Freiburg relations file (``t1 t2 x y z roll pitch yaw``).

    z, roll and pitch are dropped: the metric is planar. ``#`` lines and blank lines are skipped.
    """
    rows: list[list[float]] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        t1, t2, x, y, _z, _roll, _pitch, yaw = (float(v) for v in fields[:8])
        rows.append([t1, t2, x, y, yaw])
    return np.array(rows, dtype=np.float64).reshape(-1, 5)


def motion(start: FloatArray, end: FloatArray) -> FloatArray:
    """``start^-1 (+) end`` for rows ``x y theta``: ``end`` seen from ``start``'s frame.

    The heading difference is wrapped to (-pi, pi], so a turn across +-pi counts as small.
    """
    cos_t = np.cos(start[:, 2])
    sin_t = np.sin(start[:, 2])
    dx = end[:, 0] - start[:, 0]
    dy = end[:, 1] - start[:, 1]
    dtheta = np.angle(np.exp(1j * (end[:, 2] - start[:, 2])))
    return np.column_stack((cos_t * dx + sin_t * dy, cos_t * dy - sin_t * dx, dtheta))


def pose_index(times_s: FloatArray, queries_s: FloatArray, tol_s: float) -> IndexArray:
    """For each query time, the index of the nearest trajectory time, or -1 beyond ``tol_s``."""
    gaps = np.abs(queries_s[:, None] - times_s[None, :])
    nearest = gaps.argmin(axis=1)
    within = gaps[np.arange(len(queries_s)), nearest] <= tol_s
    return np.where(within, nearest, -1)


def score(
    times_s: FloatArray, poses: FloatArray, relations: FloatArray, tol_s: float = MATCH_TOL_S
) -> RelationScore:
    """Score a trajectory (``times_s``, rows ``x y theta``) against ``relations``.

    A relation whose either time has no pose within ``tol_s`` is left out (counted in
    ``relations``, not in ``matched``); with none matched, the errors are NaN.
    """
    first = pose_index(times_s, relations[:, 0], tol_s)
    second = pose_index(times_s, relations[:, 1], tol_s)
    ok = (first >= 0) & (second >= 0)
    if not ok.any():
        nan = math.nan
        return RelationScore(len(relations), 0, nan, nan, nan, nan)
    estimated = motion(poses[first[ok]], poses[second[ok]])
    error = motion(relations[ok, 2:5], estimated)
    trans_m = np.hypot(error[:, 0], error[:, 1])
    rot_rad = np.abs(error[:, 2])
    return RelationScore(
        relations=len(relations),
        matched=int(ok.sum()),
        trans_mean_m=float(trans_m.mean()),
        trans_max_m=float(trans_m.max()),
        rot_mean_rad=float(rot_rad.mean()),
        rot_max_rad=float(rot_rad.max()),
    )
