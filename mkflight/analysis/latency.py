"""The vehicle's response lag by cross-correlation of command and response (§F, Fig 8).

§ and Fig are those of the 2011 QUT CyPhy MikroKopter documentation. It correlates the
body-frame velocity with the pitch and reads a peak at about 4 steps of 50 ms: "the MK
responds 200 ms later". Its vehicle model (and ours, SPEC §8) is a pure delay d followed by
a first-order lag τ from the commanded to the flown tilt; for a command that varies slowly
against τ that is a delay of d + τ, the **response lag** this module estimates (measured on
the simulator flown with ``--excite 0.2``: d + τ = 0.15, 0.2, 0.3, 0.35 s with τ ≤ 0.1 s are
read within a step; a long lag against the closed loop's commands reads short: d = 0.1, τ =
0.2 s reads 0.23 s, because those commands are not slow against τ). Three curves, each the
x/y mean of the normalised cross-correlation r[k] = corr(drive[t], response[t + k]) for k =
0..``max_lag`` steps:

* **acceleration** (the lag reported): the body-frame velocity of the laser (TABLE III
  ``B_Vel.x``/``B_Vel.y``) differenced to an acceleration. Tilt makes acceleration
  (a = g·tilt), so the acceleration follows the command by the response lag. Correlating
  the velocity itself (Fig 8 literally) adds the integration: a command held
  for a while keeps pushing the velocity, and that curve peaks later the longer the
  commands dwell — it is kept as ``velocity``, but it is not the lag.
* **attitude**: the FC's own angles (TABLE IV ``AnglePitch``/``AngleRoll``) against the
  commanded angle: the attitude loop alone, without the laser.
* **velocity**: the Fig 8 curve as it is.

Signs (SPEC §1, §4): our pitch command is θ* = -ControlPitch/k and it asks for a_x = -g·θ*,
so the x drive is ``+ControlPitch`` (attitude: ``-ControlPitch`` against θ); our roll
command is φ* = -ControlRoll/k asking for a_y = +g·φ*, so the y drive is ``-ControlRoll``
(attitude: ``-ControlRoll`` against φ). A positive r at lag k: the response moves the way
the command pushed it k steps later.

Times: the TABLE IV rows' (the ``step`` events) and the TABLE III rows' scan times (the
``scan`` events; else ``(index - 1) x 100 ms``). A laser velocity is the difference of two
poses one scan apart, so it is the velocity half a scan period before its row; an
acceleration from two of those is one scan period before. Responses are resampled to the
TABLE IV rows by nearest time, and the peak is refined to a fraction of a step by a
parabola through it and its neighbours.

A calm closed-loop hover has little excitation (peak r below :data:`WEAK_PEAK_R`): fly a
set-point square wave (``sim hover --excite 0.2``) or stick inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mkflight.analysis.precision import AnalysisInputError

IMU_PERIOD_S = 0.05
LASER_PERIOD_S = 0.1
MAX_LAG_STEPS = 20
SEED_LAG_STEPS = 4
"""The original system's response lag, Fig 8: ≈ 4 steps = 200 ms."""
WEAK_PEAK_R = 0.3
"""A peak below this is weak: the flight had too little excitation (e.g. a calm hover)."""

FloatArray = npt.NDArray[np.float64]


def lagged_correlation(command: FloatArray, response: FloatArray, max_lag: int) -> FloatArray:
    """Normalised cross-correlation r[k] = corr(command[t], response[t + k]), k = 0..max_lag.

    Each lag's Pearson coefficient over the pairs where both are finite (NaN: invalid); a
    lag with fewer than 3 pairs or no variance gives NaN.

    Raises:
        ValueError: different lengths or a negative ``max_lag``.
    """
    c = np.asarray(command, dtype=np.float64)
    v = np.asarray(response, dtype=np.float64)
    if c.shape != v.shape or c.ndim != 1:
        msg = f"command and response must be 1-D of one length, got {c.shape} and {v.shape}"
        raise ValueError(msg)
    if max_lag < 0:
        msg = f"max_lag must be >= 0, got {max_lag}"
        raise ValueError(msg)
    n = len(c)
    curve = np.full(max_lag + 1, np.nan)
    for k in range(min(max_lag, n - 1) + 1):
        a, b = c[: n - k], v[k:]
        ok = np.isfinite(a) & np.isfinite(b)
        if np.count_nonzero(ok) < 3:
            continue
        a0, b0 = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
        den = math.sqrt(float(np.dot(a0, a0)) * float(np.dot(b0, b0)))
        if den > 0:
            curve[k] = float(np.dot(a0, b0)) / den
    return curve


