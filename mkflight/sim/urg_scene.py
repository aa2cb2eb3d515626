"""Range sources for the URG model: a fixed table, and a room seen from a pose.

Both satisfy :class:`mkflight.sim.urg.RangeSource`. :class:`RoomScene` is what the
simulator uses (SPEC §8, data README ``shared/data/laser/README.md``):

The hat is the simulated airframe's own (:class:`HatGeometry`, from
:class:`~mkflight.sim.vehicle.VehicleParams`: ``hat_steps``, ``mirror_edge_last_step``,
``hat_offset_m``), never the flight code's ``laser`` section: the flight's idea of its hat
is checked against it, not copied from it.

- **hat steps** (default 44-127): the mirror folds them down to the floor. We model the
  folded beams as leaving straight down along the body's z axis from a point
  ``hat_offset_m`` above the floor contact, so the slant range is
  ``(height_m + hat_offset_m) / (cos(pitch) * cos(roll))`` + noise: SPEC eq 26 inverted
  exactly, which the hat estimator turns back into ``height_m``.
- **mirror edge** (the steps after the hat up to ``mirror_edge_last_step``, default
  128-149): half read 0, half junk of 30-80 mm (valid-looking, as in the synthetic data
  sets).
- **scan steps** (every other step, default 150-725): each beam is ray-cast in the room
  from the pose at the time its group of steps is measured (the sweep takes 70 ms, so a
  moving vehicle smears the scan), tilted with roll and pitch; 1 cm Gaussian noise,
  rounded to mm; no hit or beyond DMAX -> 0; a small fraction replaced by error codes 1,
  2 or 7.

Frames: the pose is in mkflight's world frame W (SPEC §1: x forward, y right, yaw
clockwise, height up). The room is in standard 2-D math (x, y, angles counter-clockwise),
so the caster is called at ``(x_m, -y_m)`` with heading ``-yaw``. The scan plane is tilted
by ``R_y(pitch) R_x(roll)``: each beam's level-frame direction gives its azimuth, and its
slant range is the horizontal distance to the wall divided by the cosine of its elevation,
or the distance to the floor if a downward beam meets that first. The sensor sits at
``height_m + hat_offset_m`` above the floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from mkflight.config import SimVehicleConfig
from mkflight.conversions import MM_PER_M
from mkflight.sim.vehicle import VehicleParams
from mkflight.urg.units import URG_04LX, SensorParams

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

NOISE_M: Final = 0.01  # 1 sigma range noise (the URG-04LX's accuracy, README)
ERROR_FRACTION: Final = 0.005  # scan beams replaced by error codes
ERROR_CODES: Final = (1, 2, 7)
EDGE_JUNK_MM: Final = (30, 80)


class RayCaster(Protocol):
    """Ranges (m, NaN = no hit) of beams from ``(x_m, y_m)`` at ``theta_rad + angles_rad``.

    Standard 2-D math (counter-clockwise angles), like ``mkflight.sim.room.raycast`` with
    the room bound: ``functools.partial(raycast, room)``.
    """

    def __call__(
        self, x_m: float, y_m: float, theta_rad: float, angles_rad: FloatArray, max_range_m: float
    ) -> FloatArray:
        """Cast the beams."""
        ...


@dataclass(frozen=True, slots=True)
class ScenePose:
    """Where the vehicle is: world frame W (SPEC §1), height above the floor."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    height_m: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0


PoseSource = ScenePose | Callable[[int], ScenePose]


@dataclass(frozen=True, slots=True)
class HatGeometry:
    """Which URG steps the hat's mirror folds to the floor, and its offset (the airframe's).

    ``hat_steps`` (inclusive) read the floor; the steps after them up to
    ``mirror_edge_last_step`` see the mirror's edge; ``hat_offset_m`` is the hat's range
    to the floor minus the height (the range of a vehicle standing on the floor).
    """

    hat_steps: tuple[int, int]
    mirror_edge_last_step: int
    hat_offset_m: float

    @classmethod
    def of(cls, params: VehicleParams) -> HatGeometry:
        """The hat of the airframe ``params``."""
        return cls(params.hat_steps, params.mirror_edge_last_step, params.hat_offset_m)


NOMINAL_HAT: Final = HatGeometry.of(VehicleParams.from_config(SimVehicleConfig()))


class FixedRanges:
    """The same ranges in every scan: ``{step: mm}``, ``default_mm`` elsewhere (§7)."""

    def __init__(self, ranges: Mapping[int, int] | None = None, default_mm: int = 1000) -> None:
        """Keep a copy of the table."""
        self.ranges = dict(ranges or {})
        self.default_mm = default_mm

    def ranges_mm(self, t_ns: int, steps: IntArray) -> IntArray:
        """The table's values for ``steps``."""
        get = self.ranges.get
        return np.array([get(int(s), self.default_mm) for s in steps], dtype=np.int64)


