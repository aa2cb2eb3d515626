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
(:class:`~mkflight.sim.truth.TruthLog`: the airframe, rows, touchdowns) are written.

How it ended (:attr:`HoverResult.end`, judged on the truth): ``landed`` (on the floor,
≤ :data:`LANDED_M`, when control went back), ``released in the air`` (handed to the pilot
above it: the run stops there, the pilot has it), ``ground`` (never above
:data:`LANDED_M`), ``flying`` (still under our control when the time ran out). Every
touchdown's downward speed is the truth of the landing's hardness (SPEC §8: ≤ 0.5 m/s).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np

from mkflight.clock import NS_PER_S
from mkflight.config import Config
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.flight.step import PilotSticks
from mkflight.mk.messages import DebugOut
from mkflight.mk.units import imu_from_debug
from mkflight.sim.airframe import airframe_from_config, describe
from mkflight.sim.hover_excite import Excitation
from mkflight.sim.hover_flight import FlightSide, HoverFaults, scan_from_raw
from mkflight.sim.lockstep import (
    IMU_PERIOD_NS,
    LASER_DELAY_NS,
    SCAN_PERIOD_NS,
    LockstepVehicle,
    gust_seed_for,
)
from mkflight.sim.truth import TruthLog
from mkflight.sim.vehicle import Sticks
from mkflight.urg.driver import settings_from_config

SETTLE_S: Final = 3.0  # precision counts from this long after HOLD begins
LAND_MARGIN_S: Final = 5.0  # time allowed after the duration to land
LANDED_M: Final = 0.05  # on the floor (truth height); above it when handed back: in the air

END_LANDED: Final = "landed"
END_RELEASED_IN_AIR: Final = "released in the air"
END_GROUND: Final = "ground"
END_FLYING: Final = "flying"


@dataclass(slots=True)
class HoverResult:
    """What ``sim hover`` reports (SPEC §7, issue 6 and 17): precision, landing, airframe."""

    std_x_m: float
    std_y_m: float
    std_z_m: float
    rms_x_m: float
    rms_y_m: float
    rms_z_m: float
    realtime_factor: float
    log_dir: str
    sim_s: float
    wall_s: float
    hold_s: float
    end: str  # END_LANDED, END_RELEASED_IN_AIR, END_GROUND or END_FLYING
    failsafes: list[str] = field(default_factory=list)
    cpu_us_per_step: float = 0.0
    max_height_m: float = 0.0
    final_height_m: float = 0.0
    released: bool = False  # control is the pilot's at the end (Config = 0)
    touchdowns_mps: list[float] = field(default_factory=list)  # every touchdown (truth)
    airframe: dict[str, float | int | bool | list[float]] = field(default_factory=dict)
    airframe_kind: str = "nominal"  # sim.airframe
    airframe_seed: int = 0  # sim.seed (what draws a random airframe)
    learned: dict[str, object] = field(default_factory=dict)  # FlightCore.learned()
    scans: bool = False  # the laser was ray-cast scans through the real pipeline

    @property
    def landed(self) -> bool:
        """On the floor when control went back (never "released in the air")."""
        return self.end == END_LANDED

    @property
    def touchdown_mps(self) -> float:
        """The hardest touchdown's downward speed (truth), NaN if none."""
        return max(self.touchdowns_mps) if self.touchdowns_mps else math.nan

    def as_dict(self) -> dict[str, object]:
        """The ``--json`` object and ``flight.json``'s summary (NaN as null)."""
        hardest = self.touchdown_mps
        return {
            "std_x_m": _r(self.std_x_m, 5),
            "std_y_m": _r(self.std_y_m, 5),
            "std_z_m": _r(self.std_z_m, 5),
            "rms_x_m": _r(self.rms_x_m, 5),
            "rms_y_m": _r(self.rms_y_m, 5),
            "rms_z_m": _r(self.rms_z_m, 5),
            "realtime_factor": round(self.realtime_factor, 1),
            "log_dir": self.log_dir,
            "sim_s": round(self.sim_s, 3),
            "hold_s": round(self.hold_s, 3),
            "end": self.end,
            "landed": self.landed,
            "released": self.released,
            "touchdowns_mps": [round(v, 3) for v in self.touchdowns_mps],
            "touchdown_mps": _r(hardest, 3),
            "failsafes": self.failsafes,
            "cpu_us_per_step": round(self.cpu_us_per_step, 1),
            "max_height_m": round(self.max_height_m, 3),
            "final_height_m": round(self.final_height_m, 3),
            "scans": self.scans,
            "airframe_kind": self.airframe_kind,
            "airframe_seed": self.airframe_seed,
            "airframe": self.airframe,
            "learned": self.learned,
        }


def _r(value: float, digits: int) -> float | None:
    """``value`` rounded, or None (JSON null) when not finite."""
    return round(value, digits) if math.isfinite(value) else None


def flight_end(*, max_height_m: float, in_control: bool, handed_back_m: float | None) -> str:
    """How a flight ended, from the truth (module docstring).

    Args:
        max_height_m: the highest the vehicle flew (truth).
        in_control: the last command still takes control (Config bit 0).
        handed_back_m: the truth height when control last went back, None if it never did.
    """
    if max_height_m <= LANDED_M:
        return END_GROUND
    if in_control or handed_back_m is None:
        return END_FLYING
    return END_LANDED if handed_back_m <= LANDED_M else END_RELEASED_IN_AIR


