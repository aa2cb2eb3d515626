"""``mkflight sim envelope``: the flight judged on many random airframes.

For airframe ``i`` of ``n`` (airframe seed ``seed + i``: ``sim.airframe=random``,
``sim.seed=seed + i``; the flights' noise and gusts are seeded with it too), in parallel
processes, :func:`fly_airframe` flies in lock-step (:func:`mkflight.sim.hover.run_hover`):

1. **defaults**: take off, hold ``hold_s``, land: truth std x / y / z about the set-point,
   every touchdown speed, the end, the failsafes, what the flight learned;
2. **stall**: the same airframe, the laser (pose and height) dead from
   :data:`STALL_AFTER_S` into HOLD to the end: the blind landing's touchdown and its end
   (it must land, never be handed to the pilot in the air);
3. **tuned**: ``mkflight tune`` on flight 1's folder (``identify_flight`` +
   ``tuned_overrides``) and the same flight again with that config;
4. the **oracle** (:mod:`mkflight.sim.oracle`): the same airframe, seed, gusts and hold
   window flown on truth with searched gains.

The verdicts, the pass rates and the reports are :mod:`mkflight.sim.envelope_report`'s;
the figures :mod:`mkflight.sim.envelope_plot`'s. Results are plain data (picklable for
the process pool, JSON for ``--json``).
"""

from __future__ import annotations

import math
import os
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Final

from mkflight.config import Config, load_config
from mkflight.sim.airframe import draw_airframe
from mkflight.sim.oracle import DEFAULT_EVALUATIONS, MIN_SETTLE_S, search_oracle

TAKEOFF_S: Final = 8.0  # flight time allowed before the hold: handshake, climb, settle
STALL_AFTER_S: Final = 10.0  # the laser stall, this long into HOLD
STALL_LAND_S: Final = 30.0  # the stall flight asks to land this long after the stall
MIN_HOLD_S: Final = 5.0


@dataclass(frozen=True, slots=True)
class EnvelopeJob:
    """One airframe's work, sent to a worker process (plain values only)."""

    index: int
    seed: int
    hold_s: float
    config_path: str | None
    overrides: tuple[str, ...]
    folder: str  # this airframe's flight folders go under it
    oracle_evaluations: int = DEFAULT_EVALUATIONS


@dataclass(slots=True)
class FlightFigures:
    """What one simulated flight showed (truth), or why it could not be flown."""

    name: str
    std_x_m: float = math.nan
    std_y_m: float = math.nan
    std_z_m: float = math.nan
    hold_s: float = 0.0
    touchdowns_mps: list[float] = field(default_factory=list)
    end: str = "error"
    failsafes: list[str] = field(default_factory=list)
    learned: dict[str, object] = field(default_factory=dict)
    log_dir: str = ""
    wall_s: float = 0.0
    error: str | None = None  # the flight raised: this airframe fails what it had to show


@dataclass(slots=True)
class OracleFigures:
    """The oracle's result for one airframe (:class:`mkflight.sim.oracle.OracleResult`)."""

    std_x_m: float = math.nan
    std_y_m: float = math.nan
    gains: dict[str, float] = field(default_factory=dict)
    start_std_x_m: float = math.nan
    start_std_y_m: float = math.nan
    evaluations: int = 0
    wall_s: float = 0.0
    error: str | None = None


@dataclass(slots=True)
class AirframeRun:
    """Everything flown on one airframe."""

    index: int
    seed: int
    drawn: dict[str, float]
    defaults: FlightFigures
    stall: FlightFigures
    tuned: FlightFigures
    oracle: OracleFigures
    tuned_overrides: list[str] = field(default_factory=list)
    wall_s: float = 0.0

    def as_dict(self) -> dict[str, object]:
        """Plain values (JSON)."""
        return {k: _finite(v) for k, v in asdict(self).items()}


