"""The live simulator's world: one vehicle in real time, read by the FC and the URG (SPEC §8).

:class:`SimWorld` owns the vehicle state (:mod:`mkflight.sim.vehicle`), its seeded random
generators and the time origin: host monotonic time ``t0_ns`` is vehicle time 0. It is
pure and synchronous; the emulators' tasks drive it by asking for what they measure:

* the FC emulator's DebugOut (:meth:`SimWorld.analog`, an
  :class:`~mkflight.sim.fc.AnalogSource`): the IMU measured from the vehicle (trim,
  biases, vibration, noise: :mod:`mkflight.sim.vehicle_sensors`) in MK counts, as
  ``sim hover`` does;
* the URG scene's pose (:meth:`SimWorld.pose_at`, a
  :data:`~mkflight.sim.urg_scene.PoseSource`): a scan's beams are timed up to ~100 ms
  before the reply is built, so recent times are interpolated from a ring buffer of
  states (:data:`HISTORY_NS`); later times advance the vehicle.

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

The truth log (``truth.txt``, as ``sim hover`` writes it): a header line ``t x y z``, a
``# t0_ns N`` comment (the host monotonic time of ``t`` = 0, so a flight's monotonic
stamps can be matched), then one row per :data:`TRUTH_PERIOD_NS` of vehicle time:
``t`` seconds since ``truth_origin_ns``, ``x y`` world metres (SPEC §1), ``z`` height up;
flushed per row, so a killed process leaves it readable.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from pathlib import Path
from typing import Final

import numpy as np
import structlog

from mkflight.clock import NS_PER_S
from mkflight.config import Config, SimFcConfig
from mkflight.logs._file import LineFile
from mkflight.mk.messages import ANALOG_GAS
from mkflight.mk.units import MkCalibration, analog_from_si
from mkflight.sim.fc import FcModel
from mkflight.sim.fc_uart import WireChunk
from mkflight.sim.room import Room, rect_walls
from mkflight.sim.urg_scene import ScenePose
from mkflight.sim.vehicle import Sticks, VehicleParams, VehicleState, initial_state, step
from mkflight.sim.vehicle_sensors import battery_reading_v, imu_measured_si

HISTORY_NS: Final = 1_000_000_000  # states kept for requests in the past (scan beams)
MAX_CHUNK_NS: Final = 10_000_000  # one history entry at least every 10 ms of vehicle time
MIN_STEP_NS: Final = 200_000  # closer requests are answered from the current state
log = structlog.get_logger("mkflight.sim")

TRUTH_PERIOD_NS: Final = 50_000_000  # at most one truth row per 50 ms of vehicle time
TRUTH_HEADER: Final = "t x y z\n"


class TruthLog:
    """The ``t x y z`` truth file (module docstring), created new and flushed per row."""

    def __init__(self, path: str | Path, *, origin_ns: int) -> None:
        """Create ``path`` (never overwritten) and write the header and the origin comment.

        Raises:
            FileExistsError: ``path`` exists.
        """
        self.origin_ns = origin_ns
        self._file = LineFile(Path(path), "utf-8")
        self._file.write_line(TRUTH_HEADER)
        self._file.write_line(f"# t0_ns {origin_ns} (host monotonic clock at t = 0)\n")
        self.rows = 0

    def write(self, t_ns: int, state: VehicleState) -> None:
        """One row: seconds since the origin, world x and y (m), height up (m)."""
        x, y, _ = state.pos_w_m
        t_s = (t_ns - self.origin_ns) / NS_PER_S
        self._file.write_line(f"{t_s:.4f} {x:.5f} {y:.5f} {state.height_m:.5f}\n")
        self.rows += 1

    def close(self) -> None:
        """Flush, fsync and close (idempotent)."""
        self._file.close()


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
    ) -> None:
        """Put the vehicle at rest at ``pos_w_m`` (on the floor if z = 0) at host ``t0_ns``.

        Args:
            cfg: the configuration (``mk`` counts and signs, ``sim.vehicle``).
            seed: seeds the vehicle's flight errors, gusts and the sensor noise.
            t0_ns: the host monotonic time that is vehicle time 0.
            truth_path: write the truth log there (a new file), else none.
            truth_origin_ns: the truth log's ``t`` = 0 (default ``t0_ns``; 0 gives host
                monotonic seconds, the flight logs' time base).
            stick_gas_with_extern_only: the simulated pilot's gas (module docstring).
            pos_w_m: the start position, world frame W (z down).
            yaw_rad: the start heading (SPEC §1, clockwise).

        Raises:
            FileExistsError: ``truth_path`` exists.
        """
        self.params = VehicleParams.from_config(cfg)
        self.cal = MkCalibration.from_config(cfg.mk)
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
            used_ah=cfg.sim.vehicle.battery_used_ah,
        )
        self._t_ns = t0_ns
        self._sticks = Sticks()
        self.extern_active = False  # the FC applies ExternControl (logged on each change)
        self._history: deque[tuple[int, VehicleState]] = deque([(t0_ns, self._state)])
        self._truth: TruthLog | None = None
        self._truth_due_ns = t0_ns
        if truth_path is not None:
            origin = t0_ns if truth_origin_ns is None else truth_origin_ns
            self._truth = TruthLog(truth_path, origin_ns=origin)
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
            self._state = step(
                self._state, sticks, (nxt - self._t_ns) / NS_PER_S, self.params, self.rng
            )
            self._t_ns = nxt
            self._history.append((nxt, self._state))
            if nxt >= self._truth_due_ns:
                self._write_truth()
        horizon = self._t_ns - HISTORY_NS
        while len(self._history) > 2 and self._history[1][0] <= horizon:
            self._history.popleft()
        return self._state

    def _write_truth(self) -> None:
        """A truth row now (if there is a log) and the next one due a period later."""
        if self._truth is not None:
            self._truth.write(self._t_ns, self._state)
        self._truth_due_ns = self._t_ns + TRUTH_PERIOD_NS

    def _bracket(self, t_ns: int) -> tuple[int, int]:
        """History indexes ``(i, j)`` with ``t_i <= t_ns <= t_j`` (clamped to the ends)."""
        h = self._history
        j = bisect.bisect_left(h, t_ns, key=lambda e: e[0])
        if j <= 0:
            return 0, 0
        if j >= len(h):
            return len(h) - 1, len(h) - 1
        return j - 1, j

    def state_at(self, t_ns: int) -> VehicleState:
        """The vehicle at ``t_ns``: advanced to it if later, else the nearest stored state."""
        if t_ns >= self._t_ns:
            return self.advance_to(t_ns)
        i, j = self._bracket(t_ns)
        (ti, si), (tj, sj) = self._history[i], self._history[j]
        return si if t_ns - ti <= tj - t_ns else sj

    def pose_at(self, t_ns: int) -> ScenePose:
        """Where the URG is at ``t_ns`` (a :data:`~mkflight.sim.urg_scene.PoseSource`).

        Later than now: the vehicle is advanced. Earlier: linear interpolation between
        the two stored states around ``t_ns`` (yaw along the short way round); before
        the history: its oldest state.
        """
        if t_ns >= self._t_ns:
            return _pose(self.advance_to(t_ns))
        i, j = self._bracket(t_ns)
        (ti, a), (tj, b) = self._history[i], self._history[j]
        if tj <= ti:
            return _pose(a)
        w = (t_ns - ti) / (tj - ti)
        dyaw = math.remainder(b.yaw_rad - a.yaw_rad, math.tau)
        return ScenePose(
            x_m=a.pos_w_m[0] + w * (b.pos_w_m[0] - a.pos_w_m[0]),
            y_m=a.pos_w_m[1] + w * (b.pos_w_m[1] - a.pos_w_m[1]),
            yaw_rad=math.remainder(a.yaw_rad + w * dyaw, math.tau),
            height_m=a.height_m + w * (b.height_m - a.height_m),
            roll_rad=a.roll_rad + w * (b.roll_rad - a.roll_rad),
            pitch_rad=a.pitch_rad + w * (b.pitch_rad - a.pitch_rad),
        )

    # ----------------------------------------------------------------- the FC's view
    def analog(self, t_ns: int, fc: FcModel) -> dict[int, int]:
        """DebugOut counts at ``t_ns``: the IMU and battery measured, in MK units (SPEC §1).

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
        values = analog_from_si(
            pitch_rad=m.pitch_rad,
            roll_rad=m.roll_rad,
            yaw_rad=m.yaw_rad,
            acc_x_mps2=m.acc_x_mps2,
            acc_y_mps2=m.acc_y_mps2,
            acc_z_mps2=m.acc_z_mps2,
            battery_v=battery_v,
            cal=self.cal,
        )
        values[ANALOG_GAS] = 4 * round(self._sticks.gas_counts)
        return values

    def close(self) -> None:
        """Close the truth log (idempotent)."""
        if self._truth is not None:
            self._truth.close()


def _pose(s: VehicleState) -> ScenePose:
    return ScenePose(
        x_m=s.pos_w_m[0],
        y_m=s.pos_w_m[1],
        yaw_rad=s.yaw_rad,
        height_m=s.height_m,
        roll_rad=s.roll_rad,
        pitch_rad=s.pitch_rad,
    )


def default_room() -> Room:
    """A 4 m x 3 m box with a 0.25 m pillar, the world origin off-centre (SPEC §8).

    Walls in every direction within 3 m (the URG reads to 4 m, seed §P), a pillar and
    unequal distances so that x, y and yaw are all observable by the scan matcher. Room
    coordinates are standard 2-D math (y to the left, :mod:`mkflight.sim.room`): the walls
    are 1.6 m behind, 2.4 m ahead, 1.8 m left and 1.2 m right of the origin.
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
        """Boot the FC at ``t_ns`` with ``world`` as its source, and attach it."""
        super().__init__(settings, world, t_ns=t_ns)
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