def _stats(errors: list[float]) -> tuple[float, float]:
    if not errors:
        return math.nan, math.nan
    a = np.asarray(errors)
    return float(np.std(a)), float(np.sqrt(np.mean(a * a)))


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
) -> HoverResult:
    """Fly a simulated hover of ``duration_s`` (take-off, hold, land) and measure it.

    ``seed`` seeds this flight (the vehicle's per-flight errors and gusts, the noise, the
    links' jitter); the airframe is ``airframe_from_config(cfg.sim)`` (``sim.seed`` draws
    a random one). ``scans``: ray-cast URG scans through the real laser pipeline instead
    of the true pose plus noise. ``excite_m`` > 0 moves the HOLD set-point in x and y,
    independently, between ±excite_m with random dwell times (:class:`Excitation`): the
    input a response test needs (``analyze latency``). The precision is then the tracking
    error about the moving set-point.
    """
    wall0, cpu0 = time.perf_counter(), time.process_time()
    faults = HoverFaults() if faults is None else faults
    log_dir.mkdir(parents=True, exist_ok=True)
    flight = FlightSide(cfg, log_dir, height_m=height_m, scans=scans)
    core = flight.core
    steps_asked = settings_from_config(cfg.laser)  # the driver's MD request (flight side)
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
        scan_steps=(steps_asked.first_step, steps_asked.last_step),
        truth=truth,
        params=params,
    )
    stick_gas = cfg.sim.fc.stick_gas
    excitation = Excitation(excite_m, np.random.default_rng([seed, 1])) if excite_m > 0 else None
    end_ns = int(duration_s * NS_PER_S)
    stop_ns = end_ns + int(LAND_MARGIN_S * NS_PER_S)
    handshake_ns = int(cfg.mk.handshake_s * NS_PER_S)
    err_x: list[float] = []
    err_y: list[float] = []
    err_z: list[float] = []
    hold_start_ns: int | None = None
    hold_ns = 0  # the measured time: the DebugOut intervals of the counted steps
    prev_ns = 0
    had_control = False
    handed_back_m: float | None = None  # truth height when control last went back
    sticks = Sticks()
    t_ns = 0
    steps = 0
    try:
        while t_ns < stop_ns:
            prev_ns, t_ns = t_ns, vehicle.next_debug_ns()
            state = vehicle.advance_to(t_ns, sticks)
            for data in vehicle.laser_arrivals(t_ns):  # the step applies what has arrived
                flight.laser(data, t_ns, faults)
            # The FC's DebugOut, in its counts, decoded with the flight's calibration.
            debug = DebugOut.from_values(vehicle.debug_values())
            imu = imu_from_debug(debug, t_ns, flight.cal)
            if faults.imu is not None and faults.active(t_ns):
                imu = faults.imu(imu)
            flight.attitude.append((t_ns, imu.pitch_rad, imu.roll_rad))
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
                hold_start_ns = t_ns if hold_start_ns is None else hold_start_ns
                if t_ns - hold_start_ns >= SETTLE_S * NS_PER_S and t_ns < end_ns:
                    err_x.append(float(state.pos_w_m[0]) - sp.x_m)
                    err_y.append(float(state.pos_w_m[1]) - sp.y_m)
                    err_z.append(state.height_m - sp.height_m)
                    hold_ns += t_ns - prev_ns
            steps += 1
            command = out.command
            if command.take_control:  # the FC applies it: extern + neutral sticks, gas capped
                had_control, handed_back_m = True, None
                sticks = Sticks(
                    nick_counts=command.nick_counts,
                    roll_counts=command.roll_counts,
                    yaw_counts=command.yaw_counts,
                    gas_counts=min(stick_gas, command.gas_counts),
                )
            else:
                sticks = Sticks()
                if had_control and handed_back_m is None:
                    handed_back_m = state.height_m
                    if handed_back_m > LANDED_M:
                        break  # handed to the pilot in the air: the pilot has it now
            if out.phase is Phase.RELEASED:
                break
    finally:
        flight.close()
        truth.close()
    wall_s = time.perf_counter() - wall0
    sim_s = t_ns / NS_PER_S
    end = flight_end(
        max_height_m=vehicle.max_height_m,
        in_control=core.last_command.take_control,
        handed_back_m=handed_back_m,
    )
    sx, rx = _stats(err_x)
    sy, ry = _stats(err_y)
    sz, rz = _stats(err_z)
    result = HoverResult(
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
        hold_s=hold_ns / NS_PER_S,
        end=end,
        failsafes=list(core.counters.failsafe_events),
        cpu_us_per_step=(time.process_time() - cpu0) / max(steps, 1) * 1e6,
        max_height_m=vehicle.max_height_m,
        final_height_m=vehicle.state.height_m,
        released=not core.last_command.take_control,
        touchdowns_mps=[float(speed) for _, speed in vehicle.touchdowns],
        airframe=describe(params),
        airframe_kind=cfg.sim.airframe,
        airframe_seed=cfg.sim.seed,
        learned=flight.learned(),
        scans=scans,
    )
    flight.write_summary(log_dir, result.as_dict())
    return result


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