class RoomScene:
    """A URG in a room at a settable pose: a :class:`~mkflight.sim.urg.RangeSource`."""

    def __init__(
        self,
        caster: RayCaster,
        *,
        pose: PoseSource | None = None,
        hat: HatGeometry = NOMINAL_HAT,
        params: SensorParams = URG_04LX,
        seed: int = 0,
        noise_m: float = NOISE_M,
        error_fraction: float = ERROR_FRACTION,
        motion_groups: int = 8,
    ) -> None:
        """Set the scene up (see the module docstring for the geometry).

        Args:
            caster: the room's ray caster.
            pose: a fixed :class:`ScenePose` or a function of time giving one; may be
                reassigned at any time through :attr:`pose`.
            hat: the airframe's hat: its steps, the mirror's edge, its offset.
            params: the sensor's parameters (DMAX, angles, timing).
            seed: seeds the noise generator (reproducible scans).
            noise_m: 1-sigma range noise.
            error_fraction: share of scan beams replaced by error codes.
            motion_groups: the sweep is cut into this many groups of steps, each cast
                from the pose at its own time (1: the whole scan from one pose).
        """
        self.caster = caster
        self.pose: PoseSource = pose if pose is not None else ScenePose()
        self.hat = hat
        self.params = params
        self.rng = np.random.default_rng(seed)
        self.noise_m = noise_m
        self.error_fraction = error_fraction
        self.motion_groups = max(1, motion_groups)

    def pose_at(self, t_ns: int) -> ScenePose:
        """The pose at ``t_ns``."""
        pose = self.pose
        return pose if isinstance(pose, ScenePose) else pose(t_ns)

    def ranges_mm(self, t_ns: int, steps: IntArray) -> IntArray:
        """Hat, mirror-edge and scan steps of one scan starting at ``t_ns`` (mm)."""
        steps = np.asarray(steps, dtype=np.int64)
        out = np.zeros(steps.shape, dtype=np.int64)
        hat_lo, hat_hi = self.hat.hat_steps
        hat = (steps >= hat_lo) & (steps <= hat_hi)
        edge = (steps > hat_hi) & (steps <= self.hat.mirror_edge_last_step)
        scan = ~hat & ~edge
        if hat.any():
            out[hat] = self._hat(t_ns, steps[hat])
        if scan.any():
            out[scan] = self._scan(t_ns, steps[scan])
        n_edge = int(edge.sum())
        if n_edge:
            junk = self.rng.integers(EDGE_JUNK_MM[0], EDGE_JUNK_MM[1] + 1, n_edge)
            out[edge] = np.where(self.rng.random(n_edge) < 0.5, 0, junk)
        return out

    def _step_time_ns(self, t_ns: int, step: float) -> int:
        return t_ns + self.params.step_offset_ns(step)

    def _to_mm(self, ranges_m: FloatArray) -> IntArray:
        """Add noise, round to mm; no hit, beyond DMAX or below DMIN -> 0."""
        noisy = ranges_m + self.rng.normal(0.0, self.noise_m, ranges_m.shape)
        mm = np.rint(np.nan_to_num(noisy, nan=0.0) * MM_PER_M).astype(np.int64)
        bad = ~np.isfinite(noisy) | (mm > self.params.dmax_mm) | (mm < self.params.dmin_mm)
        return np.where(bad, 0, mm)

    def _hat(self, t_ns: int, steps: IntArray) -> IntArray:
        """The floor distance through the hat's mirror: SPEC eq 26 inverted."""
        pose = self.pose_at(self._step_time_ns(t_ns, float(steps.mean())))
        tilt = math.cos(pose.pitch_rad) * math.cos(pose.roll_rad)
        slant = (pose.height_m + self.hat.hat_offset_m) / tilt if tilt > 0 else math.nan
        return self._to_mm(np.full(steps.shape, slant, dtype=np.float64))

    def _scan(self, t_ns: int, steps: IntArray) -> IntArray:
        """Ray-cast the scan steps, group by group, from the pose at each group's time."""
        p = self.params
        ranges = np.empty(steps.shape, dtype=np.float64)
        for group in np.array_split(np.arange(steps.size), min(self.motion_groups, steps.size)):
            chunk = steps[group]
            pose = self.pose_at(self._step_time_ns(t_ns, float(chunk.mean())))
            body = -(chunk - p.afront_step) * p.step_angle_rad  # body angle, right positive
            ranges[group] = self._cast(pose, body.astype(np.float64))
        mm = self._to_mm(ranges)
        n_err = self.rng.binomial(mm.size, self.error_fraction) if self.error_fraction > 0 else 0
        if n_err:
            where = self.rng.choice(mm.size, size=n_err, replace=False)
            mm[where] = self.rng.choice(ERROR_CODES, size=n_err)
        return mm

    def _cast(self, pose: ScenePose, body_rad: FloatArray) -> FloatArray:
        """Slant ranges (m, NaN = none) of beams at ``body_rad``, tilted by roll and pitch."""
        cb, sb = np.cos(body_rad), np.sin(body_rad)
        cr, sr = math.cos(pose.roll_rad), math.sin(pose.roll_rad)
        cp, sp = math.cos(pose.pitch_rad), math.sin(pose.pitch_rad)
        # Level-frame direction R_y(pitch) R_x(roll) (cos b, sin b, 0), FRD (z down).
        lx = cp * cb + sp * sb * sr
        ly = sb * cr
        lz = -sp * cb + cp * sb * sr
        horizontal = np.hypot(lx, ly)
        azimuth = np.arctan2(ly, lx)  # clockwise from the nose, like yaw
        max_m = self.params.dmax_mm / MM_PER_M
        flat = self.caster(pose.x_m, -pose.y_m, -pose.yaw_rad, -azimuth, max_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            wall = np.asarray(flat, dtype=np.float64) / horizontal
            floor = np.where(lz > 1e-9, (pose.height_m + self.hat.hat_offset_m) / lz, np.inf)
        slant = np.fmin(np.nan_to_num(wall, nan=np.inf), floor)
        return np.where(slant <= max_m, slant, np.nan)
