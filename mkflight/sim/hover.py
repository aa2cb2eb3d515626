"""``mkflight sim hover``: estimator + controllers + failsafe + vehicle model in lock-step.

No ports and no real time. Two sides meet here:

* the **simulated airframe** (:class:`~mkflight.sim.lockstep.LockstepVehicle`): reads
  only ``cfg.sim`` (nominal, or a random airframe drawn with ``sim.seed``); its DebugOut
  instants follow the FC's 52-tick period plus the airframe's loop jitter and late
  frames; its IMU is measured (vibration, trims, biases, noise) and encoded into raw MK
  counts by the simulator's own encoder; its laser gives, every 100 ms, either the true
  pose and hat height plus scan-matcher-sized noise (the default, fast) or, with
  ``scans=True``, the raw ranges of a URG ray-cast in the room, each beam group at its own
  time. Laser data taken at ``t`` is stamped ``t + laser_extra_delay_s`` (what the driver
  believes: the data is older than it assumes) and arrives ~100 ms + extra + jitter later.
* the **flight** (:class:`~mkflight.flight.step.FlightCore`, the daemon's own pure step):
  DebugOut counts are decoded with the flight's calibration (``cfg.mk``:
  :class:`~mkflight.mk.units.MkCalibration`, :func:`~mkflight.mk.units.imu_from_debug`);
  with ``scans=True`` the URG values become the :class:`~mkflight.msgs.Scan` the driver
  would deliver (error codes and out-of-range values NaN) and go through the real
  :class:`~mkflight.flight.laser_pipeline.LaserPipeline` (hat height, points, PL-ICP)
  with the DebugOut pitch and roll nearest the scan's stamp, as the daemon's laser task
  does; the result enters :meth:`FlightCore.laser_step` at the next step, as the daemon's
  MK task applies it. The FC's rules then apply the command (extern gas capped by the
  pilot's stick gas, ``sim.fc.stick_gas``).

It takes off to ``height_m`` (default ``control.takeoff_height_m``), holds the take-off
x, y, ψ, lands after ``duration_s`` and releases. The precision is measured on the truth
about the set-point during HOLD (from :data:`SETTLE_S` after it starts). The two tables
(TABLE III/IV), ``events.jsonl``, ``flight.json`` (with the summary) and ``truth.txt``
(:class:`~mkflight.sim.truth.TruthLog`: the airframe, rows, touchdowns) are written. How
the flight ended is judged on the truth (:mod:`mkflight.sim.hover_result`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np

from mkflight.config import Config
from mkflight.config_search import ConfigSource
from mkflight.control.controller import Setpoint
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.conversions import NS_PER_S, US_PER_S
from mkflight.flight.step import PilotSticks
from mkflight.mk.messages import DebugOut
from mkflight.mk.units import imu_from_debug
from mkflight.msgs import Command, ImuSample
from mkflight.sim.airframe import airframe_from_config, describe
from mkflight.sim.hover_excite import Excitation
from mkflight.sim.hover_flight import FlightSide, HoverFaults, scan_from_raw
from mkflight.sim.hover_result import (
    END_FLYING,
    END_GROUND,
    END_LANDED,
    END_RELEASED_IN_AIR,
    LANDED_M,
    HoverResult,
    flight_end,
)
from mkflight.sim.lockstep import (
    IMU_PERIOD_NS,
    LASER_DELAY_NS,
    SCAN_PERIOD_NS,
    LockstepVehicle,
    gust_seed_for,
)
from mkflight.sim.truth import TruthLog
from mkflight.sim.vehicle import Sticks, VehicleState
from mkflight.urg.driver import streamed_steps

SETTLE_S: Final = 3.0  # precision counts from this long after HOLD begins
LAND_MARGIN_S: Final = 5.0  # time allowed after the duration to land


def _stats(errors: list[float]) -> tuple[float, float]:
    """``(std, rms)`` of the errors (m), NaN for none."""
    if not errors:
        return math.nan, math.nan
    a = np.asarray(errors)
    return float(np.std(a)), float(np.sqrt(np.mean(a * a)))


@dataclass(slots=True)
class _Tally:
    """What a hover measures as it flies: the truth's error in HOLD, the hand-back, the steps."""

    err_x: list[float] = field(default_factory=list)
    err_y: list[float] = field(default_factory=list)
    err_z: list[float] = field(default_factory=list)
    hold_start_ns: int | None = None
    hold_ns: int = 0  # the measured time: the DebugOut intervals of the counted steps
    had_control: bool = False
    handed_back_m: float | None = None  # truth height when control last went back
    steps: int = 0

    def hold(self, t_ns: int, dt_ns: int, end_ns: int, state: VehicleState, sp: Setpoint) -> None:
        """A step in HOLD with a valid pose: counted from :data:`SETTLE_S` in, until ``end_ns``."""
        self.hold_start_ns = t_ns if self.hold_start_ns is None else self.hold_start_ns
        if t_ns - self.hold_start_ns >= SETTLE_S * NS_PER_S and t_ns < end_ns:
            self.err_x.append(float(state.pos_w_m[0]) - sp.x_m)
            self.err_y.append(float(state.pos_w_m[1]) - sp.y_m)
            self.err_z.append(state.height_m - sp.height_m)
            self.hold_ns += dt_ns

    def released_in_air(self, take_control: bool, state: VehicleState) -> bool:
        """Note who has control after a step; True when it just went back above :data:`LANDED_M`."""
        if take_control:
            self.had_control, self.handed_back_m = True, None
            return False
        if self.had_control and self.handed_back_m is None:
            self.handed_back_m = state.height_m
            return self.handed_back_m > LANDED_M
        return False


