"""The live simulator: the simulated vehicle on two pseudo-terminals, in real time (SPEC §8).

:class:`LiveSim` is what ``mkflight sim`` (and so ``fly --hover --sim``) runs: one
:class:`~mkflight.sim.world.SimWorld` (the vehicle model in host time) behind

* a FlightCtrl emulator (:class:`~mkflight.sim.fc_server.FcEmulator` serving a
  :class:`~mkflight.sim.world.WorldFc`): its DebugOut measures the vehicle, and the
  ExternControl it receives is what the vehicle flies;
* a URG-04LX emulator (:class:`~mkflight.sim.urg_server.UrgEmulator`) whose
  :class:`~mkflight.sim.urg_scene.RoomScene` ray-casts the room from the vehicle's pose
  at each beam's time, and folds the airframe's hat beams down to the floor.

Both links time like the airframe's (:func:`~mkflight.sim.airframe.airframe_from_config`
of ``cfg.sim``): the FC's DebugOut with its loop's jitter and late frames, the URG's
replies after the sensor's own USB delay (:data:`~mkflight.sim.urg_server.USB_DELAY_S`)
plus ``laser_extra_delay_s`` (data older than the driver's configured
``transport_delay_s`` assumes) and a jitter up to ``laser_jitter_s``. Nothing of ``mk``,
``control`` or ``laser`` is read.

The room is :func:`~mkflight.sim.world.default_room` unless one is given.

Faults (:class:`~mkflight.sim.live_faults.Fault`, parsed from ``KIND@T[:ARG]`` by
:mod:`mkflight.sim.live_faults`; ``KIND:ARG@T`` is accepted too) fire ``T`` seconds
after :meth:`LiveSim.start` through the emulators' own fault methods (:data:`FAULT_KINDS`
lists them and their arguments). The FC's and the URG's vanish and replug faults need a
stable path: if one is scheduled and no link was given, the link is made in a temporary
directory. Each fault, as it fires, is logged (``sim fault``) with its time on the fault
clock (``t_s``) and on the host's monotonic clock (``mono_s``, the flight logs' time base):
the record a fault test checks that the fault happened, and when.
"""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Final, Self, TypeVar

import numpy as np
import structlog

from mkflight.config import Config, SimFcConfig
from mkflight.errors import ConfigError
from mkflight.sim.fc_server import FcEmulator
from mkflight.sim.live_faults import FAULT_KINDS as FAULT_KINDS
from mkflight.sim.live_faults import Fault as Fault
from mkflight.sim.live_faults import parse_fault as parse_fault
from mkflight.sim.live_faults import parse_faults as parse_faults
from mkflight.sim.room import Room, room_caster
from mkflight.sim.urg_scene import HatGeometry, RoomScene
from mkflight.sim.urg_server import USB_DELAY_S, UrgEmulator
from mkflight.sim.world import SimWorld, WorldFc, default_room

log = structlog.get_logger("mkflight.sim")
T = TypeVar("T")

CRASH_CHECK_S: Final = 0.5  # how often :meth:`LiveSim.serve` looks for a crashed task


class _WorldFcEmulator(FcEmulator):
    """The FC emulator serving a :class:`WorldFc` (the world advanced before the FC acts)."""

    def __init__(self, settings: SimFcConfig, world: SimWorld, *, link: str | Path | None) -> None:
        super().__init__(settings, world, link=link, name="fc")
        self._fc_settings = settings
        self._world = world

    def _new_model(self, t_ns: int) -> WorldFc:
        return WorldFc(self._fc_settings, self._world, t_ns=t_ns)


