"""The live simulator's world: one vehicle in real time, read by the FC and the URG (SPEC §8).

:class:`SimWorld` owns the vehicle state (:mod:`mkflight.sim.vehicle`), its seeded random
generators and the time origin: host monotonic time ``t0_ns`` is vehicle time 0. It is
pure and synchronous; the emulators' tasks drive it by asking for what they measure:

* the FC emulator's DebugOut (:meth:`SimWorld.analog`, an
  :class:`~mkflight.sim.fc.AnalogSource`): the IMU measured from the vehicle (trim,
  biases, vibration, noise: :mod:`mkflight.sim.vehicle_sensors`) in MK counts through the
  simulator's own encoder (:func:`mkflight.sim.mk_units.encode_analog`, with the
  airframe's accelerometer scales), as ``sim hover`` does;
* the URG scene's pose (:meth:`SimWorld.pose_at`, a
  :data:`~mkflight.sim.urg_scene.PoseSource`): a scan's beams are timed up to ~100 ms
  before the reply is built, so recent times are interpolated from a ring buffer of
  states (:data:`HISTORY_NS`, :class:`~mkflight.sim.history.StateHistory`); later
  times advance the vehicle.

The airframe is :func:`~mkflight.sim.airframe.airframe_from_config` of ``cfg.sim`` (the
nominal one, or one drawn from the envelope with ``sim.seed``): the simulator reads
nothing of ``mk``, ``control`` or ``laser``. It is logged once at the start (``sim
airframe``), and every touchdown (the vehicle meeting the floor from the air) is logged
(``sim touchdown``: time, downward speed, the height it came from, who flew it) and
kept in :attr:`SimWorld.touchdowns`: the truth of a landing's hardness (SPEC §8: ≤ 0.5
m/s).

Closed loop: the vehicle flies what the FC flies (``FcModel.effective_command``, the
extern command added to the pilot's sticks, gas capped by the stick gas). The command is
read at the start of every advance, and :class:`WorldFc` advances the world to ``t``
before the FC handles anything at ``t``, so a command takes effect at the FC tick that
handled it (not at the next DebugOut).

The simulated pilot (``stick_gas_with_extern_only``, the default): the motors run only
while the FC applies extern control. A real pilot raises the gas stick (the cap,
``sim.fc.stick_gas``, far above hover) only once mkflight has control, and pulls it down
when control ends; a pilot holding 200 counts through the handshake would shoot the
vehicle into the ceiling. With the flag off the world flies ``effective_command``
literally, stick gas included.

Time never goes back: a request in the past is answered from the history, the state
stays where it is.

The truth log (``truth.txt``, :class:`~mkflight.sim.truth.TruthLog`, as ``sim hover``
writes it): the airframe, then one row per :data:`TRUTH_PERIOD_NS` of vehicle time
(seconds since ``truth_origin_ns``, world x and y, height up) and a ``# touchdown T_S
SPEED_MPS`` comment per touchdown.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
import structlog

from mkflight.config import Config, SimFcConfig
from mkflight.conversions import NS_PER_S
from mkflight.mk.messages import ANALOG_GAS
from mkflight.sim.airframe import airframe_from_config, describe
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_timing import DebugTiming
from mkflight.sim.fc_uart import WireChunk
from mkflight.sim.history import StateHistory, scene_pose
from mkflight.sim.mk_units import encode_analog
from mkflight.sim.room import Room, rect_walls
from mkflight.sim.truth import TruthLog
from mkflight.sim.urg_scene import ScenePose
from mkflight.sim.vehicle import Sticks, VehicleParams, VehicleState, initial_state, step
from mkflight.sim.vehicle_sensors import battery_reading_v, imu_measured_si

HISTORY_NS: Final = NS_PER_S  # states kept for requests in the past (scan beams)
MAX_CHUNK_NS: Final = 10_000_000  # one history entry at least every 10 ms of vehicle time
MIN_STEP_NS: Final = 200_000  # closer requests are answered from the current state
log = structlog.get_logger("mkflight.sim")

TRUTH_PERIOD_NS: Final = 50_000_000  # at most one truth row per 50 ms of vehicle time


class SimWorld:
    """The simulated vehicle in host time, seen by the FC and the URG (module docstring)."""

    def __init__(
        self,
        cfg: Config,
        *,
        seed: int,
        t0_ns: int,
        truth_path: str | Path | None = None,
        truth_origin_ns: int | None = None,
        stick_gas_with_extern_only: bool = True,
        pos_w_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        params: VehicleParams | None = None,
    ) -> None:
        """Put the vehicle at rest at ``pos_w_m`` (on the floor if z = 0) at host ``t0_ns``.

        Args:
            cfg: the configuration: ``sim`` only (the airframe, ``sim.airframe`` and
                ``sim.seed``; the FC's settings).
            seed: seeds this flight: the vehicle's per-flight errors, its gusts, the
                sensor noise and the links' jitter (not the airframe: ``sim.seed``).
            t0_ns: the host monotonic time that is vehicle time 0.
            truth_path: write the truth log there (a new file), else none.
            truth_origin_ns: the truth log's ``t`` = 0 (default ``t0_ns``; 0 gives host
                monotonic seconds, the flight logs' time base).
            stick_gas_with_extern_only: the simulated pilot's gas (module docstring).
            pos_w_m: the start position, world frame W (z down).
            yaw_rad: the start heading (SPEC §1, clockwise).
            params: the airframe (default: ``airframe_from_config(cfg.sim)``).

        Raises:
            FileExistsError: ``truth_path`` exists.
        """
        self.params = airframe_from_config(cfg.sim) if params is None else params
        self.seed = seed
        self.airframe_info: dict[str, object] = {
            "kind": cfg.sim.airframe if params is None else "given",
            "seed": cfg.sim.seed,
            **describe(self.params),
        }
        vehicle_seed, sensor_seed = np.random.SeedSequence(seed).spawn(2)
        self.rng = np.random.default_rng(vehicle_seed)
        self.sensor_rng = np.random.default_rng(sensor_seed)
        self.t0_ns = t0_ns
        self.stick_gas_with_extern_only = stick_gas_with_extern_only
        self.battery_override_v: float | None = None  # fault: the battery reads this
        self.fc: FcModel | None = None  # whose command the vehicle flies
        self._state = initial_state(
            self.params,
            self.rng,
            pos_w_m=pos_w_m,
            yaw_rad=yaw_rad,
            used_ah=self.params.battery_used_ah,
            gust_seed=seed,
        )
        self._t_ns = t0_ns
        self._sticks = Sticks()
        self.extern_active = False  # the FC applies ExternControl (logged on each change)
        self._history = StateHistory(HISTORY_NS, t0_ns, self._state)
        self._peak_m = 0.0  # the highest point since the last touchdown (or the start)
        self._truth: TruthLog | None = None
        self._truth_due_ns = t0_ns
        if truth_path is not None:
            origin = t0_ns if truth_origin_ns is None else truth_origin_ns
            self._truth = TruthLog(truth_path, origin_ns=origin, airframe=self.airframe_info)
        log.info("sim airframe", flight_seed=seed, **self.airframe_info)
        self._write_truth()

    # ----------------------------------------------------------------- state
    @property
    def t_ns(self) -> int:
        """The host time the vehicle has been advanced to."""
        return self._t_ns

    @property
    def state(self) -> VehicleState:
        """The vehicle now (at :attr:`t_ns`)."""
        return self._state

    @property
    def sticks(self) -> Sticks:
        """What the vehicle flew in its last advance (MK counts)."""
        return self._sticks

    @property
    def touchdowns(self) -> tuple[tuple[float, float], ...]:
        """Every touchdown so far: ``(t_s, speed_mps)``, vehicle time (0 at ``t0_ns``)."""
        return self._state.touchdowns

    @property
    def truth_rows(self) -> int:
        """Rows written to the truth log so far."""
        return 0 if self._truth is None else self._truth.rows

    def attach(self, fc: FcModel) -> None:
        """Fly ``fc``'s command from now on."""
        self.fc = fc

    def command_sticks(self) -> Sticks:
        """What the vehicle flies now: the FC's command after the pilot's rule.

        No FC, or one rebooting: motors off. Extern control not applied and
        :attr:`stick_gas_with_extern_only`: the pilot's gas stick is down (gas 0).
        """
        fc = self.fc
        active = fc is not None and not fc.booting and fc.extern_active
        if active != self.extern_active:  # what a fault test reads: who flies the vehicle
            self.extern_active = active
            log.info(
                "sim fc extern control",
                active=active,
                t_s=round(self._t_ns / NS_PER_S, 3),
                height_m=round(self._state.height_m, 3),
                by="" if fc is None else "reboot" if fc.booting else fc.controls.released_by,
            )
        if fc is None or fc.booting:
            return Sticks()
        cmd = fc.effective_command()
        gas = cmd.gas
        if self.stick_gas_with_extern_only and not fc.extern_active:
            gas = 0
        return Sticks(
            nick_counts=float(cmd.nick),
            roll_counts=float(cmd.roll),
            yaw_counts=float(cmd.yaw),
            gas_counts=float(gas),
        )

    # ----------------------------------------------------------------- time
    def advance_to(self, t_ns: int) -> VehicleState:
        """Step the vehicle to host time ``t_ns`` with the command in force now.

        A time in the past (or within :data:`MIN_STEP_NS`) leaves the state as it is.
        The history gets an entry at least every :data:`MAX_CHUNK_NS`; entries older
        than :data:`HISTORY_NS` are dropped.
        """
        if t_ns - self._t_ns < MIN_STEP_NS:
            return self._state
        sticks = self._sticks = self.command_sticks()
        while self._t_ns < t_ns:
            nxt = min(t_ns, self._t_ns + MAX_CHUNK_NS)
            before = len(self._state.touchdowns)
            self._state = step(
                self._state, sticks, (nxt - self._t_ns) / NS_PER_S, self.params, self.rng
            )
            self._t_ns = nxt
            self._history.append(nxt, self._state)
            if len(self._state.touchdowns) > before:
                self._touched_down(before)
            self._peak_m = max(self._peak_m, self._state.height_m)
            if nxt >= self._truth_due_ns:
                self._write_truth()
        return self._state

    def _touched_down(self, known: int) -> None:
        """Log the touchdowns after the first ``known`` and note them in the truth log."""
        for t_s, speed in self._state.touchdowns[known:]:
            log.info(
                "sim touchdown",
                t_s=round(t_s, 3),
                speed_mps=round(speed, 3),
                height_m=round(self._peak_m, 3),  # where it came down from
                extern_active=self.extern_active,  # False: the pilot's sticks flew it
            )
            if self._truth is not None:
                self._truth.touchdown(self.t0_ns + round(t_s * NS_PER_S), speed)
        self._peak_m = 0.0

    def _write_truth(self) -> None:
        """A truth row now (if there is a log) and the next one due a period later."""
        if self._truth is not None:
            self._truth.write(self._t_ns, self._state)
        self._truth_due_ns = self._t_ns + TRUTH_PERIOD_NS

    def state_at(self, t_ns: int) -> VehicleState:
        """The vehicle at ``t_ns``: advanced to it if later, else the nearest stored state."""
        if t_ns >= self._t_ns:
            return self.advance_to(t_ns)
        return self._history.nearest(t_ns)

    def pose_at(self, t_ns: int) -> ScenePose:
        """Where the URG is at ``t_ns`` (a :data:`~mkflight.sim.urg_scene.PoseSource`).

        Later than now: the vehicle is advanced. Earlier: linear interpolation between
        the two stored states around ``t_ns`` (yaw along the short way round); before
        the history: its oldest state.
        """
        if t_ns >= self._t_ns:
            return scene_pose(self.advance_to(t_ns))
        return self._history.pose_at(t_ns)

    # ----------------------------------------------------------------- the FC's view
    def analog(self, t_ns: int, fc: FcModel) -> dict[int, int]:
        """DebugOut counts at ``t_ns``: the IMU and battery measured, in MK units (SPEC §1).

        Encoded by the simulator's own :func:`~mkflight.sim.mk_units.encode_analog` with
        this airframe's accelerometer scales, never the flight's calibration.

        Also attaches ``fc`` (its command is what the vehicle flies). Gas (index 7) is
        4x the gas the vehicle flies, as the FC reports it; the receiver level is the
        FC's own.
        """
        self.attach(fc)
        state = self.state_at(t_ns)
        m = imu_measured_si(state, self.params, self.sensor_rng)
        battery_v = self.battery_override_v
        if battery_v is None:
            battery_v = battery_reading_v(state, self.params, self.sensor_rng)
        values = encode_analog(m, battery_v, self.params)
        values[ANALOG_GAS] = 4 * round(self._sticks.gas_counts)
        return values

    def close(self) -> None:
        """Close the truth log (idempotent); a pending touchdown line gets a row after it."""
        if self._truth is not None:
            self._truth.close(self._t_ns, self._state)


def default_room() -> Room:
    """A 4 m x 3 m box with a 0.25 m pillar, the world origin off-centre (SPEC §8).

    Walls in every direction within 3 m (the URG reads to 4 m: §P of the 2011 QUT CyPhy
    MikroKopter documentation), a pillar and unequal distances so that x, y and yaw are all
    observable by the scan matcher. Room coordinates are standard 2-D math (y to the left,
    :mod:`mkflight.sim.room`): the walls are 1.6 m behind, 2.4 m ahead, 1.8 m left and 1.2 m
    right of the origin.
    """
    walls = rect_walls((-1.6, -1.2, 2.4, 1.8))
    pillar = rect_walls((1.2, 0.7, 1.45, 0.95))  # ahead and to the left
    return Room(np.vstack((walls, pillar)))


class WorldFc(FcModel):
    """An :class:`FcModel` that keeps the world in step with it.

    Before the FC takes bytes or runs its main loop up to ``t``, the world is advanced
    to ``t`` with the command in force until then; a frame handled at ``t`` changes the
    command from ``t`` on. The world is the FC's analog source.
    """

    def __init__(self, settings: SimFcConfig, world: SimWorld, *, t_ns: int) -> None:
        """Boot the FC at ``t_ns`` with ``world`` as its source, and attach it.

        Its DebugOut timing is the airframe's (``debug_jitter_ticks``,
        ``debug_late_fraction``), seeded with the world's seed.
        """
        p = world.params
        timing = DebugTiming(p.debug_jitter_ticks, p.debug_late_fraction, seed=world.seed)
        super().__init__(settings, world, t_ns=t_ns, timing=timing)
        self.world = world
        world.attach(self)

    def receive(self, data: bytes, t_ns: int) -> WireChunk:
        """Advance the world to ``t_ns``, then :meth:`FcModel.receive`."""
        self.world.advance_to(t_ns)
        return super().receive(data, t_ns)

    def poll(self, t_ns: int) -> list[bytes]:
        """Advance the world to ``t_ns``, then :meth:`FcModel.poll`."""
        self.world.advance_to(t_ns)
        return super().poll(t_ns)
