"""The flight side of ``sim hover``: what the daemon does with what the links deliver.

:class:`FlightSide` holds the daemon's pure core (:class:`~mkflight.flight.step.FlightCore`),
the flight's own MK calibration (``cfg.mk``: DebugOut counts are decoded as the daemon
decodes them, whatever the simulated airframe really is), the real laser pipeline for
ray-cast scans, and the flight folder's tables and events. A scan becomes the
:class:`~mkflight.msgs.Scan` the URG driver would deliver (:func:`scan_from_raw`), goes
through :meth:`~mkflight.flight.laser_pipeline.LaserPipeline.process` with the DebugOut
pitch and roll nearest its stamp (the daemon's ``attitude_at``), and its result enters
:meth:`~mkflight.flight.step.FlightCore.laser_step` at the step it arrived for, with that
step's time as its arrival (the daemon's MK task). :class:`HoverFaults` cuts the laser
or rewrites the IMU samples in a time window.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final

import numpy as np

from mkflight.config import Config
from mkflight.config_search import ConfigSource
from mkflight.conversions import MM_PER_M, NS_PER_S
from mkflight.flight.laser_pipeline import LaserPipeline
from mkflight.flight.step import FlightCore, ImuStepOutput
from mkflight.logs import schema
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import new_flight_info, with_summary, write_flight_json
from mkflight.logs.table3 import Table3Writer
from mkflight.logs.table4 import Table4Writer
from mkflight.mk.units import MkCalibration
from mkflight.msgs import ImuSample, Pose2D, Scan
from mkflight.sim.lockstep import PoseFix, RawScan
from mkflight.urg.units import URG_04LX

ATTITUDE_SAMPLES: Final = 64  # DebugOut attitudes kept for a scan's pitch and roll (app.py's)


@dataclass(frozen=True, slots=True)
class HoverFaults:
    """Faults injected from ``from_s`` until ``until_s`` (failsafe tests, users' what-ifs).

    ``imu`` rewrites each decoded DebugOut sample in the window; ``drop_pose`` and
    ``drop_height`` lose the laser's pose and hat height of the scans stamped in it (both:
    a laser stall).
    """

    from_s: float = math.inf
    until_s: float = math.inf
    imu: Callable[[ImuSample], ImuSample] | None = None
    drop_pose: bool = False
    drop_height: bool = False

    def active(self, t_ns: int) -> bool:
        """Whether the window holds ``t_ns``."""
        return self.from_s * NS_PER_S <= t_ns < self.until_s * NS_PER_S


def scan_from_raw(raw: RawScan) -> Scan:
    """The :class:`~mkflight.msgs.Scan` the URG driver makes of ``raw`` (values in [DMIN, DMAX])."""
    p = URG_04LX
    values = raw.values_mm.astype(np.float64)
    ok = (values >= p.dmin_mm) & (values <= p.dmax_mm)
    ranges = np.where(ok, values / MM_PER_M, np.nan)
    return Scan(t_ns=raw.stamp_ns, ranges_m=ranges, first_step=raw.first_step, seq=raw.seq)


class FlightSide:
    """The flight side of ``sim hover``: the daemon's core, calibration, pipeline and logs."""

    def __init__(
        self,
        cfg: Config,
        log_dir: Path,
        *,
        height_m: float | None,
        scans: bool,
        config_source: ConfigSource | None = None,
    ) -> None:
        """The core, the calibration, the pipeline (``scans``); write ``flight.json``."""
        self.cfg = cfg
        self.core = FlightCore(cfg, height_m=height_m)
        self.cal = MkCalibration.from_config(cfg.mk)  # the flight's, not the airframe's
        self.pipeline = LaserPipeline(cfg) if scans else None
        self.attitude: deque[tuple[int, float, float]] = deque(maxlen=ATTITUDE_SAMPLES)
        self.info = new_flight_info(
            datetime.now(UTC), cfg, fc_version=cfg.sim.fc.version, config_source=config_source
        )
        write_flight_json(log_dir, self.info)
        self.t3 = Table3Writer(log_dir)
        self.t4 = Table4Writer(log_dir)
        self.events = EventsWriter(log_dir)
        self.fixes = 0  # pose fixes delivered: their sequence numbers

    def close(self) -> None:
        """Close the tables and the events."""
        self.t3.close()
        self.t4.close()
        self.events.close()

    def attitude_at(self, t_ns: int) -> tuple[float, float]:
        """Pitch and roll of the DebugOut sample nearest ``t_ns`` (the daemon's rule)."""
        if not self.attitude:
            return math.nan, math.nan
        best = min(self.attitude, key=lambda a: abs(a[0] - t_ns))
        return best[1], best[2]

    def laser(self, data: PoseFix | RawScan, t_ns: int, faults: HoverFaults) -> None:
        """Apply one laser delivery at the step of ``t_ns`` (the daemon's MK task does)."""
        degenerate = False
        match_ms = 0.0  # a pose fix: no matching ran
        pose: Pose2D | None
        height: float | None
        if isinstance(data, PoseFix):
            self.fixes += 1
            pose, height, stamp, seq = data.pose, data.height_m, data.pose.t_ns, self.fixes
        else:
            assert self.pipeline is not None
            scan = scan_from_raw(data)
            pitch, roll = self.attitude_at(scan.t_ns)
            r = self.pipeline.process(scan, pitch, roll)
            pose, height, stamp, degenerate = r.pose, r.height_m, r.scan_t_ns, r.degenerate
            seq, match_ms = data.seq, round(r.compute_s * 1000, 3)
        if faults.active(stamp):
            pose = None if faults.drop_pose else pose
            height = None if faults.drop_height else height
        step = self.core.counters.imu_steps + 1  # the step it enters at (the daemon's count)
        row3 = self.core.laser_step(
            pose, height, t_ns=stamp, degenerate=degenerate, arrival_ns=t_ns
        )
        if row3 is not None:
            self.t3.write_row(row3)
        self.events.write(
            schema.Scan(
                t_ns=stamp,
                index=None if row3 is None else row3.index,
                step=step,
                seq=seq,
                valid=pose is not None,
                got_ns=t_ns,
                x_m=None if pose is None else pose.x_m,
                y_m=None if pose is None else pose.y_m,
                yaw_rad=None if pose is None else pose.yaw_rad,
                height_m=height,
                degenerate=degenerate,
                match_ms=match_ms,
            )
        )

    def log_step(self, t_ns: int, out: ImuStepOutput, imu: ImuSample) -> None:
        """The tables and what they do not hold (SPEC §6): height, gas, battery, phase."""
        command = out.command
        self.t4.write_row(out.row)
        sp = self.core.active_setpoint
        self.events.write(
            schema.Step(
                t_ns=t_ns,
                x_m=round(out.estimate.x_m, 4),
                y_m=round(out.estimate.y_m, 4),
                sp_x_m=None if sp is None else round(sp.x_m, 4),
                sp_y_m=None if sp is None else round(sp.y_m, 4),
                sp_height_m=None if sp is None else round(sp.height_m, 4),
                height_m=round(out.estimate.height_m, 4),
                vz_up_mps=round(out.estimate.vz_up_mps, 4),
                gas_counts=command.gas_counts,
                battery_v=round(imu.battery_v, 2),
                phase=out.phase.name,
                action=out.action.name,
                latency_ms=None,  # lock-step: no wire, no latency
            )
        )
        for e in out.failsafe_events:
            cause = getattr(e.cause, "value", "")
            self.events.write(schema.Failsafe(t_ns=e.t_ns, action=e.action.name, cause=cause))
        for pe in out.phase_events:
            self.events.write(
                schema.PhaseChange(t_ns=pe.t_ns, to=pe.to_phase.name, reason=pe.reason)
            )

    def learned(self) -> dict[str, object]:
        """``FlightCore.learned()`` when the core has it, else nothing."""
        learned = getattr(self.core, "learned", None)
        return dict(learned()) if callable(learned) else {}

    def write_summary(self, log_dir: Path, summary: Mapping[str, Any]) -> None:
        """``flight.json`` again, with ``sim hover``'s summary (``HoverResult.as_dict()``)."""
        typed = schema.from_plain(
            schema.HoverSummary,
            {**summary, "learned": schema.from_plain(schema.Learned, summary["learned"])},
        )
        write_flight_json(log_dir, with_summary(self.info, typed))


__all__ = ["FlightSide", "HoverFaults", "scan_from_raw"]