class LiveSim:
    """The simulated vehicle on two ptys, closed loop, with a fault schedule (module doc)."""

    def __init__(
        self,
        cfg: Config,
        *,
        seed: int | None = None,
        mk_link: str | Path | None = None,
        laser_link: str | Path | None = None,
        truth_path: str | Path | None = None,
        truth_origin_ns: int | None = None,
        faults: Sequence[Fault | str] = (),
        room: Room | None = None,
        stick_gas_with_extern_only: bool = True,
        fault_clock: asyncio.Event | None = None,
    ) -> None:
        """Check the fault schedule; nothing runs before :meth:`start`.

        Args:
            cfg: the configuration (``sim`` only: the airframe and the FC's settings).
            seed: seeds this flight: the vehicle's errors and gusts, the sensor noise,
                the links' jitter and the garbage (default ``sim.seed``; a random
                airframe is drawn with ``sim.seed``).
            mk_link: a stable symlink to the FC's pty, else none.
            laser_link: a stable symlink to the URG's pty, else none.
            truth_path: write the truth log there (a new file).
            truth_origin_ns: the truth log's ``t`` = 0 (default: the start).
            faults: the schedule, as :class:`Fault` or ``KIND@T[:ARG]`` strings.
            room: the room (default :func:`default_room`).
            stick_gas_with_extern_only: the simulated pilot (:mod:`mkflight.sim.world`).
            fault_clock: if given, the fault times count from when it is set, not the start.

        Raises:
            ConfigError: a bad fault string.
        """
        self.cfg = cfg
        self.seed = cfg.sim.seed if seed is None else seed
        self.faults = parse_faults(faults)
        self.room = room if room is not None else default_room()
        self._links = {"fc": mk_link, "laser": laser_link}
        self._truth_path = truth_path
        self._truth_origin_ns = truth_origin_ns
        self._stick_gas_with_extern_only = stick_gas_with_extern_only
        self._garbage_rng = np.random.default_rng([self.seed, 2])
        self._fault_clock = fault_clock
        self._tmpdir: tempfile.TemporaryDirectory[str] | None = None
        self._world: SimWorld | None = None
        self._fc: _WorldFcEmulator | None = None
        self._urg: UrgEmulator | None = None
        self._fault_task: asyncio.Task[None] | None = None
        self._start_s = 0.0
        self._fault_origin_s = 0.0  # the fault times count from here
        self.fired: list[Fault] = []  # the faults injected so far, in order
        self.faults_done = asyncio.Event()  # set when every scheduled fault has fired
        self.error: BaseException | None = None  # the fault task's crash

    # ----------------------------------------------------------------- parts
    @property
    def world(self) -> SimWorld:
        """The vehicle (after :meth:`start`)."""
        return _started(self._world)

    @property
    def fc(self) -> FcEmulator:
        """The FlightCtrl emulator (after :meth:`start`)."""
        return _started(self._fc)

    @property
    def urg(self) -> UrgEmulator:
        """The URG emulator (after :meth:`start`)."""
        return _started(self._urg)

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> tuple[str, str]:
        """Start the vehicle and both emulators now; return the FC's and the URG's paths.

        Raises:
            ConfigError: the truth file exists or cannot be created, or a link cannot be
                made.
        """
        for device in ("fc", "laser"):
            if self._links[device] is None and self._needs_link(device):
                if self._tmpdir is None:
                    self._tmpdir = tempfile.TemporaryDirectory(prefix="mkflight-sim-")
                self._links[device] = Path(self._tmpdir.name) / device
        t0_ns = time.monotonic_ns()
        try:
            self._world = SimWorld(
                self.cfg,
                seed=self.seed,
                t0_ns=t0_ns,
                truth_path=self._truth_path,
                truth_origin_ns=self._truth_origin_ns,
                stick_gas_with_extern_only=self._stick_gas_with_extern_only,
            )
        except OSError as err:
            msg = f"cannot create the truth log {str(self._truth_path)!r}: {err.strerror or err}"
            raise ConfigError(msg) from err
        self._fc = _WorldFcEmulator(self.cfg.sim.fc, self._world, link=self._links["fc"])
        params = self._world.params
        scene = RoomScene(
            room_caster(self.room),
            pose=self._world.pose_at,
            hat=HatGeometry.of(params),
            seed=self.seed,
        )
        self._urg = UrgEmulator(
            scene,
            link=self._links["laser"],
            name="urg",
            usb_delay_s=USB_DELAY_S + params.laser_extra_delay_s,  # older than assumed
            usb_jitter_s=params.laser_jitter_s,
            seed=self.seed,
        )
        try:
            await self._fc.start()
            await self._urg.start()
        except OSError as err:
            await self.stop()
            msg = f"cannot create the simulator's ptys or links: {err}"
            raise ConfigError(msg) from err
        self._start_s = self._fault_origin_s = time.monotonic()
        self._fault_task = asyncio.create_task(self._run_faults(), name="sim-faults")
        self._fault_task.add_done_callback(self._on_fault_task_done)
        log.info("sim started", mk=self._fc.path, laser=self._urg.path, seed=self.seed)
        return self._fc.path, self._urg.path

    def _needs_link(self, device: str) -> bool:
        prefix = "fc-" if device == "fc" else "laser-"
        return any(f.kind in (prefix + "vanish", prefix + "replug") for f in self.faults)

    async def stop(self) -> None:
        """Stop the faults and both emulators, close the truth log, remove the links.

        Raises:
            BaseException: the first crash of an emulator task or of the fault task.
        """
        crash: BaseException | None = None
        if self._fault_task is not None:
            self._fault_task.cancel()
            await asyncio.gather(self._fault_task, return_exceptions=True)
            self._fault_task = None
        if self._fc is not None:  # the FC's view of every command it took (fault tests)
            c = self._fc.model.controls
            log.info(
                "sim fc commands",
                frames=c.extern_frames,
                max_tilt_counts=round(c.max_tilt_counts, 2),
                max_yaw_counts=c.max_yaw_counts,
                max_gas_counts=c.max_gas_counts,
                min_gas_counts=c.min_gas_counts,
                extern_active=self._fc.model.extern_active,
            )
        for emulator in (self._fc, self._urg):
            if emulator is None:
                continue
            try:
                await emulator.stop()
            except Exception as err:
                crash = crash or err
        if self._world is not None:
            self._world.close()
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None
        crash = crash or self.error
        if crash is not None:
            raise crash

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        """Stop (a crash found then is raised, chained to the body's error if any)."""
        await self.stop()

    def crashed(self) -> BaseException | None:
        """The first crash of an emulator task or the fault task, or None."""
        for emulator in (self._fc, self._urg):
            if emulator is not None and emulator.error is not None:
                return emulator.error
        return self.error

    async def serve(self, stop: asyncio.Event, duration_s: float | None = None) -> None:
        """Run until ``stop`` is set or ``duration_s`` has passed since the start.

        Raises:
            RuntimeError: a task crashed (the crash is its cause).
        """
        end_s = None if duration_s is None else self._start_s + duration_s
        while not stop.is_set():
            if (crash := self.crashed()) is not None:
                msg = f"the simulator crashed: {crash!r}"
                raise RuntimeError(msg) from crash
            wait_s = CRASH_CHECK_S
            if end_s is not None:
                wait_s = min(wait_s, end_s - time.monotonic())
                if wait_s <= 0:
                    return
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait_s):
                    await stop.wait()

    # ----------------------------------------------------------------- faults
    async def _run_faults(self) -> None:
        """Fire each fault at its time (a timer: the schedule is wall-clock by design)."""
        if self._fault_clock is not None:
            await self._fault_clock.wait()
            self._fault_origin_s = time.monotonic()
            log.info(
                "sim fault clock started",
                faults=len(self.faults),
                mono_s=round(self._fault_origin_s, 3),
            )
        for fault in self.faults:
            delay_s = self._fault_origin_s + fault.at_s - time.monotonic()
            if delay_s > 0:
                await asyncio.sleep(delay_s)
            self.inject(fault)
        self.faults_done.set()

    def _on_fault_task_done(self, task: asyncio.Task[None]) -> None:
        if not task.cancelled() and task.exception() is not None and self.error is None:
            self.error = task.exception()

    def inject(self, fault: Fault) -> None:
        """Inject ``fault`` now (its time is not looked at) and note it in :attr:`fired`."""
        fc, urg, world = self.fc, self.urg, self.world
        x = 0.0 if fault.arg is None else fault.arg  # kinds with an argument always have one
        n = round(x)

        def battery() -> None:
            world.battery_override_v = x

        actions: dict[str, Callable[[], object]] = {
            "fc-vanish": fc.vanish,
            "fc-replug": fc.replug,
            "fc-silent": lambda: fc.silence_for(x),
            "fc-reboot": lambda: fc.reboot(x),
            "fc-garbage": lambda: fc.inject_garbage(self._garbage(n)),
            "fc-corrupt": lambda: fc.corrupt_next(n),
            "laser-vanish": urg.vanish,
            "laser-replug": urg.replug,
            "laser-stall": lambda: urg.stall_for(x),
            "laser-garbage": lambda: urg.inject_garbage(self._garbage(n) + b"\n"),
            "laser-badsum": lambda: urg.corrupt_next(n),
            "battery": battery,
            "pilot-nick": lambda: fc.model.controls.set_sticks(nick=n),
        }
        actions[fault.kind]()
        self.fired.append(fault)
        # t_s on the fault clock (the schedule's), mono_s on the host's monotonic clock:
        # the flight logs' time base, so a test can place the fault in the flight's events
        now_s = time.monotonic()
        log.info(
            "sim fault",
            fault=str(fault),
            t_s=round(now_s - self._fault_origin_s, 3),
            mono_s=round(now_s, 3),
        )

    def _garbage(self, n: int) -> bytes:
        """``n`` random bytes (seeded)."""
        return self._garbage_rng.integers(0, 256, n, dtype=np.uint8).tobytes()


def _started(part: T | None) -> T:
    if part is None:
        msg = "sim: not started"
        raise RuntimeError(msg)
    return part
