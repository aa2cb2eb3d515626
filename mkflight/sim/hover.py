"""``mkflight sim hover``: estimator + controllers + failsafe + vehicle model in lock-step.

No ports and no real time: the vehicle model is stepped between the FC's DebugOut
instants (every 52 FC ticks = 53.248 ms, mk-serial.md §7.2). At each instant the IMU is
measured (vibration, trim, biases, noise), quantised through the MK's own counts
(SPEC §1's table both ways) and fed to the estimator; the failsafe, the flight phases and
the controllers decide the command; the FC's rules apply it (extern gas capped by the
pilot's stick gas). Every 100 ms a laser pose and hat height are measured at the scan's
time (truth plus scan-matcher-sized noise) and delivered 100 ms later (seed §G), stamped
with the time the scan was taken. The two tables (TABLE III/IV), ``flight.json`` and a
truth log are written, and the hover precision is measured on the truth about the
set-point during HOLD.

The laser here is a pose measurement, not ray-cast scans through the matcher: the
matcher's own accuracy is measured on the datasets (``tools/bench.py``); this tool is for
tuning the estimator and the loops, fast.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from mkflight.clock import NS_PER_S
from mkflight.config import Config
from mkflight.control.phases import Phase, PhaseRequests
from mkflight.flight.step import FlightCore, PilotSticks
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import new_flight_info, with_summary, write_flight_json
from mkflight.logs.table3 import Table3Writer
from mkflight.logs.table4 import Table4Writer
from mkflight.mk.messages import ANALOG_GAS, ANALOG_RECEIVER_LEVEL, DebugOut
from mkflight.mk.units import MkCalibration, analog_from_si, imu_from_debug
from mkflight.msgs import ImuSample, Pose2D
from mkflight.sim.vehicle import Sticks, VehicleParams, VehicleState, initial_state, step
from mkflight.sim.vehicle_sensors import battery_reading_v, imu_measured_si

IMU_PERIOD_NS = 52 * 1_024_000  # 'd' 5: 50 FC ticks + the 2-tick overshoot (mk-serial §7.2)
SCAN_PERIOD_NS = 100_000_000  # 600 rpm
LASER_DELAY_NS = 100_000_000  # the scan reaches the pose ~100 ms after it was taken (§G)
POSE_NOISE_M = 0.003  # the scan matcher at hover: ~1-3 mm per relation (data README)
YAW_NOISE_RAD = 0.001
HEIGHT_NOISE_M = 0.0015  # the median of 84 hat beams with 1 cm noise
SETTLE_S = 3.0  # precision counts from this long after HOLD begins
LAND_MARGIN_S = 5.0  # time allowed after the duration to land


@dataclass(slots=True)
class HoverResult:
    """What ``sim hover`` reports (SPEC §7, issue 6)."""

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
    landed: bool
    failsafes: list[str] = field(default_factory=list)
    cpu_us_per_step: float = 0.0
    max_height_m: float = 0.0
    final_height_m: float = 0.0
    released: bool = False

    def as_dict(self) -> dict[str, object]:
        """The ``--json`` object."""
        return {
            "std_x_m": round(self.std_x_m, 5),
            "std_y_m": round(self.std_y_m, 5),
            "std_z_m": round(self.std_z_m, 5),
            "rms_x_m": round(self.rms_x_m, 5),
            "rms_y_m": round(self.rms_y_m, 5),
            "rms_z_m": round(self.rms_z_m, 5),
            "realtime_factor": round(self.realtime_factor, 1),
            "log_dir": self.log_dir,
            "sim_s": round(self.sim_s, 3),
            "hold_s": round(self.hold_s, 3),
            "landed": self.landed,
            "failsafes": self.failsafes,
            "cpu_us_per_step": round(self.cpu_us_per_step, 1),
            "max_height_m": round(self.max_height_m, 3),
        }


@dataclass(frozen=True, slots=True)
class HoverFaults:
    """Faults injected from ``from_s`` on (for the failsafe tests and for users' what-ifs)."""

    from_s: float = math.inf
    imu: Callable[[ImuSample], ImuSample] | None = None
    drop_pose: bool = False
    drop_height: bool = False


class Excitation:
    """A random square wave per axis: ±amplitude, each level held 1.5-3 s (uniform, seeded).

    Random dwell times make the commands broadband enough for a clean cross-correlation
    (a fixed period would give a periodic curve with several equal peaks).
    """

    MIN_DWELL_S = 1.5
    MAX_DWELL_S = 3.0

    def __init__(self, amplitude_m: float, rng: np.random.Generator) -> None:
        self.amplitude_m = amplitude_m
        self._rng = rng
        self._level = [1.0, -1.0]
        self._next_ns: list[int] | None = None

    def _dwell_ns(self) -> int:
        return int(self._rng.uniform(self.MIN_DWELL_S, self.MAX_DWELL_S) * NS_PER_S)

    def offset_m(self, t_ns: int) -> tuple[float, float]:
        """The (dx, dy) offset at ``t_ns`` (times must not go back)."""
        if self._next_ns is None:
            self._next_ns = [t_ns + self._dwell_ns(), t_ns + self._dwell_ns()]
        for axis in (0, 1):
            while t_ns >= self._next_ns[axis]:
                self._level[axis] = -self._level[axis]
                self._next_ns[axis] += self._dwell_ns()
        return self.amplitude_m * self._level[0], self.amplitude_m * self._level[1]


def _advance(
    vehicle: VehicleState,
    sticks: Sticks,
    t_ns: int,
    params: VehicleParams,
    rng: np.random.Generator,
) -> VehicleState:
    """Step the vehicle to ``t_ns`` (its float time may be a hair ahead already: skip)."""
    dt_s = t_ns / NS_PER_S - vehicle.t_s
    if dt_s <= 1e-9:
        return vehicle
    return step(vehicle, sticks, dt_s, params, rng)


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
) -> HoverResult:
    """Fly a simulated hover of ``duration_s`` (take-off, hold, land) and measure it.

    ``excite_m`` > 0 moves the HOLD set-point in x and y, independently, between ±excite_m
    with random dwell times (:class:`Excitation`): the input a response test needs
    (``analyze latency``). The precision is then the tracking error about the moving
    set-point.
    """
    wall0, cpu0 = time.perf_counter(), time.process_time()
    rng = np.random.default_rng(seed)
    params = VehicleParams.from_config(cfg)
    vehicle: VehicleState = initial_state(params, rng, used_ah=cfg.sim.vehicle.battery_used_ah)
    cal = MkCalibration.from_config(cfg.mk)
    core = FlightCore(cfg, height_m=height_m)
    if faults is None:
        faults = HoverFaults()
    fault_from_ns = int(faults.from_s * NS_PER_S) if math.isfinite(faults.from_s) else 2**62
    max_height_m = 0.0
    stick_gas = cfg.sim.fc.stick_gas
    excitation = Excitation(excite_m, np.random.default_rng([seed, 1])) if excite_m > 0 else None

    log_dir.mkdir(parents=True, exist_ok=True)
    info = new_flight_info(datetime.now(UTC), cfg, fc_version=cfg.sim.fc.version)
    write_flight_json(log_dir, info)
    t3, t4, events = Table3Writer(log_dir), Table4Writer(log_dir), EventsWriter(log_dir)
    truth = (log_dir / "truth.txt").open("x", encoding="utf-8")
    truth.write("t x y z\n")

    sticks = Sticks()
    pending: deque[tuple[int, Pose2D, float]] = deque()  # (delivery t_ns, pose, height)
    next_scan_ns = 0
    end_ns = int(duration_s * NS_PER_S)
    stop_ns = end_ns + int(LAND_MARGIN_S * NS_PER_S)
    err_x: list[float] = []
    err_y: list[float] = []
    err_z: list[float] = []
    hold_start_ns: int | None = None
    t_ns = 0
    steps = 0
    try:
        while t_ns < stop_ns:
            t_ns += IMU_PERIOD_NS
            # Scans taken up to now: measured at their own time (the vehicle's pose then).
            while next_scan_ns <= t_ns:
                vehicle = _advance(vehicle, sticks, next_scan_ns, params, rng)
                pose = Pose2D(
                    next_scan_ns,
                    float(vehicle.pos_w_m[0] + rng.normal(0, POSE_NOISE_M)),
                    float(vehicle.pos_w_m[1] + rng.normal(0, POSE_NOISE_M)),
                    float(vehicle.yaw_rad + rng.normal(0, YAW_NOISE_RAD)),
                )
                height = float(vehicle.height_m + rng.normal(0, HEIGHT_NOISE_M))
                pending.append((next_scan_ns + LASER_DELAY_NS, pose, height))
                next_scan_ns += SCAN_PERIOD_NS
            vehicle = _advance(vehicle, sticks, t_ns, params, rng)
            truth.write(
                f"{t_ns / NS_PER_S:.4f} {vehicle.pos_w_m[0]:.5f} {vehicle.pos_w_m[1]:.5f} "
                f"{vehicle.height_m:.5f}\n"
            )
            # The laser poses whose delay has passed arrive now (TABLE III step).
            while pending and pending[0][0] <= t_ns:
                _, pose, height = pending.popleft()
                faulty = pose.t_ns >= fault_from_ns
                row3 = core.laser_step(
                    None if faulty and faults.drop_pose else pose,
                    None if faulty and faults.drop_height else height,
                    t_ns=pose.t_ns,
                )
                if row3 is not None:
                    t3.write_row(row3)
                    events.write(pose.t_ns, "scan", index=row3.index)  # the row's scan time
            # The FC's DebugOut: measured, in MK counts, back to SI (SPEC §1 both ways).
            m = imu_measured_si(vehicle, params, rng)
            battery = battery_reading_v(vehicle, params, rng)
            analog = analog_from_si(
                pitch_rad=m.pitch_rad,
                roll_rad=m.roll_rad,
                yaw_rad=m.yaw_rad,
                acc_x_mps2=m.acc_x_mps2,
                acc_y_mps2=m.acc_y_mps2,
                acc_z_mps2=m.acc_z_mps2,
                battery_v=battery,
                cal=cal,
            )
            analog[ANALOG_GAS] = 4 * int(sticks.gas_counts)
            analog[ANALOG_RECEIVER_LEVEL] = 200
            imu = imu_from_debug(DebugOut.from_values(analog), t_ns, cal)
            if faults.imu is not None and t_ns >= fault_from_ns:
                imu = faults.imu(imu)
            max_height_m = max(max_height_m, vehicle.height_m)
            if excitation is not None and core.phase is Phase.HOLD:
                core.set_hold_offset(*excitation.offset_m(t_ns))
            out = core.imu_step(
                imu,
                PhaseRequests(
                    takeoff=True,
                    land=t_ns >= end_ns,
                    handshake_ok=t_ns >= int(cfg.mk.handshake_s * NS_PER_S),
                ),
                sticks=PilotSticks(thrust_counts=stick_gas),
            )
            command = out.command
            t4.write_row(out.row)
            # What the two tables do not hold (SPEC §6): height, gas, battery, phase, action.
            sp_now = core.active_setpoint
            events.write(
                t_ns,
                "step",
                x_m=round(out.estimate.x_m, 4),
                y_m=round(out.estimate.y_m, 4),
                sp_x_m=None if sp_now is None else round(sp_now.x_m, 4),
                sp_y_m=None if sp_now is None else round(sp_now.y_m, 4),
                sp_height_m=None if sp_now is None else round(sp_now.height_m, 4),
                height_m=round(out.estimate.height_m, 4),
                vz_up_mps=round(out.estimate.vz_up_mps, 4),
                gas_counts=command.gas_counts,
                battery_v=round(imu.battery_v, 2),
                phase=out.phase.name,
                action=out.action.name,
            )
            for e in out.failsafe_events:
                cause = getattr(e.cause, "value", "")
                events.write(e.t_ns, "failsafe", action=e.action.name, cause=cause)
            for pe in out.phase_events:
                events.write(pe.t_ns, "phase", to=pe.to_phase.name, reason=pe.reason)
            if out.phase is Phase.HOLD and out.estimate.pose_valid:
                sp = core.active_setpoint
                if hold_start_ns is None:
                    hold_start_ns = t_ns
                if sp is not None and t_ns - hold_start_ns >= SETTLE_S * NS_PER_S and t_ns < end_ns:
                    err_x.append(float(vehicle.pos_w_m[0]) - sp.x_m)
                    err_y.append(float(vehicle.pos_w_m[1]) - sp.y_m)
                    err_z.append(vehicle.height_m - sp.height_m)
            # The FC applies it: extern added to the (neutral) sticks, gas capped (§7.4).
            if command.take_control:
                sticks = Sticks(
                    nick_counts=command.nick_counts,
                    roll_counts=command.roll_counts,
                    yaw_counts=command.yaw_counts,
                    gas_counts=min(stick_gas, command.gas_counts),
                )
            else:
                sticks = Sticks()
            steps += 1
            if out.phase is Phase.RELEASED:
                break
    finally:
        t3.close()
        t4.close()
        events.close()
        truth.close()
    wall_s = time.perf_counter() - wall0
    cpu_us = (time.process_time() - cpu0) / max(steps, 1) * 1e6
    sx, rx = _stats(err_x)
    sy, ry = _stats(err_y)
    sz, rz = _stats(err_z)
    sim_s = t_ns / NS_PER_S
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
        hold_s=len(err_x) * IMU_PERIOD_NS / NS_PER_S,
        landed=core.phase in (Phase.LANDED, Phase.RELEASED),
        failsafes=core.counters.failsafe_events,
        cpu_us_per_step=cpu_us,
        max_height_m=max_height_m,
        final_height_m=vehicle.height_m,
        released=not core.last_command.take_control,
    )
    write_flight_json(log_dir, with_summary(info, result.as_dict()))
    return result


__all__ = ["HoverResult", "run_hover"]