def _finite(obj: object) -> object:
    """``obj`` with NaN/inf floats as None and floats rounded (strict JSON)."""
    if isinstance(obj, float):
        return round(obj, 6) if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def airframe_config(job: EnvelopeJob, extra: Sequence[str] = ()) -> Config:
    """The configuration of ``job``'s airframe: the user's, a random airframe, ``extra``."""
    overrides = [*job.overrides, "sim.airframe=random", f"sim.seed={job.seed}", *extra]
    return load_config(job.config_path, overrides)


def _error(err: BaseException) -> str:
    """One line naming an exception and where it came from (the last frame)."""
    frames = traceback.extract_tb(err.__traceback__)
    where = f" at {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
    return f"{type(err).__name__}: {err}{where}"


def _fly(
    name: str,
    cfg: Config,
    *,
    duration_s: float,
    seed: int,
    log_dir: Path,
    stall_from_s: float | None = None,
) -> FlightFigures:
    """One lock-step flight, its figures from truth; an exception becomes ``error``."""
    from mkflight.sim.hover import HoverFaults, run_hover

    wall0 = time.perf_counter()
    faults = (
        None
        if stall_from_s is None
        else HoverFaults(from_s=stall_from_s, drop_pose=True, drop_height=True)
    )
    try:
        r = run_hover(cfg, duration_s=duration_s, seed=seed, log_dir=log_dir, faults=faults)
    except Exception as err:
        return FlightFigures(
            name, log_dir=str(log_dir), wall_s=time.perf_counter() - wall0, error=_error(err)
        )
    return FlightFigures(
        name,
        std_x_m=r.std_x_m,
        std_y_m=r.std_y_m,
        std_z_m=r.std_z_m,
        hold_s=r.hold_s,
        touchdowns_mps=[float(v) for v in r.touchdowns_mps],
        end=r.end,
        failsafes=list(r.failsafes),
        learned=dict(r.learned),
        log_dir=str(log_dir),
        wall_s=time.perf_counter() - wall0,
    )


def _tune(job: EnvelopeJob, log_dir: str) -> list[str]:
    """``mkflight tune`` on a flight folder: the overrides for this airframe."""
    from mkflight.analysis.identify import identify_flight
    from mkflight.analysis.tune import tuned_overrides

    cfg = airframe_config(job)
    return list(tuned_overrides(identify_flight(log_dir), cfg))


def hold_window(duration_s: float, hold_s: float) -> tuple[float, float]:
    """``(start_s, length_s)`` of a flight's measured hold: it ends at ``duration_s``.

    ``run_hover`` measures from settling in HOLD until the land request at
    ``duration_s``; ``hold_s`` is the measured length. Without one (the flight never held),
    the nominal window after :data:`TAKEOFF_S`.
    """
    if hold_s >= MIN_HOLD_S:
        return max(duration_s - hold_s, MIN_SETTLE_S), hold_s
    return TAKEOFF_S, max(duration_s - TAKEOFF_S, MIN_HOLD_S)


def _oracle(
    job: EnvelopeJob, cfg: Config, defaults: FlightFigures, duration_s: float
) -> OracleFigures:
    """The oracle on the flight's airframe, seed, gusts and hold window."""
    from mkflight.sim.airframe import airframe_from_config
    from mkflight.sim.hover import gust_seed_for

    start_s, length_s = hold_window(duration_s, defaults.hold_s)
    try:
        r = search_oracle(
            airframe_from_config(cfg.sim),
            seed=job.seed,
            gust_seed=gust_seed_for(job.seed),
            hold_s=length_s,
            settle_s=start_s,
            max_evaluations=job.oracle_evaluations,
        )
    except Exception as err:
        return OracleFigures(error=_error(err))
    return OracleFigures(
        std_x_m=r.std_x_m,
        std_y_m=r.std_y_m,
        gains=dict(
            zip(
                ("kp_xy", "ki_xy", "kp_vxy", "ki_vxy", "kd_vxy"),
                r.best.gains.as_tuple(),
                strict=True,
            )
        ),
        start_std_x_m=r.start.std_x_m,
        start_std_y_m=r.start.std_y_m,
        evaluations=r.evaluations,
        wall_s=r.wall_s,
    )