def peak_lag(curve: FloatArray) -> int:
    """The lag (steps) of the curve's largest finite value.

    Raises:
        AnalysisInputError: no finite value (no motion in the log, or too few rows).
    """
    if not np.any(np.isfinite(curve)):
        msg = "no correlation: the commands or responses do not vary (or too few rows)"
        raise AnalysisInputError(msg)
    return int(np.nanargmax(curve))


def refine_peak(curve: FloatArray, k: int) -> float:
    """The peak's lag to a fraction of a step: the vertex of the parabola through k-1, k, k+1.

    ``k`` itself when a neighbour is missing or the three points are not a maximum.
    """
    if k <= 0 or k >= len(curve) - 1:
        return float(k)
    a, b, c = float(curve[k - 1]), float(curve[k]), float(curve[k + 1])
    den = a - 2.0 * b + c
    if not (math.isfinite(a) and math.isfinite(c)) or den >= 0:
        return float(k)
    return k + max(-0.5, min(0.5, 0.5 * (a - c) / den))


def resample_nearest(
    t_from_s: FloatArray, values: FloatArray, t_to_s: FloatArray, tolerance_s: float
) -> FloatArray:
    """``values`` at the times ``t_to_s``, nearest in time (NaN if none within tolerance)."""
    if len(t_from_s) == 0:
        return np.full(len(t_to_s), np.nan)
    right = np.clip(np.searchsorted(t_from_s, t_to_s), 0, len(t_from_s) - 1)
    left = np.clip(right - 1, 0, len(t_from_s) - 1)
    near = np.where(
        np.abs(t_from_s[left] - t_to_s) <= np.abs(t_from_s[right] - t_to_s), left, right
    )
    out = values[near].astype(np.float64)
    out[np.abs(t_from_s[near] - t_to_s) > tolerance_s] = np.nan
    return out


def acceleration_from_velocity(
    t_s: FloatArray, vel_mps: FloatArray, period_s: float
) -> tuple[FloatArray, FloatArray]:
    """(times, accelerations) from laser velocities stamped at their scan's time.

    Each velocity belongs half a scan period before its row; the difference of two
    consecutive ones belongs midway between those. Pairs further apart than 1.5 periods
    (a skipped scan) are dropped.
    """
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(vel_mps, dtype=np.float64)
    dt = np.diff(t)
    ok = (dt > 0) & (dt <= 1.5 * period_s)
    acc = np.diff(v)[ok] / dt[ok]
    t_mid = 0.5 * (t[:-1] + t[1:])[ok] - 0.5 * period_s
    return t_mid, acc


@dataclass(frozen=True, slots=True)
class LagCurve:
    """One response's correlation: the x/y mean curve, the per-axis ones and the peak."""

    curve: FloatArray
    curve_x: FloatArray
    curve_y: FloatArray
    lag_steps: int
    lag_fine_steps: float
    lag_x_steps: int | None
    lag_y_steps: int | None

    @property
    def peak_r(self) -> float:
        """The correlation at the peak (below :data:`WEAK_PEAK_R`: a weak, unreliable lag)."""
        return float(self.curve[self.lag_steps])

    def as_dict(self, period_s: float) -> dict[str, object]:
        """JSON-ready (NaN in a curve becomes ``null``)."""

        def clean(a: FloatArray) -> list[float | None]:
            return [round(float(x), 4) if math.isfinite(x) else None for x in a]

        return {
            "lag_steps": self.lag_steps,
            "lag_s": round(self.lag_fine_steps * period_s, 4),
            "peak_r": round(self.peak_r, 4),
            "lag_x_steps": self.lag_x_steps,
            "lag_y_steps": self.lag_y_steps,
            "curve": clean(self.curve),
            "curve_x": clean(self.curve_x),
            "curve_y": clean(self.curve_y),
        }


def _peak_or_none(curve: FloatArray) -> int | None:
    return int(np.nanargmax(curve)) if np.any(np.isfinite(curve)) else None


def lag_curve(
    drive_x: FloatArray, resp_x: FloatArray, drive_y: FloatArray, resp_y: FloatArray, max_lag: int
) -> LagCurve:
    """The x and y correlations, their mean (over the axes that have one) and its peak.

    Raises:
        AnalysisInputError: no finite correlation on either axis.
    """
    cx = lagged_correlation(drive_x, resp_x, max_lag)
    cy = lagged_correlation(drive_y, resp_y, max_lag)
    both = np.vstack([cx, cy])
    counts = np.sum(np.isfinite(both), axis=0)
    sums = np.nansum(both, axis=0)
    mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    lag = peak_lag(mean)
    return LagCurve(
        curve=mean,
        curve_x=cx,
        curve_y=cy,
        lag_steps=lag,
        lag_fine_steps=refine_peak(mean, lag),
        lag_x_steps=_peak_or_none(cx),
        lag_y_steps=_peak_or_none(cy),
    )


