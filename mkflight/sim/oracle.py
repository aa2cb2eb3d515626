"""The oracle: an airframe flown by a PID on its TRUE state, with gains searched.

What the physics allows. The flight is judged against this: the same airframe (its
:class:`~mkflight.sim.vehicle.VehicleParams`), the same gusts (the same ``gust_seed``, so
the same OU turbulence and wind at the same instants) and the same hold window, flown by
a controller that knows everything the flight has to estimate
(:class:`~mkflight.sim.oracle_pilot.TruthPilot`: the flight's horizontal cascade with the
gains under test, on the true state).

The delay (attitude delay + lag, the 53 ms sample-and-hold, the integer counts) and the
gusts stay: no estimator can remove those. :func:`search_oracle` searches the five
horizontal gains for the smallest ``(std x + std y) / 2`` about the set-point over the
hold: a coarse search along a common scale of the gains (:data:`BASE_GAINS` at a
bandwidth guessed from the airframe's delay and lag), then a Nelder-Mead refinement in
log-gain space (scipy). Every evaluation flies the same gusts and the same noise seed, so
the objective is deterministic and the search reproducible.

The simulator never reads the flight code's constants (``cfg.control``, ``cfg.mk``): the
oracle's limits and gains are its own copies of the flight's defaults.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Final

import numpy as np

from mkflight.sim.oracle_pilot import PERIOD_S, TruthPilot
from mkflight.sim.vehicle import VehicleParams, initial_state, step

MIN_SETTLE_S: Final = 3.0  # never judge the first seconds in the air
DEFAULT_SETTLE_S: Final = 5.0
DEFAULT_HEIGHT_M: Final = 0.6
DEFAULT_EVALUATIONS: Final = 40
#: Delay + lag the control defaults were tuned on (§F of the 2011 QUT CyPhy MikroKopter
#: documentation: the MK's ~200 ms attitude response).
NOMINAL_RESPONSE_S: Final = 0.2


@dataclass(frozen=True, slots=True)
class OracleGains:
    """The horizontal cascade's gains, the same meaning as ``control.kp_xy ... kd_vxy``.

    Units: position kp 1/s, ki 1/s²; velocity kp 1/s, ki 1/s², kd dimensionless.
    """

    kp_xy: float
    ki_xy: float
    kp_vxy: float
    ki_vxy: float
    kd_vxy: float

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        """``(kp_xy, ki_xy, kp_vxy, ki_vxy, kd_vxy)``."""
        return (self.kp_xy, self.ki_xy, self.kp_vxy, self.ki_vxy, self.kd_vxy)

    def scaled(self, bandwidth: float) -> OracleGains:
        """The gains of a loop ``bandwidth`` times faster (each gain by its time dimension).

        A PID's gains of ``s^-n`` scale as ``bandwidth^n`` so that the loop keeps its
        shape: position kp by b, ki by b², velocity kp by b, ki by b², kd unchanged.
        """
        b = bandwidth
        return OracleGains(
            self.kp_xy * b, self.ki_xy * b * b, self.kp_vxy * b, self.ki_vxy * b * b, self.kd_vxy
        )


#: The flight's control defaults (config.yaml's control section, copied: the simulator
#: never reads the flight's config). The search reports them as its reference flight.
START_GAINS: Final = OracleGains(kp_xy=2.8, ki_xy=0.05, kp_vxy=5.1, ki_vxy=0.46, kd_vxy=1.1)
#: Where the search starts (scaled to the airframe): the best gains of a 200-evaluation
#: search on the nominal airframe (0.1 s delay + 0.1 s lag) in 0.2 m/s² gusts. On random
#: airframes a 40-evaluation search from here ends within ~2 % of a 150-evaluation one
#: (from the defaults: 15-40 % above it).
BASE_GAINS: Final = OracleGains(kp_xy=8.0, ki_xy=0.25, kp_vxy=7.5, ki_vxy=0.5, kd_vxy=1.5)
COARSE_FACTORS: Final = (0.75, 1.0, 1.3)  # around the bandwidth guess
SIMPLEX_STEP: Final = 0.3  # Nelder-Mead's first steps, in log-gain (x 1.35)


@dataclass(frozen=True, slots=True)
class OracleFlight:
    """One oracle flight: truth std about the set-point over the hold window (m)."""

    gains: OracleGains
    std_x_m: float
    std_y_m: float
    std_z_m: float
    samples: int

    @property
    def objective_m(self) -> float:
        """What the search minimises: the mean of the x and y std (m); inf if none/NaN."""
        value = 0.5 * (self.std_x_m + self.std_y_m)
        return value if math.isfinite(value) and self.samples > 0 else math.inf


@dataclass(frozen=True, slots=True)
class OracleResult:
    """The best oracle flight found, the starting gains' flight and the search's cost."""

    best: OracleFlight
    start: OracleFlight
    evaluations: int
    wall_s: float

    @property
    def std_x_m(self) -> float:
        """The best flight's std x (m)."""
        return self.best.std_x_m

    @property
    def std_y_m(self) -> float:
        """The best flight's std y (m)."""
        return self.best.std_y_m

    def as_dict(self) -> dict[str, object]:
        """Plain values for reports."""
        return {
            "std_x_m": round(self.best.std_x_m, 5),
            "std_y_m": round(self.best.std_y_m, 5),
            "std_z_m": round(self.best.std_z_m, 5),
            "gains": {k: round(v, 4) for k, v in _gain_items(self.best.gains)},
            "start_std_x_m": round(self.start.std_x_m, 5),
            "start_std_y_m": round(self.start.std_y_m, 5),
            "evaluations": self.evaluations,
            "wall_s": round(self.wall_s, 2),
        }


