"""Replaying the original system's logs: TABLE IV as DebugOut, TABLE III as the matcher.

TABLE III and TABLE IV are those of the 2011 QUT CyPhy MikroKopter documentation. A folder
with only the original system's two tables (``imu_50ms.log``, ``laser_100ms.log``; SPEC §6)
has no bytes to play back, so the replay serves both ports with the simulator's pure
device models (:class:`~mkflight.replay.feeder.Feeder` ``models``) on the lock-step clock:

* **FC**: :class:`SeedFc`, the emulated FlightCtrl 0.84a (it answers the version
  request, the DebugOut subscription, confirms and 'p' as the real one does), whose
  DebugOut values are a level vehicle standing on the ground until the daemon takes
  off, then the TABLE IV rows, one row per DebugOut frame, re-encoded in MK counts
  (:func:`~mkflight.mk.units.analog_from_si`, the inverse of the link's conversion);
* **URG**: the emulated URG-04LX in the simulator's room, standing on the ground at the
  first TABLE III pose and, from take-off, at the TABLE III pose of the time and at the
  take-off height (the original system's tables have no height: the hat reads
  ``control.takeoff_height_m`` while the tables last);
* **scan matcher**: :class:`SeedMatcher` gives each scan the TABLE III pose of its time
  (row 0 before take-off, then one row per 100 ms), the hat height from the real
  pipeline; the world frame W is the original system's.

The daemon's estimator and controllers run on that and write their own tables; when the
TABLE IV rows run out the replay asks for a landing (as ``--duration`` would), the hat
reads the vehicle coming down, and the daemon lands and releases as in flight.
:func:`compare_columns` sets the two tables side by side column by column.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mkflight.config import Config
from mkflight.conversions import NS_PER_S
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.matcher_worker import MatcherWorker
from mkflight.mk.messages import DebugOut
from mkflight.mk.units import MkCalibration, analog_from_si
from mkflight.msgs import Pose2D, Scan
from mkflight.scanmatch.geometry import Pose
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_answers import build_debug_out
from mkflight.sim.room import room_caster
from mkflight.sim.sources import FixedSource
from mkflight.sim.urg import UrgModel
from mkflight.sim.urg_scene import HatGeometry, RoomScene, ScenePose
from mkflight.sim.urg_server import USB_DELAY_S
from mkflight.sim.world import default_room

LASER_PERIOD_NS = 100_000_000  # TABLE III: one row per 100 ms
DESCENT_MPS = 0.3  # how the hat reads the landing after the tables end


class SeedClock:
    """When the original system's rows begin (the daemon's take-off) and end (the last DebugOut)."""

    def __init__(self, n_imu_rows: int, n_laser_rows: int) -> None:
        self.n_imu_rows = n_imu_rows
        self.n_laser_rows = n_laser_rows
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def laser_row(self, t_ns: int) -> int:
        """The TABLE III row for time ``t_ns``: row 0 until take-off, the last after the end."""
        if self.start_ns is None or t_ns < self.start_ns:
            return 0
        return int(min((t_ns - self.start_ns) // LASER_PERIOD_NS, self.n_laser_rows - 1))


class SeedFc(FcModel):
    """The emulated FC whose DebugOut plays TABLE IV from take-off on, a row per frame."""

    def __init__(
        self,
        cfg: Config,
        imu: npt.NDArray[np.void],
        clock: SeedClock,
        *,
        t_ns: int,
        on_end: Callable[[int], None],
    ) -> None:
        cal = MkCalibration.from_config(cfg.mk)
        resting = analog_from_si(  # level on the floor, in the recorded flight's own units
            pitch_rad=0.0,
            roll_rad=0.0,
            yaw_rad=0.0,
            acc_x_mps2=0.0,
            acc_y_mps2=0.0,
            acc_z_mps2=-cal.g_mps2,
            battery_v=cfg.sim.fc.battery_v,
            cal=cal,
        )
        super().__init__(cfg.sim.fc, FixedSource(resting), t_ns=t_ns)
        self._cal = cal
        self._imu = imu
        self._clock = clock
        self._on_end = on_end
        self.rows_sent = 0

    def debug_out(self, t_ns: int) -> DebugOut:
        """The next TABLE IV row once the daemon has taken off, else the resting vehicle."""
        clock = self._clock
        if clock.start_ns is None or self.rows_sent >= len(self._imu):
            return super().debug_out(t_ns)
        row = self._imu[self.rows_sent]
        self.rows_sent += 1
        if self.rows_sent == len(self._imu):
            clock.end_ns = t_ns
            self._on_end(t_ns)
        analog = dict(self.source.analog(t_ns, self))
        analog.update(
            analog_from_si(
                pitch_rad=float(row["AnglePitch"]),
                roll_rad=float(row["AngleRoll"]),
                yaw_rad=float(row["AngleYaw"]),
                acc_x_mps2=float(row["AccX"]),
                acc_y_mps2=float(row["AccY"]),
                acc_z_mps2=float(row["AccZ"]),
                battery_v=self.battery_v,
                cal=self._cal,
            )
        )
        return build_debug_out(
            analog,
            gas=self.effective_command().gas,
            battery_v=self.battery_v,
            receiver_level=self.receiver_level,
            status=self.status,
        )


def seed_scene(cfg: Config, laser: npt.NDArray[np.void], clock: SeedClock) -> RoomScene:
    """The URG's room, the vehicle on the ground, then at the TABLE III pose (docstring)."""
    hold_m = cfg.control.takeoff_height_m

    def pose_at(t_ns: int) -> ScenePose:
        row = laser[clock.laser_row(t_ns)]
        height = hold_m if clock.start_ns is not None and t_ns >= clock.start_ns else 0.0
        if clock.end_ns is not None and t_ns > clock.end_ns:
            height = max(0.0, hold_m - DESCENT_MPS * (t_ns - clock.end_ns) / NS_PER_S)
        return ScenePose(
            x_m=float(row["CurrentPosition.x"]),
            y_m=float(row["CurrentPosition.y"]),
            yaw_rad=float(row["CurrentPosition.theta"]),
            height_m=height,
        )

    # The recorded flight's own hat (cfg.laser): a replay re-creates what it flew with.
    hat = HatGeometry(cfg.laser.hat_steps, cfg.laser.scan_steps[0] - 1, cfg.laser.hat_offset_m)
    return RoomScene(room_caster(default_room()), pose=pose_at, hat=hat, seed=0)


