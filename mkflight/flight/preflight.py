"""Pre-flight checks (SPEC §7): nothing takes off unless each passes; each is named when not.

The checks, in order, on links the daemon has already opened:

1. **FC version**: the FlightCtrl answers 'v' (``MkLink.connect``) without a hardware error.
2. **DebugOut rate**: :data:`RATE_SAMPLES` samples arrive with a median interval inside
   :data:`DEBUG_PERIOD_RANGE_S` (the FC's 'd' 5 gives ≈ 53 ms).
3. **level and still**: the FC's angles within :data:`MAX_LEVEL_RAD` (a vehicle on a slope
   or held in a hand would take off sideways).
4. **battery**: above ``safety.warn_voltage_v`` (a pack that already warns does not fly).
5. **laser info**: the URG answers the SCIP 2.0 start-up (``UrgDriver.connect``) and streams.
6. **scan rate**: :data:`RATE_SCANS` scans with a median interval inside
   :data:`SCAN_PERIOD_RANGE_S` (600 rpm: 100 ms).
7. **hat height**: valid on the last scans and below :data:`MAX_GROUND_HEIGHT_M`: the
   vehicle is on the ground (the daemon takes off; it must never start in the air).
8. **scan match**: the matcher has a valid first pose (enough structure in the room).

The log directory and the configuration are checked before any port is opened (the
daemon's own job: a bad config never gets this far).
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import dataclass

from mkflight.conversions import MS_PER_S, NS_PER_MS, NS_PER_S
from mkflight.errors import LinkError, PreflightError
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.matcher_worker import MatcherError, MatcherWorker
from mkflight.mk.link import MkLink
from mkflight.mk.messages import VersionInfo
from mkflight.msgs import ImuSample, Scan
from mkflight.urg.driver import UrgDriver
from mkflight.urg.driver_types import UrgInfo

RATE_SAMPLES = 10
DEBUG_PERIOD_RANGE_S = (0.030, 0.100)
MAX_LEVEL_RAD = 0.15
RATE_SCANS = 6
SCAN_PERIOD_RANGE_S = (0.080, 0.150)
MAX_GROUND_HEIGHT_M = 0.25
ANSWER_TIMEOUT_S = 3.0


@dataclass(frozen=True, slots=True)
class PreflightReport:
    """What the checks measured (printed and kept in ``flight.json``)."""

    fc_version: str
    debug_period_ms: float
    battery_v: float
    pitch_rad: float
    roll_rad: float
    laser: str
    scan_period_ms: float
    ground_height_m: float
    last_sample: ImuSample
    last_scan: Scan
    first_result: LaserResult

    def as_dict(self) -> dict[str, object]:
        """The figures, for ``flight.json`` and the events log."""
        return {
            "fc_version": self.fc_version,
            "debug_period_ms": round(self.debug_period_ms, 2),
            "battery_v": round(self.battery_v, 2),
            "pitch_rad": round(self.pitch_rad, 4),
            "roll_rad": round(self.roll_rad, 4),
            "laser": self.laser,
            "scan_period_ms": round(self.scan_period_ms, 2),
            "ground_height_m": round(self.ground_height_m, 4),
        }


async def check_fc(link: MkLink, warn_voltage_v: float) -> tuple[VersionInfo, list[ImuSample]]:
    """Checks 1-4 on a started link (see the module docstring).

    Raises:
        PreflightError: naming the check that failed.
    """
    try:
        version = await link.connect()
    except LinkError as err:
        raise PreflightError(check="FC version", detail=f"no answer on {link.port}: {err}") from err
    if version.has_hardware_error:
        raise PreflightError(
            check="FC version", detail=f"FlightCtrl {version.text} reports a hardware error"
        )
    link.subscribe()
    samples: list[ImuSample] = []
    try:
        while len(samples) < RATE_SAMPLES:
            samples.append(await link.next_sample(ANSWER_TIMEOUT_S))
    except LinkError as err:
        got = len(samples)
        msg = f"{got} of {RATE_SAMPLES} DebugOut samples from {link.port}: {err}"
        raise PreflightError(check="DebugOut rate", detail=msg) from err
    period_s = statistics.median(
        (b.t_ns - a.t_ns) / NS_PER_S for a, b in itertools.pairwise(samples)
    )
    lo, hi = DEBUG_PERIOD_RANGE_S
    if not lo <= period_s <= hi:
        msg = (
            f"median interval {period_s * MS_PER_S:.1f} ms, "
            f"expected {lo * MS_PER_S:g}-{hi * MS_PER_S:g}"
        )
        raise PreflightError(check="DebugOut rate", detail=msg)
    last = samples[-1]
    if not (abs(last.pitch_rad) <= MAX_LEVEL_RAD and abs(last.roll_rad) <= MAX_LEVEL_RAD):
        msg = (
            f"pitch {last.pitch_rad:.3f} rad, roll {last.roll_rad:.3f} rad "
            f"(at most {MAX_LEVEL_RAD} rad): put the vehicle down level"
        )
        raise PreflightError(check="level", detail=msg)
    if not (math.isfinite(last.battery_v) and last.battery_v > warn_voltage_v):
        msg = f"{last.battery_v:.2f} V, not above safety.warn_voltage_v {warn_voltage_v:g} V"
        raise PreflightError(check="battery", detail=msg)
    return version, samples


async def check_laser(driver: UrgDriver) -> tuple[UrgInfo, list[Scan]]:
    """Checks 5-6: the URG's start-up and its scan rate.

    Raises:
        PreflightError: naming the check that failed.
    """
    try:
        info = await driver.connect()
        await driver.start_stream()
    except LinkError as err:
        raise PreflightError(check="laser info", detail=f"{driver.port}: {err}") from err
    scans: list[Scan] = []
    try:
        while len(scans) < RATE_SCANS:
            scans.append(await driver.next_scan(ANSWER_TIMEOUT_S))
    except LinkError as err:
        msg = f"{len(scans)} of {RATE_SCANS} scans from {driver.port}: {err}"
        raise PreflightError(check="scan rate", detail=msg) from err
    period_s = statistics.median((b.t_ns - a.t_ns) / NS_PER_S for a, b in itertools.pairwise(scans))
    lo, hi = SCAN_PERIOD_RANGE_S
    if not lo <= period_s <= hi:
        msg = (
            f"median interval {period_s * MS_PER_S:.1f} ms, "
            f"expected {lo * MS_PER_S:g}-{hi * MS_PER_S:g}"
        )
        raise PreflightError(check="scan rate", detail=msg)
    return info, scans


async def check_hat_and_match(
    worker: MatcherWorker, scans: list[Scan], pitch_rad: float, roll_rad: float
) -> LaserResult:
    """Checks 7-8: the hat height is valid and on the ground; the matcher has a pose.

    The scans go through the matcher (its first one fixes the world frame W).

    Raises:
        PreflightError: naming the check that failed.
    """
    result: LaserResult | None = None
    try:
        for scan in scans:
            result = await worker.process(scan, pitch_rad, roll_rad)
    except MatcherError as err:
        raise PreflightError(check="scan match", detail=str(err)) from err
    assert result is not None
    if result.height_m is None:
        raise PreflightError(
            check="hat height", detail=f"no height from the hat: {result.height_reason}"
        )
    if result.height_m > MAX_GROUND_HEIGHT_M:
        msg = (
            f"{result.height_m:.2f} m above the floor (at most {MAX_GROUND_HEIGHT_M} m): "
            "the vehicle must start on the ground"
        )
        raise PreflightError(check="hat height", detail=msg)
    if result.pose is None:
        raise PreflightError(
            check="scan match", detail="no valid pose: too little structure in view"
        )
    return result


def period_ms(times_ns: list[int]) -> float:
    """The median interval of timestamps (ns), in ms; NaN for fewer than two."""
    if len(times_ns) < 2:
        return math.nan
    return statistics.median((b - a) / NS_PER_MS for a, b in itertools.pairwise(times_ns))