def _gain_items(g: OracleGains) -> list[tuple[str, float]]:
    names = ("kp_xy", "ki_xy", "kp_vxy", "ki_vxy", "kd_vxy")
    return list(zip(names, g.as_tuple(), strict=True))


def fly_oracle(
    params: VehicleParams,
    gains: OracleGains,
    *,
    seed: int,
    gust_seed: int,
    hold_s: float,
    settle_s: float = DEFAULT_SETTLE_S,
    height_m: float = DEFAULT_HEIGHT_M,
) -> OracleFlight:
    """Fly ``params`` with ``gains`` on truth and measure the std over ``[settle, settle+hold)``.

    The vehicle starts hovering at (0, 0, ``height_m``) at t = 0, with the set-point there;
    ``settle_s`` is the flight time at which the measured window starts (use the flight's
    own window start so that both see the same gusts at the same instants).

    Args:
        params: the airframe (its true constants; the oracle knows them).
        gains: the horizontal cascade's gains.
        seed: seeds the vehicle's random generator (as the flight's ``seed`` does).
        gust_seed: the gusts' seed: the same as the flight compared with.
        hold_s: length of the measured window (s).
        settle_s: start of the measured window (s, >= :data:`MIN_SETTLE_S`).
        height_m: hover height (m).

    Raises:
        ValueError: a non-positive hold, a settle shorter than :data:`MIN_SETTLE_S`, or a
            height <= 0.
    """
    if not (hold_s > 0 and settle_s >= MIN_SETTLE_S and height_m > 0):
        msg = (
            f"oracle: need hold_s > 0, settle_s >= {MIN_SETTLE_S} and height_m > 0, got "
            f"{hold_s}, {settle_s}, {height_m}"
        )
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    state = initial_state(params, rng, pos_w_m=(0.0, 0.0, -height_m), gust_seed=gust_seed)
    pilot = TruthPilot(params, gains.as_tuple(), height_m, state.vel_w_mps)
    start_n = math.ceil(settle_s / PERIOD_S - 1e-9)
    end_n = start_n + round(hold_s / PERIOD_S)
    ex: list[float] = []
    ey: list[float] = []
    ez: list[float] = []
    for n in range(end_n):
        if n >= start_n:
            x, y, z = state.pos_w_m
            ex.append(x)
            ey.append(y)
            ez.append(-z - height_m)
        state = step(state, pilot.sticks(state), PERIOD_S, params, rng)
    return OracleFlight(gains, _std(ex), _std(ey), _std(ez), len(ex))