def _fc_sticks(command: Command, stick_gas: int) -> Sticks:
    """What the FC flies: extern + neutral pilot sticks, the gas capped by the stick gas."""
    if not command.take_control:
        return Sticks()
    return Sticks(
        nick_counts=command.nick_counts,
        roll_counts=command.roll_counts,
        yaw_counts=command.yaw_counts,
        gas_counts=min(stick_gas, command.gas_counts),
    )


def _debug_imu(
    vehicle: LockstepVehicle, flight: FlightSide, t_ns: int, faults: HoverFaults
) -> ImuSample:
    """The FC's DebugOut at ``t_ns``, in its counts, decoded with the flight's calibration."""
    debug = DebugOut.from_values(vehicle.debug_values())
    imu = imu_from_debug(debug, t_ns, flight.cal)
    if faults.imu is not None and faults.active(t_ns):
        imu = faults.imu(imu)
    flight.attitude.append((t_ns, imu.pitch_rad, imu.roll_rad))
    return imu


def _fly(
    cfg: Config,
    flight: FlightSide,
    vehicle: LockstepVehicle,
    tally: _Tally,
    *,
    duration_s: float,
    faults: HoverFaults,
    excitation: Excitation | None,
) -> int:
    """Step flight and vehicle in lock-step, DebugOut by DebugOut; the last step's time (ns).

    Lands at ``duration_s``, stops :data:`LAND_MARGIN_S` later at the latest, or when
    control goes back in the air or the phase is RELEASED.
    """
    core = flight.core
    stick_gas = cfg.sim.fc.stick_gas
    end_ns = int(duration_s * NS_PER_S)
    stop_ns = end_ns + int(LAND_MARGIN_S * NS_PER_S)
    handshake_ns = int(cfg.mk.handshake_s * NS_PER_S)
    sticks = Sticks()
    t_ns = 0
    while t_ns < stop_ns:
        prev_ns, t_ns = t_ns, vehicle.next_debug_ns()
        state = vehicle.advance_to(t_ns, sticks)
        for data in vehicle.laser_arrivals(t_ns):  # the step applies what has arrived
            flight.laser(data, t_ns, faults)
        imu = _debug_imu(vehicle, flight, t_ns, faults)
        if excitation is not None and core.phase is Phase.HOLD:
            core.set_hold_offset(*excitation.offset_m(t_ns))
        out = core.imu_step(
            imu,
            PhaseRequests(takeoff=True, land=t_ns >= end_ns, handshake_ok=t_ns >= handshake_ns),
            sticks=PilotSticks(thrust_counts=stick_gas),
        )
        flight.log_step(t_ns, out, imu)
        sp = core.active_setpoint
        if out.phase is Phase.HOLD and out.estimate.pose_valid and sp is not None:
            tally.hold(t_ns, t_ns - prev_ns, end_ns, state, sp)
        tally.steps += 1
        sticks = _fc_sticks(out.command, stick_gas)
        if tally.released_in_air(out.command.take_control, state):
            break  # handed to the pilot in the air: the pilot has it now
        if out.phase is Phase.RELEASED:
            break
    return t_ns