def fly_airframe(job: EnvelopeJob) -> AirframeRun:
    """Fly one airframe: defaults, laser stall, tuned, oracle (runs in a worker process)."""
    wall0 = time.perf_counter()
    root = Path(job.folder)
    cfg = airframe_config(job)
    duration_s = TAKEOFF_S + job.hold_s
    defaults = _fly(
        "defaults", cfg, duration_s=duration_s, seed=job.seed, log_dir=root / "defaults"
    )
    hold_start_s = duration_s - defaults.hold_s - _settle_s() if defaults.hold_s > 0 else TAKEOFF_S
    stall_s = hold_start_s + STALL_AFTER_S
    stall = _fly(
        "stall",
        cfg,
        duration_s=stall_s + STALL_LAND_S,
        seed=job.seed,
        log_dir=root / "stall",
        stall_from_s=stall_s,
    )
    overrides: list[str] = []
    if defaults.error is not None:
        tuned = FlightFigures("tuned", error="not tuned: the defaults flight failed")
    else:
        try:
            overrides = _tune(job, defaults.log_dir)
        except Exception as err:
            tuned = FlightFigures("tuned", error=f"tune: {_error(err)}")
        else:
            try:
                tuned_cfg = airframe_config(job, overrides)
            except Exception as err:
                tuned = FlightFigures("tuned", error=f"tuned config: {_error(err)}")
            else:
                tuned = _fly(
                    "tuned", tuned_cfg, duration_s=duration_s, seed=job.seed, log_dir=root / "tuned"
                )
    oracle = _oracle(job, cfg, defaults, duration_s)
    return AirframeRun(
        index=job.index,
        seed=job.seed,
        drawn=dict(draw_airframe(job.seed).drawn),
        defaults=defaults,
        stall=stall,
        tuned=tuned,
        oracle=oracle,
        tuned_overrides=overrides,
        wall_s=time.perf_counter() - wall0,
    )


def _settle_s() -> float:
    """How long ``run_hover`` lets HOLD settle before it measures (its ``SETTLE_S``)."""
    from mkflight.sim.hover import SETTLE_S

    return float(SETTLE_S)


def default_jobs() -> int:
    """Worker processes by default: one per CPU."""
    return max(os.cpu_count() or 1, 1)


def envelope_jobs(
    *,
    n: int,
    seed: int,
    hold_s: float,
    folder: Path,
    config_path: str | None = None,
    overrides: Sequence[str] = (),
    oracle_evaluations: int = DEFAULT_EVALUATIONS,
) -> list[EnvelopeJob]:
    """The ``n`` airframes' jobs: seeds ``seed .. seed + n - 1``, folders ``folder/seed-S``."""
    return [
        EnvelopeJob(
            index=i,
            seed=seed + i,
            hold_s=hold_s,
            config_path=config_path,
            overrides=tuple(overrides),
            folder=str(folder / f"seed-{seed + i}"),
            oracle_evaluations=oracle_evaluations,
        )
        for i in range(n)
    ]


def run_envelope(
    jobs: Sequence[EnvelopeJob],
    *,
    workers: int,
    on_done: Callable[[AirframeRun], None] | None = None,
) -> list[AirframeRun]:
    """Fly every job, ``workers`` at a time in processes (1: in this process); by index."""
    runs: list[AirframeRun] = []
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            run = fly_airframe(job)
            runs.append(run)
            if on_done is not None:
                on_done(run)
    else:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
            futures: list[Future[AirframeRun]] = [pool.submit(fly_airframe, j) for j in jobs]
            for future in as_completed(futures):
                run = future.result()
                runs.append(run)
                if on_done is not None:
                    on_done(run)
    return sorted(runs, key=lambda r: r.index)


__all__ = [
    "AirframeRun",
    "EnvelopeJob",
    "FlightFigures",
    "OracleFigures",
    "envelope_jobs",
    "fly_airframe",
    "run_envelope",
]
