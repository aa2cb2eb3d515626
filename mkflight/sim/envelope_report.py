"""The envelope's verdicts and reports: criteria, pass rates, worst airframes, tables.

Pure: :class:`~mkflight.sim.envelope.AirframeRun` values in, verdicts and text out.

The criteria, what the flight must show on random airframes (:class:`Criteria`):

* **precision** (the defaults flight, the airframe's first flight): std x <= max(0.03 m,
  1.25 x the oracle's std x), the same for y against the oracle's y (the same gusts on
  the same axis), and std z <= 0.01 m; on at least 95 % of the airframes;
* **touchdowns**: every touchdown of every flight (defaults, stall, tuned) <= 0.5 m/s, on
  every airframe;
* **stall**: the laser-stall flight ends "landed" (never "released in the air", never a
  crash), on every airframe;
* **tuned**: the tuned config flies the airframe at least as well as the defaults: each
  of its std x / y / z within that axis's limit or no more than 10 % above the defaults'
  (run-to-run noise), on at least 95 % of the airframes.

A flight that raised fails everything it had to show.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Final

import numpy as np

from mkflight.sim.envelope import AirframeRun, FlightFigures

LANDED: Final = "landed"
TUNED_TOLERANCE: Final = 0.10
WORST_COUNT: Final = 5
#: The drawn parameters the text reports show (all of them go to --json).
KEY_PARAMETERS: Final = (
    ("attitude_delay_s", "delay s", 3),
    ("attitude_tau_s", "lag s", 3),
    ("counts_per_rad", "counts/rad", 0),
    ("hover_gas_counts", "hover gas", 0),
    ("vibration_counts", "vibration", 0),
    ("gust_accel_std_mps2", "gusts m/s2", 2),
    ("drag_linear_per_s", "drag /s", 2),
    ("ground_effect", "ground effect", 2),
    ("laser_extra_delay_s", "laser delay s", 3),
)


@dataclass(frozen=True, slots=True)
class Criteria:
    """The envelope's thresholds (m, m/s, shares; the module docstring)."""

    floor_m: float = 0.03
    oracle_factor: float = 1.25
    max_std_z_m: float = 0.01
    max_touchdown_mps: float = 0.5
    precision_share: float = 0.95
    tuned_share: float = 0.95

    def xy_limit_m(self, oracle_m: float) -> float:
        """The std x or y allowed on an airframe whose oracle reached ``oracle_m``."""
        if not math.isfinite(oracle_m):
            return self.floor_m
        return max(self.floor_m, self.oracle_factor * oracle_m)


CRITERIA: Final = Criteria()  # the module docstring's


@dataclass(frozen=True, slots=True)
class Verdict:
    """One airframe against :class:`Criteria`; ``reasons`` says each failure."""

    precision: bool
    touchdowns: bool
    stall_landed: bool
    tuned: bool
    ratio: float  # the larger of std x / oracle x and std y / oracle y (NaN if unknown)
    reasons: tuple[str, ...]

    @property
    def passed(self) -> bool:
        """Precision, touchdowns, stall landed, and the tuned flight's criterion."""
        return self.precision and self.touchdowns and self.stall_landed and self.tuned


def _ok(value: float, limit: float) -> bool:
    return math.isfinite(value) and value <= limit


