"""The simulated side of ``sim hover``: the airframe and its sensors on a lock-step clock.

:class:`LockstepVehicle` is what the flight code of ``sim hover`` (:mod:`mkflight.sim.hover`)
flies instead of the ports: it reads only ``cfg.sim`` (the airframe,
:func:`~mkflight.sim.airframe.airframe_from_config`) and gives what the two links would
carry, on the times they would carry it:

* **DebugOut** (:meth:`LockstepVehicle.next_debug_ns`, :meth:`LockstepVehicle.debug_values`):
  every 52 FC ticks of 1.024 ms (mk-serial.md §7.2) plus the airframe's loop jitter and
  late frames (:class:`~mkflight.sim.fc_timing.DebugJitter`, seeded); the IMU measured
  with the airframe's vibration, trims, biases and noise, as raw counts from the
  simulator's own encoder (:func:`~mkflight.sim.mk_units.encode_analog`).
* **Laser**, one scan per 100 ms (scan ``k``'s step 0 at ``k * 100 ms``), in one of two
  forms:

  - *poses* (the default, fast): the true pose and height at the scan's time plus
    scan-matcher-sized noise (:class:`PoseFix`), stamped ``t + laser_extra_delay_s`` and
    delivered ``LASER_DELAY_NS`` (100 ms, §G of the 2011 QUT CyPhy MikroKopter
    documentation) + extra + jitter after ``t``;
  - *scans* (``scans=True``): the raw ranges the URG would send (:class:`RawScan`),
    ray-cast in the room (:func:`~mkflight.sim.world.default_room`) by
    :class:`~mkflight.sim.urg_scene.RoomScene` from the pose at each beam group's own
    time (a history of states every ≤ 10 ms, :class:`~mkflight.sim.history.StateHistory`),
    with the airframe's hat. The driver stamps the front step with what it believes:
    ``t_front + laser_extra_delay_s``; it arrives when the URG sends it: the end step
    (70.8 ms) + the sensor's USB delay (:data:`~mkflight.sim.urg_server.USB_DELAY_S`) +
    extra + jitter.

  Jitter is uniform in ``0..laser_jitter_s`` per scan (seeded); deliveries stay in order.

The truth: :attr:`LockstepVehicle.state`, a ``truth.txt`` row at the end of every
:meth:`LockstepVehicle.advance_to` (:class:`~mkflight.sim.truth.TruthLog`) and a
``# touchdown`` line per touchdown (:attr:`LockstepVehicle.touchdowns`).

Seeds: ``seed`` seeds this flight (the vehicle's per-flight errors and gusts, sensor
noise, link jitter), each from its own generator, so switching the laser form does not
change the vehicle's errors; the airframe itself is ``sim.seed``'s.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from mkflight.config import SimConfig
from mkflight.conversions import NS_PER_S
from mkflight.mk.messages import ANALOG_GAS, ANALOG_RECEIVER_LEVEL
from mkflight.msgs import Pose2D
from mkflight.sim.airframe import airframe_from_config
from mkflight.sim.fc_timing import TICK_NS, DebugJitter, DebugTiming
from mkflight.sim.history import StateHistory
from mkflight.sim.mk_units import encode_analog
from mkflight.sim.room import room_caster
from mkflight.sim.truth import TruthLog
from mkflight.sim.urg_answers import DEAD_ZONE_CODE
from mkflight.sim.urg_scene import HatGeometry, RoomScene
from mkflight.sim.urg_server import USB_DELAY_S
from mkflight.sim.vehicle import Sticks, VehicleParams, VehicleState, initial_state, step
from mkflight.sim.vehicle_sensors import battery_reading_v, imu_measured_si
from mkflight.sim.world import default_room
from mkflight.urg.units import URG_04LX

IntArray = npt.NDArray[np.int64]

IMU_PERIOD_NS: Final = 52 * TICK_NS  # 'd' 5: 50 FC ticks + the 2-tick overshoot (§7.2)
SCAN_PERIOD_NS: Final = URG_04LX.scan_period_ns  # 600 rpm: 100 ms
LASER_DELAY_NS: Final = 100_000_000  # poses: the pose reaches the flight ~100 ms later (§G)
POSE_NOISE_M: Final = 0.003  # the scan matcher at hover: ~1-3 mm per relation (data README)
YAW_NOISE_RAD: Final = 0.001
HEIGHT_NOISE_M: Final = 0.0015  # the median of 84 hat beams with 1 cm noise
HISTORY_KEEP_NS: Final = 500_000_000  # states kept for the beams of a scan (70 ms sweep)
CHUNK_NS: Final = 10_000_000  # scans: a stored state at least every 10 ms
RECEIVER_LEVEL: Final = 200  # the FC's RC receiver level: a good link
END_STEP_NS: Final = URG_04LX.step_offset_ns(URG_04LX.amax_step)  # the last step: 70.8 ms
FRONT_STEP_NS: Final = URG_04LX.step_offset_ns(URG_04LX.afront_step)  # step 384: 37.5 ms


@dataclass(frozen=True, slots=True)
class PoseFix:
    """A laser pose and hat height as the scan matcher would give them (the fast form).

    ``pose.t_ns`` is the stamp the driver would give (the scan's time + the airframe's
    ``laser_extra_delay_s``: the data is older than the flight believes).
    """

    pose: Pose2D
    height_m: float


@dataclass(frozen=True, slots=True)
class RawScan:
    """The values of one URG scan as they reach the driver (``scans=True``).

    ``values_mm[i]`` is step ``first_step + i`` on the wire: mm, 0 = no echo, < 20 an
    error code. ``stamp_ns`` is the host time the driver gives the front step (the true
    time + ``laser_extra_delay_s``); ``start_ns`` the true time of step 0.
    """

    seq: int
    start_ns: int
    stamp_ns: int
    first_step: int
    values_mm: IntArray


LaserData = PoseFix | RawScan


def gust_seed_for(seed: int) -> int:
    """The gusts of flight ``seed`` (an oracle flying the same airframe meets the same ones)."""
    return seed


class LockstepVehicle:
    """The simulated airframe, its FC's DebugOut and its laser, in lock-step (module doc)."""

    def __init__(
        self,
        sim: SimConfig,
        *,
        seed: int,
        scans: bool = False,
        scan_steps: tuple[int, int] = (URG_04LX.amin_step, URG_04LX.amax_step),
        truth: TruthLog | None = None,
        params: VehicleParams | None = None,
    ) -> None:
        """The vehicle at rest on the floor at time 0.

        Args:
            sim: the simulator's config section (the airframe); nothing else is read.
            seed: seeds this flight (module docstring).
            scans: give raw URG scans (:class:`RawScan`) instead of poses.
            scan_steps: the steps the driver asked for (its MD command), inclusive.
            truth: write the truth rows and touchdowns there.
            params: the airframe (default: ``airframe_from_config(sim)``).
        """
        self.params = airframe_from_config(sim) if params is None else params
        p = self.params
        self.seed = seed
        self.scans = scans
        self.scan_steps = scan_steps
        self._truth = truth
        vehicle_rng, sensor_rng, link_rng = np.random.SeedSequence(seed).spawn(3)
        self._rng = np.random.default_rng(vehicle_rng)
        self._sensor_rng = np.random.default_rng(sensor_rng)
        self._link_rng = np.random.default_rng(link_rng)
        self.state: VehicleState = initial_state(
            p, self._rng, used_ah=p.battery_used_ah, gust_seed=gust_seed_for(seed)
        )
        self.t_ns = 0
        self._debug_ns = 0
        self.debug_jitter = DebugJitter(
            DebugTiming(p.debug_jitter_ticks, p.debug_late_fraction, seed=seed)
        )
        self.sticks = Sticks()
        self._history = StateHistory(HISTORY_KEEP_NS, 0, self.state) if scans else None
        self._scene = (
            RoomScene(
                room_caster(default_room()),
                pose=self._history.pose_at,
                hat=HatGeometry.of(p),
                seed=seed,
            )
            if self._history is not None
            else None
        )
        self._scan_k = 0
        self._extra_ns = round(p.laser_extra_delay_s * NS_PER_S)
        self._jitter_ns = round(p.laser_jitter_s * NS_PER_S)
        self._outbox: deque[tuple[int, LaserData]] = deque()
        self._last_delivery_ns = 0
        self.max_height_m = 0.0

    # ----------------------------------------------------------------- time
    def next_debug_ns(self) -> int:
        """The time of the next DebugOut: 52 ticks after the last, plus the loop's jitter."""
        self._debug_ns += IMU_PERIOD_NS + self.debug_jitter.extra_ticks() * TICK_NS
        return self._debug_ns

    @property
    def touchdowns(self) -> tuple[tuple[float, float], ...]:
        """Every touchdown so far, ``(t_s, speed_mps)`` (truth: the downward speed)."""
        return self.state.touchdowns

    def advance_to(self, t_ns: int, sticks: Sticks) -> VehicleState:
        """Fly ``sticks`` (what the FC applies) up to ``t_ns``, measuring the laser on the way.

        Writes one truth row at ``t_ns`` (if there is a truth log).
        """
        self.sticks = sticks
        while (event_ns := self._laser_event_ns()) <= t_ns:
            self._step_to(event_ns)
            self._measure_laser()
        self._step_to(t_ns)
        if self._truth is not None:
            self._truth.write(self.t_ns, self.state)
        return self.state

    def _step_to(self, t_ns: int) -> None:
        """Step the vehicle to ``t_ns`` (in ≤ 10 ms chunks into the history for scans)."""
        before = len(self.state.touchdowns)
        while self.t_ns < t_ns:
            nxt = t_ns if self._history is None else min(t_ns, self.t_ns + CHUNK_NS)
            dt_s = (nxt - self.t_ns) / NS_PER_S
            self.state = step(self.state, self.sticks, dt_s, self.params, self._rng)
            self.t_ns = nxt
            if self._history is not None:
                self._history.append(nxt, self.state)
            self.max_height_m = max(self.max_height_m, self.state.height_m)
        if self._truth is not None:
            for t_s, speed in self.state.touchdowns[before:]:
                self._truth.touchdown(round(t_s * NS_PER_S), speed)

    # ----------------------------------------------------------------- the FC
    def debug_values(self) -> dict[int, int]:
        """The DebugOut's raw values now (MK counts by index): measured, encoded, gas."""
        s, p = self.state, self.params
        m = imu_measured_si(s, p, self._sensor_rng)
        values = encode_analog(m, battery_reading_v(s, p, self._sensor_rng), p)
        values[ANALOG_GAS] = 4 * round(self.sticks.gas_counts)
        values[ANALOG_RECEIVER_LEVEL] = RECEIVER_LEVEL
        return values

    # ----------------------------------------------------------------- the laser
    def _laser_event_ns(self) -> int:
        """When the next laser measurement is taken (poses) or complete (scans)."""
        start = self._scan_k * SCAN_PERIOD_NS
        return start + END_STEP_NS if self.scans else start

    def _measure_laser(self) -> None:
        """Measure scan ``k`` (the vehicle is at its event time) and queue its delivery."""
        k = self._scan_k
        self._scan_k += 1
        start_ns = k * SCAN_PERIOD_NS
        jitter = int(self._link_rng.integers(0, self._jitter_ns + 1)) if self._jitter_ns else 0
        data: LaserData
        if self._scene is None:
            s, rng = self.state, self._sensor_rng
            pose = Pose2D(
                start_ns + self._extra_ns,
                float(s.pos_w_m[0] + rng.normal(0, POSE_NOISE_M)),
                float(s.pos_w_m[1] + rng.normal(0, POSE_NOISE_M)),
                float(s.yaw_rad + rng.normal(0, YAW_NOISE_RAD)),
            )
            data = PoseFix(pose, float(s.height_m + rng.normal(0, HEIGHT_NOISE_M)))
            deliver = start_ns + LASER_DELAY_NS + self._extra_ns + jitter
        else:
            data = RawScan(
                seq=k,
                start_ns=start_ns,
                stamp_ns=start_ns + FRONT_STEP_NS + self._extra_ns,
                first_step=self.scan_steps[0],
                values_mm=self._scan_values(start_ns),
            )
            usb_ns = round(USB_DELAY_S * NS_PER_S) + self._extra_ns + jitter
            deliver = start_ns + END_STEP_NS + usb_ns
        deliver = max(deliver, self._last_delivery_ns)  # USB keeps the order
        self._last_delivery_ns = deliver
        self._outbox.append((deliver, data))

    def _scan_values(self, start_ns: int) -> IntArray:
        """The wire values of the requested steps of the scan starting at ``start_ns``."""
        assert self._scene is not None
        p = URG_04LX
        first, last = self.scan_steps
        out = np.full(last - first + 1, DEAD_ZONE_CODE, dtype=np.int64)
        lo, hi = max(first, p.amin_step), min(last, p.amax_step)
        if lo <= hi:
            mm = self._scene.ranges_mm(start_ns, np.arange(lo, hi + 1, dtype=np.int64))
            out[lo - first : hi - first + 1] = np.where((mm > p.dmax_mm) | (mm < 0), 0, mm)
        return out

    def laser_arrivals(self, t_ns: int) -> list[LaserData]:
        """The laser data that has reached the flight by ``t_ns``, in order."""
        out: list[LaserData] = []
        while self._outbox and self._outbox[0][0] <= t_ns:
            out.append(self._outbox.popleft()[1])
        return out


__all__ = [
    "IMU_PERIOD_NS",
    "LASER_DELAY_NS",
    "SCAN_PERIOD_NS",
    "LaserData",
    "LockstepVehicle",
    "PoseFix",
    "RawScan",
    "gust_seed_for",
]