@dataclass(frozen=True, slots=True)
class Latency:
    """The response lag (acceleration curve) and the attitude and velocity curves."""

    acceleration: LagCurve
    attitude: LagCurve | None
    velocity: LagCurve | None
    samples: int
    period_s: float = IMU_PERIOD_S

    @property
    def lag_steps(self) -> int:
        """The response lag in whole steps (the acceleration curve's peak)."""
        return self.acceleration.lag_steps

    @property
    def lag_s(self) -> float:
        """The response lag in seconds (refined peak x the median step period)."""
        return self.acceleration.lag_fine_steps * self.period_s

    @property
    def peak_r(self) -> float:
        """The acceleration curve's correlation at its peak."""
        return self.acceleration.peak_r

    def as_dict(self) -> dict[str, object]:
        """The ``--json`` object: the lag, then each curve's own figures."""
        return {
            "lag_steps": self.lag_steps,
            "lag_s": round(self.lag_s, 4),
            "peak_r": round(self.peak_r, 4),
            "period_s": round(self.period_s, 6),
            "samples": self.samples,
            "acceleration": self.acceleration.as_dict(self.period_s),
            "attitude": None if self.attitude is None else self.attitude.as_dict(self.period_s),
            "velocity": None if self.velocity is None else self.velocity.as_dict(self.period_s),
        }


def _curve_or_none(
    drive_x: FloatArray, resp_x: FloatArray, drive_y: FloatArray, resp_y: FloatArray, max_lag: int
) -> LagCurve | None:
    """:func:`lag_curve`, or None when neither axis correlates (no data or no variance)."""
    try:
        return lag_curve(drive_x, resp_x, drive_y, resp_y, max_lag)
    except AnalysisInputError:
        return None


def estimate_latency(
    *,
    t4_s: FloatArray,
    control_pitch_counts: FloatArray,
    control_roll_counts: FloatArray,
    t3_s: FloatArray,
    b_vel_x_mps: FloatArray,
    b_vel_y_mps: FloatArray,
    angle_pitch_rad: FloatArray | None = None,
    angle_roll_rad: FloatArray | None = None,
    max_lag: int = MAX_LAG_STEPS,
) -> Latency:
    """The response lag from TABLE IV and TABLE III columns and their rows' times (s).

    ``t3_s`` are the scans' times (see the module doc); the lag in seconds is the refined
    peak times the median TABLE IV period (the FC's DebugOut period is ≈ 53 ms, not 50).

    Raises:
        AnalysisInputError: no finite acceleration correlation on either axis.
    """
    t4 = np.asarray(t4_s, dtype=np.float64)
    t3 = np.asarray(t3_s, dtype=np.float64)
    period_s = float(np.median(np.diff(t4))) if len(t4) > 1 else IMU_PERIOD_S
    scan_s = float(np.median(np.diff(t3))) if len(t3) > 1 else LASER_PERIOD_S
    cp = np.asarray(control_pitch_counts, dtype=np.float64)
    cr = np.asarray(control_roll_counts, dtype=np.float64)
    drive_x, drive_y = cp, -cr
    tax, ax = acceleration_from_velocity(t3, np.asarray(b_vel_x_mps), scan_s)
    tay, ay = acceleration_from_velocity(t3, np.asarray(b_vel_y_mps), scan_s)
    acceleration = lag_curve(
        drive_x,
        resample_nearest(tax, ax, t4, scan_s),
        drive_y,
        resample_nearest(tay, ay, t4, scan_s),
        max_lag,
    )
    t_vel = t3 - 0.5 * scan_s
    velocity = _curve_or_none(
        drive_x,
        resample_nearest(t_vel, np.asarray(b_vel_x_mps, dtype=np.float64), t4, scan_s),
        drive_y,
        resample_nearest(t_vel, np.asarray(b_vel_y_mps, dtype=np.float64), t4, scan_s),
        max_lag,
    )
    attitude = None
    if angle_pitch_rad is not None and angle_roll_rad is not None:
        attitude = _curve_or_none(
            -cp,
            np.asarray(angle_pitch_rad, dtype=np.float64),
            -cr,
            np.asarray(angle_roll_rad, dtype=np.float64),
            max_lag,
        )
    return Latency(
        acceleration=acceleration,
        attitude=attitude,
        velocity=velocity,
        samples=len(t4),
        period_s=period_s,
    )