def judge(
    *,
    std_m: tuple[float, float, float],
    oracle_m: tuple[float, float],
    touchdowns_mps: Sequence[float],
    stall_end: str,
    tuned_std_m: tuple[float, float, float] | None,
    errors: Sequence[str] = (),
    criteria: Criteria = Criteria(),
) -> Verdict:
    """Judge one airframe from plain figures (pure; the unit tests' entry point).

    Args:
        std_m: the defaults flight's truth std (x, y, z), m.
        oracle_m: the oracle's std (x, y), m (NaN: no oracle, the floor applies).
        touchdowns_mps: every touchdown speed of every flight, m/s.
        stall_end: the laser-stall flight's end ("landed", "released in the air", ...).
        tuned_std_m: the tuned flight's std (x, y, z), or None if it was not flown.
        errors: flights that raised, one line each (each a failure reason).
        criteria: the thresholds.
    """
    reasons: list[str] = list(errors)
    sx, sy, _ = std_m
    lim_x, lim_y = criteria.xy_limit_m(oracle_m[0]), criteria.xy_limit_m(oracle_m[1])
    limits = (lim_x, lim_y, criteria.max_std_z_m)
    precision = True
    for axis, value, limit in zip("xyz", std_m, limits, strict=True):
        if not _ok(value, limit):
            precision = False
            reasons.append(f"std {axis} {value:.4f} m > {limit:.4f} m")
    hard = [v for v in touchdowns_mps if not _ok(v, criteria.max_touchdown_mps)]
    touchdowns = not hard
    if hard:
        listed = ", ".join(f"{v:.2f}" for v in hard)
        reasons.append(f"touchdown {listed} m/s > {criteria.max_touchdown_mps} m/s")
    stall_landed = stall_end == LANDED
    if not stall_landed:
        reasons.append(f"laser stall: {stall_end}")
    tuned = tuned_std_m is not None
    if tuned_std_m is None:
        reasons.append("tuned flight not flown")
    else:
        for axis, value, default, limit in zip("xyz", tuned_std_m, std_m, limits, strict=True):
            bound = (
                max(limit, default * (1.0 + TUNED_TOLERANCE)) if math.isfinite(default) else limit
            )
            if not _ok(value, bound):
                tuned = False
                reasons.append(f"tuned std {axis} {value:.4f} m > {bound:.4f} m")
    ratios = [s / o for s, o in ((sx, oracle_m[0]), (sy, oracle_m[1])) if o > 0]
    ratio = max(ratios) if ratios and all(math.isfinite(r) for r in ratios) else math.nan
    if errors:
        precision = touchdowns = stall_landed = tuned = False
    return Verdict(precision, touchdowns, stall_landed, tuned, ratio, tuple(reasons))


def _std3(f: FlightFigures) -> tuple[float, float, float]:
    return (f.std_x_m, f.std_y_m, f.std_z_m)


def all_touchdowns(run: AirframeRun) -> list[float]:
    """Every touchdown of every flight of ``run`` (m/s)."""
    return [*run.defaults.touchdowns_mps, *run.stall.touchdowns_mps, *run.tuned.touchdowns_mps]


def judge_run(run: AirframeRun, criteria: Criteria = Criteria()) -> Verdict:
    """Judge one :class:`AirframeRun`."""
    errors = [
        f"{f.name} flight: {f.error}" for f in (run.defaults, run.stall) if f.error is not None
    ]
    if run.oracle.error is not None:
        errors.append(f"oracle: {run.oracle.error}")
    tuned = None if run.tuned.error is not None else _std3(run.tuned)
    verdict = judge(
        std_m=_std3(run.defaults),
        oracle_m=(run.oracle.std_x_m, run.oracle.std_y_m),
        touchdowns_mps=all_touchdowns(run),
        stall_end=run.stall.end,
        tuned_std_m=tuned,
        errors=errors,
        criteria=criteria,
    )
    if run.tuned.error is not None:
        reasons = tuple(r for r in verdict.reasons if r != "tuned flight not flown")
        verdict = Verdict(
            verdict.precision,
            verdict.touchdowns,
            verdict.stall_landed,
            False,
            verdict.ratio,
            (*reasons, f"tuned: {run.tuned.error}"),
        )
    return verdict


@dataclass(frozen=True, slots=True)
class Summary:
    """The envelope's pass rates and whether its criteria hold."""

    n: int
    precision_pass: int
    touchdown_pass: int
    stall_pass: int
    tuned_pass: int
    ok: bool
    failed: tuple[str, ...]  # the criteria that do not hold, said in words


