"""A short history of vehicle states, for measurements timed in the past (the URG's beams).

A URG scan's beams are measured over 70 ms, each at its own time, and a scan is only
built once its last beam is measured; the vehicle has moved on by then. The live world
(:mod:`mkflight.sim.world`) and the lock-step ``sim hover --scans``
(:mod:`mkflight.sim.hover`) both keep the states they stepped through, at least every
few milliseconds, and answer "where was the URG at ``t``" by linear interpolation
between the two stored states around ``t`` (yaw along the short way round). Pure: the
owner appends states in time order and drops the old ones.
"""

from __future__ import annotations

import bisect
import math
from collections import deque

from mkflight.sim.urg_scene import ScenePose
from mkflight.sim.vehicle import VehicleState


def scene_pose(s: VehicleState) -> ScenePose:
    """The URG's pose of a vehicle state (world frame W, height up)."""
    return ScenePose(
        x_m=s.pos_w_m[0],
        y_m=s.pos_w_m[1],
        yaw_rad=s.yaw_rad,
        height_m=s.height_m,
        roll_rad=s.roll_rad,
        pitch_rad=s.pitch_rad,
    )


def interpolate_pose(
    t_ns: int, a: tuple[int, VehicleState], b: tuple[int, VehicleState]
) -> ScenePose:
    """The pose at ``t_ns`` between the stored states ``a = (t_a, s_a)`` and ``b`` (linear).

    Yaw goes the short way round; ``t_b <= t_a`` gives ``a``'s pose.
    """
    (ti, sa), (tj, sb) = a, b
    if tj <= ti:
        return scene_pose(sa)
    w = (t_ns - ti) / (tj - ti)
    dyaw = math.remainder(sb.yaw_rad - sa.yaw_rad, math.tau)
    return ScenePose(
        x_m=sa.pos_w_m[0] + w * (sb.pos_w_m[0] - sa.pos_w_m[0]),
        y_m=sa.pos_w_m[1] + w * (sb.pos_w_m[1] - sa.pos_w_m[1]),
        yaw_rad=math.remainder(sa.yaw_rad + w * dyaw, math.tau),
        height_m=sa.height_m + w * (sb.height_m - sa.height_m),
        roll_rad=sa.roll_rad + w * (sb.roll_rad - sa.roll_rad),
        pitch_rad=sa.pitch_rad + w * (sb.pitch_rad - sa.pitch_rad),
    )


class StateHistory:
    """``(t_ns, state)`` pairs in time order, the newest ``keep_ns`` of them (module doc)."""

    def __init__(self, keep_ns: int, t_ns: int, state: VehicleState) -> None:
        """Start with ``state`` at ``t_ns``; keep at least ``keep_ns`` of history."""
        self.keep_ns = keep_ns
        self._h: deque[tuple[int, VehicleState]] = deque([(t_ns, state)])

    def __len__(self) -> int:
        return len(self._h)

    @property
    def newest(self) -> tuple[int, VehicleState]:
        """The last pair appended."""
        return self._h[-1]

    def append(self, t_ns: int, state: VehicleState) -> None:
        """Add the state at ``t_ns`` (not before the newest) and drop what is too old."""
        h = self._h
        h.append((t_ns, state))
        horizon = t_ns - self.keep_ns
        while len(h) > 2 and h[1][0] <= horizon:
            h.popleft()

    def bracket(self, t_ns: int) -> tuple[int, int]:
        """Indexes ``(i, j)`` with ``t_i <= t_ns <= t_j`` (clamped to the ends)."""
        h = self._h
        j = bisect.bisect_left(h, t_ns, key=lambda e: e[0])
        if j <= 0:
            return 0, 0
        if j >= len(h):
            return len(h) - 1, len(h) - 1
        return j - 1, j

    def nearest(self, t_ns: int) -> VehicleState:
        """The stored state nearest ``t_ns``."""
        i, j = self.bracket(t_ns)
        (ti, si), (tj, sj) = self._h[i], self._h[j]
        return si if t_ns - ti <= tj - t_ns else sj

    def pose_at(self, t_ns: int) -> ScenePose:
        """The interpolated pose at ``t_ns`` (clamped to the oldest and newest states)."""
        i, j = self.bracket(t_ns)
        return interpolate_pose(t_ns, self._h[i], self._h[j])


__all__ = ["StateHistory", "interpolate_pose", "scene_pose"]