def run_hover(
    cfg: Config,
    *,
    duration_s: float,
    seed: int,
    log_dir: Path,
    height_m: float | None = None,
    faults: HoverFaults | None = None,
    excite_m: float = 0.0,
    scans: bool = False,
    config_source: ConfigSource | None = None,
) -> HoverResult:
    """Fly a simulated hover of ``duration_s`` (take-off, hold, land) and measure it.

    ``seed`` seeds this flight (the vehicle's per-flight errors and gusts, the noise, the
    links' jitter); the airframe is ``airframe_from_config(cfg.sim)`` (``sim.seed`` draws
    a random one). ``scans``: ray-cast URG scans through the real laser pipeline instead
    of the true pose plus noise. ``excite_m`` > 0 moves the HOLD set-point in x and y,
    independently, between ±excite_m with random dwell times (:class:`Excitation`): the
    input a response test needs (``analyze latency``). The precision is then the tracking
    error about the moving set-point. ``config_source``: for ``flight.json``.
    """
    wall0, cpu0 = time.perf_counter(), time.process_time()
    faults = HoverFaults() if faults is None else faults
    log_dir.mkdir(parents=True, exist_ok=True)
    flight = FlightSide(cfg, log_dir, height_m=height_m, scans=scans, config_source=config_source)
    steps_asked = streamed_steps(cfg.laser)  # the driver's MD request (flight side)
    params = airframe_from_config(cfg.sim)
    airframe = {"kind": cfg.sim.airframe, "seed": cfg.sim.seed, **describe(params)}
    try:
        truth = TruthLog(log_dir / "truth.txt", origin_ns=0, airframe=airframe)
    except BaseException:
        flight.close()
        raise
    vehicle = LockstepVehicle(
        cfg.sim,
        seed=seed,
        scans=scans,
        scan_steps=steps_asked,
        truth=truth,
        params=params,
    )
    excitation = Excitation(excite_m, np.random.default_rng([seed, 1])) if excite_m > 0 else None
    tally = _Tally()
    try:
        t_ns = _fly(
            cfg, flight, vehicle, tally, duration_s=duration_s, faults=faults, excitation=excitation
        )
    finally:
        flight.close()
        truth.close()
    wall_s = time.perf_counter() - wall0
    result = _result(
        cfg,
        flight,
        vehicle,
        tally,
        log_dir=log_dir,
        scans=scans,
        sim_s=t_ns / NS_PER_S,
        wall_s=wall_s,
        cpu0=cpu0,
    )
    flight.write_summary(log_dir, result.as_dict())
    return result


def _result(
    cfg: Config,
    flight: FlightSide,
    vehicle: LockstepVehicle,
    tally: _Tally,
    *,
    log_dir: Path,
    scans: bool,
    sim_s: float,
    wall_s: float,
    cpu0: float,
) -> HoverResult:
    """The flown hover's :class:`HoverResult`, the CPU time counted from ``cpu0``."""
    core = flight.core
    end = flight_end(
        max_height_m=vehicle.max_height_m,
        in_control=core.last_command.take_control,
        handed_back_m=tally.handed_back_m,
    )
    sx, rx = _stats(tally.err_x)
    sy, ry = _stats(tally.err_y)
    sz, rz = _stats(tally.err_z)
    return HoverResult(
        std_x_m=sx,
        std_y_m=sy,
        std_z_m=sz,
        rms_x_m=rx,
        rms_y_m=ry,
        rms_z_m=rz,
        realtime_factor=sim_s / wall_s if wall_s > 0 else math.inf,
        log_dir=str(log_dir),
        sim_s=sim_s,
        wall_s=wall_s,
        hold_s=tally.hold_ns / NS_PER_S,
        end=end,
        failsafes=list(core.counters.failsafe_events),
        cpu_us_per_step=(time.process_time() - cpu0) / max(tally.steps, 1) * US_PER_S,
        max_height_m=vehicle.max_height_m,
        final_height_m=vehicle.state.height_m,
        released=not core.last_command.take_control,
        touchdowns_mps=[float(speed) for _, speed in vehicle.touchdowns],
        airframe=describe(vehicle.params),
        airframe_kind=cfg.sim.airframe,
        airframe_seed=cfg.sim.seed,
        learned=flight.learned(),
        scans=scans,
    )


__all__ = [
    "END_FLYING",
    "END_GROUND",
    "END_LANDED",
    "END_RELEASED_IN_AIR",
    "IMU_PERIOD_NS",
    "LASER_DELAY_NS",
    "SCAN_PERIOD_NS",
    "SETTLE_S",
    "Excitation",
    "HoverFaults",
    "HoverResult",
    "flight_end",
    "gust_seed_for",
    "run_hover",
    "scan_from_raw",
]