def summarize(verdicts: Sequence[Verdict], criteria: Criteria = Criteria()) -> Summary:
    """Pass counts and the overall verdict (>= 95 % precision and tuned; 100 % the rest)."""
    n = len(verdicts)
    counts = {
        "precision": sum(v.precision for v in verdicts),
        "touchdown": sum(v.touchdowns for v in verdicts),
        "stall": sum(v.stall_landed for v in verdicts),
        "tuned": sum(v.tuned for v in verdicts),
    }
    failed: list[str] = []
    if n == 0:
        failed.append("no airframe flown")
    if counts["precision"] < criteria.precision_share * n - 1e-9:
        failed.append(
            f"precision on {counts['precision']}/{n} airframes (< {criteria.precision_share:.0%})"
        )
    if counts["touchdown"] < n:
        failed.append(
            f"touchdowns > {criteria.max_touchdown_mps} m/s on {n - counts['touchdown']}/{n}"
        )
    if counts["stall"] < n:
        failed.append(f"laser stall not landed on {n - counts['stall']}/{n}")
    if counts["tuned"] < criteria.tuned_share * n - 1e-9:
        failed.append(
            f"tuned config at least as good on {counts['tuned']}/{n} (< {criteria.tuned_share:.0%})"
        )
    return Summary(
        n,
        counts["precision"],
        counts["touchdown"],
        counts["stall"],
        counts["tuned"],
        not failed,
        tuple(failed),
    )


def worst(
    runs: Sequence[AirframeRun], verdicts: Sequence[Verdict], count: int = WORST_COUNT
) -> list[int]:
    """Indexes (into ``runs``) of the ``count`` worst airframes by std / oracle ratio.

    Failures to fly (NaN ratio) come first.
    """

    def key(i: int) -> float:
        r = verdicts[i].ratio
        return -math.inf if not math.isfinite(r) else -r

    return sorted(range(len(runs)), key=key)[:count]


def _pct(values: Sequence[float]) -> dict[str, float | None]:
    a = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"median": None, "p95": None, "max": None}
    return {
        "median": round(float(np.median(a)), 5),
        "p95": round(float(np.percentile(a, 95)), 5),
        "max": round(float(np.max(a)), 5),
    }


def statistics(runs: Sequence[AirframeRun]) -> dict[str, dict[str, float | None]]:
    """Median, p95 and max of the std, the oracle and the touchdown speeds over airframes."""
    return {
        "std_x_m": _pct([r.defaults.std_x_m for r in runs]),
        "std_y_m": _pct([r.defaults.std_y_m for r in runs]),
        "std_z_m": _pct([r.defaults.std_z_m for r in runs]),
        "tuned_std_x_m": _pct([r.tuned.std_x_m for r in runs]),
        "tuned_std_y_m": _pct([r.tuned.std_y_m for r in runs]),
        "tuned_std_z_m": _pct([r.tuned.std_z_m for r in runs]),
        "oracle_x_m": _pct([r.oracle.std_x_m for r in runs]),
        "oracle_y_m": _pct([r.oracle.std_y_m for r in runs]),
        "touchdown_mps": _pct([v for r in runs for v in all_touchdowns(r)]),
        "stall_touchdown_mps": _pct([v for r in runs for v in r.stall.touchdowns_mps]),
    }


def report_dict(
    runs: Sequence[AirframeRun],
    *,
    seed: int,
    hold_s: float,
    wall_s: float,
    criteria: Criteria = Criteria(),
) -> dict[str, object]:
    """The ``--json`` object."""
    verdicts = [judge_run(r, criteria) for r in runs]
    summary = summarize(verdicts, criteria)
    airframes = []
    for run, v in zip(runs, verdicts, strict=True):
        item = run.as_dict()
        item["verdict"] = {**asdict(v), "passed": v.passed, "ratio": _round(v.ratio)}
        airframes.append(item)
    return {
        "n": len(runs),
        "seed": seed,
        "hold_s": hold_s,
        "wall_s": round(wall_s, 1),
        "criteria": asdict(criteria),
        "ok": summary.ok,
        "failed": list(summary.failed),
        "pass": {
            "precision": summary.precision_pass,
            "touchdown": summary.touchdown_pass,
            "stall": summary.stall_pass,
            "tuned": summary.tuned_pass,
        },
        "worst": [runs[i].seed for i in worst(runs, verdicts)],
        "statistics": statistics(runs),
        "airframes": airframes,
    }


def _round(value: float, digits: int = 4) -> float | None:
    return round(value, digits) if math.isfinite(value) else None