def seed_urg(cfg: Config, laser: npt.NDArray[np.void], clock: SeedClock, t_ns: int) -> UrgModel:
    """The emulated URG-04LX in :func:`seed_scene`, powered up at ``t_ns``."""
    return UrgModel(
        seed_scene(cfg, laser, clock), t_ns=t_ns, delivery_delay_ns=round(USB_DELAY_S * NS_PER_S)
    )


class SeedMatcher(MatcherWorker):
    """The in-process matcher, its pose replaced by TABLE III's from take-off on."""

    def __init__(self, cfg: Config, laser: npt.NDArray[np.void], clock: SeedClock) -> None:
        super().__init__(cfg, mode="inline")
        self._laser = laser
        self._clock = clock
        #: the TABLE III row behind each pose given while the tables last, by scan time
        self.rows_used: dict[int, int] = {}

    async def process(
        self,
        scan: Scan,
        pitch_rad: float,
        roll_rad: float,
        motion_prior: Pose | None = None,
    ) -> LaserResult:
        """The real result (height from the hat), with TABLE III's pose of the scan's time."""
        result = await super().process(scan, pitch_rad, roll_rad, motion_prior)
        clock = self._clock
        j = clock.laser_row(scan.t_ns)
        row = self._laser[j]
        started = clock.start_ns is not None and scan.t_ns >= clock.start_ns
        if started and (clock.end_ns is None or scan.t_ns <= clock.end_ns):
            self.rows_used[scan.t_ns] = j
        pose = Pose2D(
            scan.t_ns,
            float(row["CurrentPosition.x"]),
            float(row["CurrentPosition.y"]),
            float(row["CurrentPosition.theta"]),
        )
        return dataclasses.replace(
            result, pose=pose, pose_reason="", degenerate=False, match_valid=True
        )


@dataclass(frozen=True, slots=True)
class ColumnComparison:
    """One column of the replay's table against the original's, over the rows both have."""

    name: str
    n: int
    rms_diff: float
    max_abs_diff: float
    correlation: float


def compare_columns(
    ours: npt.NDArray[np.void], seed: npt.NDArray[np.void], columns: tuple[str, ...]
) -> list[ColumnComparison]:
    """RMS and largest difference and correlation of each column, row by row.

    Rows where either value is not finite (the first velocity of a flight is NaN) are
    left out of that column; ``n`` counts the rows compared.
    """
    rows = min(len(ours), len(seed))
    out = []
    for name in columns:
        a = np.asarray(ours[name][:rows], dtype=np.float64)
        b = np.asarray(seed[name][:rows], dtype=np.float64)
        both = np.isfinite(a) & np.isfinite(b)
        a, b = a[both], b[both]
        n = int(a.shape[0])
        with np.errstate(all="ignore"):  # an original value of 1e300 overflows to inf: shown so
            d = a - b
            corr = math.nan
            if n > 2 and np.std(a) > 0 and np.std(b) > 0:
                corr = float(np.corrcoef(a, b)[0, 1])
            rms = float(np.sqrt(np.mean(d * d))) if n else math.nan
        out.append(
            ColumnComparison(name, n, rms, float(np.max(np.abs(d))) if n else math.nan, corr)
        )
    return out
