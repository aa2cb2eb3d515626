"""A 2D room model (wall segments) and a vectorised laser ray caster.

Used by the scan-matcher tests and, later, the URG emulator. The API is deliberately small:

* :class:`Room` -- an (n, 4) array of wall segments ``x1 y1 x2 y2`` in metres.
* :func:`box_room` -- a rectangular room with optional rectangular obstacles.
* :func:`random_room` -- a seeded random polygon room with boxes and pillars.
* :func:`raycast` -- ranges seen from a pose: NaN where no wall is within range.

Frame: standard 2D math, angles counter-clockwise from +x toward +y. SPEC's body frame
(x forward, y right, yaw clockwise) is the same math written in ``(x, y_right)``
coordinates, so a caller that keeps y right and clockwise angles gets consistent results.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
Rect = tuple[float, float, float, float]  # x_min, y_min, x_max, y_max


@dataclass(frozen=True, slots=True, eq=False)
class Room:
    """Wall segments of a room.

    Attributes:
        walls_m: (n, 4) float64 array, one segment ``x1 y1 x2 y2`` (metres) per row.
    """

    walls_m: FloatArray

    def __post_init__(self) -> None:
        walls = np.asarray(self.walls_m, dtype=np.float64).reshape(-1, 4)
        object.__setattr__(self, "walls_m", walls)

    @property
    def n_walls(self) -> int:
        """Number of wall segments."""
        return int(self.walls_m.shape[0])


def polygon_walls(vertices: Sequence[tuple[float, float]]) -> FloatArray:
    """The closed polygon through ``vertices`` as (n, 4) segments."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    return np.hstack((v, np.roll(v, -1, axis=0)))


def rect_walls(rect: Rect) -> FloatArray:
    """The four sides of an axis-aligned rectangle ``(x_min, y_min, x_max, y_max)``."""
    x0, y0, x1, y1 = rect
    return polygon_walls([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])


def box_room(width_m: float, depth_m: float, obstacles: Sequence[Rect] = ()) -> Room:
    """A ``width_m`` (x) by ``depth_m`` (y) room centred on the origin, with boxes inside.

    Args:
        width_m: extent along x.
        depth_m: extent along y.
        obstacles: axis-aligned rectangles ``(x_min, y_min, x_max, y_max)``.
    """
    hw, hd = width_m / 2.0, depth_m / 2.0
    parts = [rect_walls((-hw, -hd, hw, hd))] + [rect_walls(r) for r in obstacles]
    return Room(np.vstack(parts))


def random_room(
    seed: int,
    *,
    radius_m: tuple[float, float] = (2.5, 4.5),
    n_vertices: tuple[int, int] = (5, 9),
    n_obstacles: tuple[int, int] = (1, 4),
) -> Room:
    """A seeded random room: a star-shaped polygon around the origin plus boxes and pillars.

    The polygon's vertices lie at increasing angles with radii in ``radius_m``, so the
    origin always sees every wall; obstacles are small squares (pillars) or rectangles
    (boxes) placed at least 1 m from the origin, so a sensor near the origin is clear.

    Args:
        seed: the random seed (the same seed gives the same room).
        radius_m: range of the vertex distances from the origin.
        n_vertices: inclusive range of the polygon's vertex count.
        n_obstacles: inclusive range of the obstacle count.
    """
    rng = np.random.default_rng(seed)
    n = int(rng.integers(n_vertices[0], n_vertices[1] + 1))
    # Evenly spread vertex angles with a little jitter, so the polygon is not a sliver.
    jitter = rng.uniform(-0.25, 0.25, n)
    angles = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False) + jitter + rng.uniform(0, 6.3)
    radii = rng.uniform(radius_m[0], radius_m[1], n)
    verts = [
        (float(r * math.cos(a)), float(r * math.sin(a))) for r, a in zip(radii, angles, strict=True)
    ]
    parts = [polygon_walls(verts)]
    r_in = radius_m[0] * math.cos(math.pi / max(n, 3))  # a radius inside the polygon
    for _ in range(int(rng.integers(n_obstacles[0], n_obstacles[1] + 1))):
        dist = rng.uniform(1.0, max(1.1, r_in - 0.6))
        bearing = rng.uniform(0.0, 2.0 * math.pi)
        cx, cy = dist * math.cos(bearing), dist * math.sin(bearing)
        if rng.random() < 0.5:
            hx = hy = float(rng.uniform(0.1, 0.2))  # pillar
        else:
            hx, hy = float(rng.uniform(0.15, 0.4)), float(rng.uniform(0.15, 0.4))  # box
        parts.append(rect_walls((cx - hx, cy - hy, cx + hx, cy + hy)))
    return Room(np.vstack(parts))


def room_caster(room: Room) -> Callable[..., FloatArray]:
    """``raycast`` bound to ``room``: the ray caster a URG scene takes."""
    return functools.partial(raycast, room)


def raycast(
    room: Room,
    x_m: float,
    y_m: float,
    theta_rad: float,
    angles_rad: npt.ArrayLike,
    max_range_m: float,
) -> FloatArray:
    """Ranges from the pose ``(x_m, y_m, theta_rad)`` along the beams ``angles_rad``.

    Each beam leaves the sensor at ``theta_rad + angle`` (counter-clockwise) and returns
    the distance to the nearest wall it crosses. Vectorised over beams x walls (no
    Python loop), so 682 beams against 30 walls take well under a millisecond.

    Args:
        room: the walls.
        x_m: sensor x.
        y_m: sensor y.
        theta_rad: sensor heading.
        angles_rad: (n,) beam angles relative to the heading.
        max_range_m: beams that hit nothing closer than this return NaN.

    Returns:
        (n,) float64 ranges in metres, NaN where nothing is hit within ``max_range_m``.
    """
    a = np.asarray(angles_rad, dtype=np.float64).ravel() + theta_rad
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]  # (n, 1)
    w = room.walls_m
    if w.shape[0] == 0:
        return np.full(a.shape, np.nan)
    ex, ey = (w[:, 2] - w[:, 0])[None, :], (w[:, 3] - w[:, 1])[None, :]  # (1, m)
    ox, oy = (w[:, 0] - x_m)[None, :], (w[:, 1] - y_m)[None, :]
    # Solve origin + t*d = wall_start + u*e  for t (range) and u (position on the wall).
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ox * ey - oy * ex) / den
        u = (ox * dy - oy * dx) / den
        hit = (np.abs(den) > 1e-12) & (t > 1e-9) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    r: FloatArray = np.asarray(t.min(axis=1), dtype=np.float64)
    r[~(r < max_range_m)] = np.nan
    return r
