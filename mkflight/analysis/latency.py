"""The vehicle's response lag by cross-correlation of command and velocity (seed §F, Fig 8).

The seed correlates the body-frame velocity with the pitch angle and reads a peak at about
4 steps of 50 ms, i.e. the MK responds ≈ 200 ms later. Here the commanded tilt of each
50 ms step (TABLE IV ``ControlPitch``/``ControlRoll``, MK counts) is correlated with the
laser's body-frame velocity (TABLE III ``B_Vel.x``/``B_Vel.y``), resampled to the 50 ms rows
by nearest time, for lags 0..``max_lag`` steps; the x and y curves are averaged.

Signs (SPEC §1, §4): our pitch command is θ* = -ControlPitch/k and it asks for the
acceleration a_x = -g·θ*, so the x drive is ``+ControlPitch``; our roll command is
φ* = -ControlRoll/k and asks for a_y = +g·φ*, so the y drive is ``-ControlRoll``. A positive
correlation at lag k means that the velocity moves the way the command pushed it k steps
later.

What the lag means: the velocity responds to the tilt through the attitude loop's delay and
lag *and* an integration (velocity is the integral of the acceleration), so the peak is
later than the attitude delay alone, and in closed-loop hover the controller's feedback
(command opposing velocity) pulls the curve down at small lags. It is the "command to
velocity" response time of the seed's Fig 8, not a pure transport delay. Row times are
the step events' (TABLE IV; else index 1 at 50 ms) and ``(index - 1) x 100 ms`` (TABLE
III: index 1 at the first scan, 0 s): the alignment is good to about one 50 ms step.
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
"""The seed's Fig 8: ≈ 4 steps = 200 ms."""
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
        msg = "no correlation: the commands or velocities do not vary (or too few rows)"
        raise AnalysisInputError(msg)
    return int(np.nanargmax(curve))


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


@dataclass(frozen=True, slots=True)
class Latency:
    """The lag at the peak of the mean x/y curve, and the per-axis curves."""

    lag_steps: int
    lag_s: float
    curve: FloatArray
    lag_x_steps: int | None
    curve_x: FloatArray
    lag_y_steps: int | None
    curve_y: FloatArray
    samples: int
    period_s: float = IMU_PERIOD_S

    @property
    def peak_r(self) -> float:
        """The correlation at the peak (below :data:`WEAK_PEAK_R`: a weak, unreliable lag)."""
        return float(self.curve[self.lag_steps])

    def as_dict(self) -> dict[str, object]:
        """The ``--json`` object (NaN in a curve becomes ``null``)."""

        def clean(a: FloatArray) -> list[float | None]:
            return [round(float(x), 4) if math.isfinite(x) else None for x in a]

        return {
            "lag_steps": self.lag_steps,
            "lag_s": round(self.lag_s, 4),
            "curve": clean(self.curve),
            "lag_x_steps": self.lag_x_steps,
            "curve_x": clean(self.curve_x),
            "lag_y_steps": self.lag_y_steps,
            "curve_y": clean(self.curve_y),
            "peak_r": round(self.peak_r, 4),
            "samples": self.samples,
            "period_s": round(self.period_s, 6),
        }


def _peak_or_none(curve: FloatArray) -> int | None:
    return int(np.nanargmax(curve)) if np.any(np.isfinite(curve)) else None


def estimate_latency(
    *,
    index4: FloatArray,
    control_pitch_counts: FloatArray,
    control_roll_counts: FloatArray,
    index3: FloatArray,
    b_vel_x_mps: FloatArray,
    b_vel_y_mps: FloatArray,
    max_lag: int = MAX_LAG_STEPS,
    t4_s: FloatArray | None = None,
) -> Latency:
    """The command-to-velocity lag from TABLE IV and TABLE III columns (signs: module doc).

    ``t4_s``: the TABLE IV rows' times (s) when known (the ``step`` events' ``t_ns``: the
    FC's DebugOut period is ≈ 53 ms, not 50); else ``index x 50 ms``. ``lag_s`` is the lag
    times the median row period.

    Raises:
        AnalysisInputError: no finite correlation on either axis.
    """
    if t4_s is None:
        t4 = np.asarray(index4, dtype=np.float64) * IMU_PERIOD_S
    else:
        t4 = np.asarray(t4_s, dtype=np.float64)
    period_s = float(np.median(np.diff(t4))) if len(t4) > 1 else IMU_PERIOD_S
    t3 = (np.asarray(index3, dtype=np.float64) - 1.0) * LASER_PERIOD_S
    vx = resample_nearest(t3, np.asarray(b_vel_x_mps), t4, LASER_PERIOD_S)
    vy = resample_nearest(t3, np.asarray(b_vel_y_mps), t4, LASER_PERIOD_S)
    drive_x = np.asarray(control_pitch_counts, dtype=np.float64)
    drive_y = -np.asarray(control_roll_counts, dtype=np.float64)
    cx = lagged_correlation(drive_x, vx, max_lag)
    cy = lagged_correlation(drive_y, vy, max_lag)
    both = np.vstack([cx, cy])
    counts = np.sum(np.isfinite(both), axis=0)
    sums = np.nansum(both, axis=0)
    mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    lag = peak_lag(mean)
    return Latency(
        lag_steps=lag,
        lag_s=lag * period_s,
        curve=mean,
        lag_x_steps=_peak_or_none(cx),
        curve_x=cx,
        lag_y_steps=_peak_or_none(cy),
        curve_y=cy,
        samples=len(t4),
        period_s=period_s,
    )