def _std(values: list[float]) -> float:
    if not values:
        return math.nan
    return float(np.std(np.asarray(values)))


def guess_bandwidth(params: VehicleParams) -> float:
    """A starting scale of :data:`BASE_GAINS` for this airframe: nominal response / its own.

    The defaults suit a 0.1 s delay + 0.1 s lag (§F); a loop around a slower response
    must be slower by about the same factor (a delay's phase lag grows with frequency).
    """
    response_s = params.attitude_delay_s + params.attitude_tau_s
    return NOMINAL_RESPONSE_S / max(response_s, 1e-3)


def search_oracle(
    params: VehicleParams,
    *,
    seed: int,
    gust_seed: int,
    hold_s: float,
    settle_s: float = DEFAULT_SETTLE_S,
    height_m: float = DEFAULT_HEIGHT_M,
    max_evaluations: int = DEFAULT_EVALUATIONS,
) -> OracleResult:
    """Search the horizontal gains for the smallest ``(std x + std y) / 2`` on this airframe.

    1. :data:`START_GAINS` (the flight's defaults) as they are: the reference;
    2. coarse: :data:`BASE_GAINS` scaled (:meth:`OracleGains.scaled`) to
       :data:`COARSE_FACTORS` times :func:`guess_bandwidth`, the best of all kept;
    3. local: Nelder-Mead on the log of the five gains from there (first steps
       :data:`SIMPLEX_STEP`), within the remaining evaluations (``max_evaluations`` in
       all, at least the four above).

    Every evaluation is :func:`fly_oracle` with the same ``seed``, ``gust_seed`` and
    window: a deterministic objective. The result is never worse than the defaults.
    A 60 s hold costs ~0.2 s an evaluation on this machine: ~8 s for the default 40.
    """
    from scipy.optimize import minimize

    wall0 = time.perf_counter()
    cache: dict[tuple[float, ...], OracleFlight] = {}

    def fly(gains: OracleGains) -> OracleFlight:
        key = tuple(round(v, 9) for v in gains.as_tuple())
        if key not in cache:
            cache[key] = fly_oracle(
                params,
                gains,
                seed=seed,
                gust_seed=gust_seed,
                hold_s=hold_s,
                settle_s=settle_s,
                height_m=height_m,
            )
        return cache[key]

    start = fly(START_GAINS)
    best = start
    guess = guess_bandwidth(params)
    for factor in COARSE_FACTORS:
        flight = fly(BASE_GAINS.scaled(guess * factor))
        if flight.objective_m < best.objective_m:
            best = flight
    budget = max_evaluations - len(cache)
    if budget > 0:
        x0 = np.log(np.asarray(best.gains.as_tuple()))

        def objective(logs: np.ndarray) -> float:
            if len(cache) >= max_evaluations:
                return math.inf
            values = np.exp(np.clip(logs, -8.0, 5.0))
            return fly(OracleGains(*(float(v) for v in values))).objective_m

        simplex = np.vstack([x0, x0 + np.diag(np.full(5, SIMPLEX_STEP))])
        minimize(
            objective,
            x0,
            method="Nelder-Mead",
            options={"maxfev": budget, "initial_simplex": simplex, "xatol": 0.02, "fatol": 1e-5},
        )
        best = min(cache.values(), key=lambda f: f.objective_m)
    return OracleResult(
        best=best, start=start, evaluations=len(cache), wall_s=time.perf_counter() - wall0
    )


__all__ = [
    "BASE_GAINS",
    "START_GAINS",
    "OracleFlight",
    "OracleGains",
    "OracleResult",
    "fly_oracle",
    "guess_bandwidth",
    "search_oracle",
]
