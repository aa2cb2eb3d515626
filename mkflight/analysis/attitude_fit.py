"""The FC's attitude response: pure delay + first-order lag + gain + offset (§F).

§F is that of the 2011 QUT CyPhy MikroKopter documentation. The commanded angle is held from
each row's time to the next (zero-order hold); the model is
``tau * x'(t) + x(t) = u(t - d)``, ``angle(t) = K * x(t) + b``, simulated exactly between
the rows' real (jittered) times from rest. Every ``(d, tau)`` of a grid
(:data:`DELAY_GRID_S`, :data:`TAU_GRID_S`) gets ``K`` and ``b`` by linear least squares, all
at once (one pass over the rows with the whole grid as arrays), and the point of least
residual wins. :func:`fit_attitude` fits each axis and all of them together (one ``d``,
``tau`` and ``K``, an offset each); :mod:`mkflight.analysis.identify` applies it to a
flight. A fit whose data cannot carry it says why in :attr:`AttitudeFit.poor`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from mkflight.logs.flight_json import json_safe

__all__ = [
    "DELAY_GRID_S",
    "GAIN_LIMITS",
    "MIN_EXCITATION_RAD",
    "MIN_FIT_SAMPLES",
    "MIN_R2",
    "TAU_GRID_S",
    "AttitudeFit",
    "fit_attitude",
]

FloatArray = npt.NDArray[np.float64]

DELAY_GRID_S: Final = np.round(np.arange(0.0, 0.3 + 1e-9, 0.005), 6)
"""The pure delays tried (s)."""
TAU_GRID_S: Final = np.round(np.arange(0.02, 0.4 + 1e-9, 0.005), 6)
"""The first-order lags tried (s)."""
MIN_FIT_SAMPLES: Final = 100
"""An attitude fit needs this many HOLD rows (5 s) to be trusted."""
MIN_EXCITATION_RAD: Final = 0.01
"""... and a commanded angle whose standard deviation is at least this."""
MIN_R2: Final = 0.6
"""... and this share of the angle's variance explained."""
GAIN_LIMITS: Final = (0.5, 2.0)
"""... and a gain K in this range (an FC at 60 to 240 counts/rad for the default 120)."""


@dataclass(frozen=True, slots=True)
class AttitudeFit:
    """A delay + first-order lag fit of the FC's angle to the commanded angle (§F).

    Attributes:
        axis: ``"pitch"``, ``"roll"`` or ``"both"`` (one model for the two axes).
        delay_s: the pure delay d (NaN: not fitted).
        tau_s: the first-order lag tau.
        gain: K, the FC's angle per commanded angle (1.0: ``mk.counts_per_rad`` is right).
        offsets_rad: the constant offset b of each axis (the FC's horizon bias).
        r2: the share of the angle's variance the model explains.
        residual_rad: the RMS of what it does not explain.
        samples: the rows fitted (per axis summed for ``both``).
        excitation_rad: the standard deviation of the commanded angle over those rows.
        poor: why the fit is not to be trusted; ``""`` when it is.
    """

    axis: str
    delay_s: float
    tau_s: float
    gain: float
    offsets_rad: tuple[float, ...]
    r2: float
    residual_rad: float
    samples: int
    excitation_rad: float
    poor: str

    @property
    def good(self) -> bool:
        """The fit can be used."""
        return not self.poor

    @property
    def response_s(self) -> float:
        """Delay + lag, d + tau: the response time the position loop sees."""
        return self.delay_s + self.tau_s

    def as_dict(self) -> dict[str, Any]:
        """Plain values (NaN as None) for ``--json``."""
        out: dict[str, Any] = json_safe(
            {
                "delay_s": round(self.delay_s, 4),
                "tau_s": round(self.tau_s, 4),
                "response_s": round(self.response_s, 4),
                "gain": round(self.gain, 4),
                "offsets_rad": [round(v, 5) for v in self.offsets_rad],
                "r2": round(self.r2, 4),
                "residual_rad": round(self.residual_rad, 5),
                "samples": self.samples,
                "excitation_rad": round(self.excitation_rad, 5),
                "good": self.good,
                "poor": self.poor,
            }
        )
        return out


def fit_attitude(
    t_s: npt.ArrayLike,
    command_rad: npt.ArrayLike,
    angle_rad: npt.ArrayLike,
    fit: npt.ArrayLike,
    *,
    delays_s: npt.ArrayLike = DELAY_GRID_S,
    taus_s: npt.ArrayLike = TAU_GRID_S,
    names: tuple[str, ...] = ("pitch", "roll"),
) -> tuple[AttitudeFit, ...]:
    """Fit delay + first-order lag + gain + offset per axis and for all axes together.

    Args:
        t_s: the rows' times, strictly increasing (s).
        command_rad: ``(axes, rows)``: the angle commanded at each row, held until the
            next row (zero-order hold); the model starts at rest with no command.
        angle_rad: ``(axes, rows)``: the FC's measured angle at each row (NaN: skipped).
        fit: the rows to fit (the earlier ones only drive the simulation).
        delays_s: the delays to try.
        taus_s: the lags to try (> 0).
        names: the axes' names.

    Returns:
        One :class:`AttitudeFit` per axis, then the joint one (axis ``"both"``).

    Raises:
        ValueError: times not strictly increasing, or a lag not > 0.
    """
    cmd = np.atleast_2d(np.asarray(command_rad, dtype=np.float64))
    y = np.atleast_2d(np.asarray(angle_rad, dtype=np.float64))
    t = np.asarray(t_s, dtype=np.float64)
    delays = np.asarray(delays_s, dtype=np.float64)
    taus = np.asarray(taus_s, dtype=np.float64)
    masks = np.asarray(fit, dtype=bool)[None, :] & np.isfinite(y) & np.isfinite(cmd)
    if np.any(~(np.diff(t) > 0)) or np.any(~(taus > 0)):
        msg = "fit_attitude: times must increase strictly and lags be > 0"
        raise ValueError(msg)
    sums = _grid_sums(t, np.where(np.isfinite(cmd), cmd, 0.0), y, masks, delays, taus)
    fits = [
        _best(names[a], sums[:, a : a + 1], _std(cmd[a][masks[a]]), delays, taus)
        for a in range(cmd.shape[0])
    ]
    fits.append(_best("both", sums, _std(cmd[masks]), delays, taus))
    return tuple(fits)


def _std(values: FloatArray) -> float:
    return float(np.std(values)) if len(values) else 0.0


def _grid_sums(
    t: FloatArray,
    cmd: FloatArray,
    y: FloatArray,
    masks: npt.NDArray[np.bool_],
    delays: FloatArray,
    taus: FloatArray,
) -> FloatArray:
    """Least-squares sums over the fitted rows for every (axis, delay, lag).

    Returns ``(6, axes, delays, taus)``: n, Σx, Σx², Σxy, Σy, Σy², with x the model's
    unit-gain response. The lag is simulated exactly between the rows: the response to
    the command steps Δc_k switched at ``t_k + d`` is ``u(t) - z(t)``, ``u`` the command
    in force and ``z = Σ Δc_k exp(-(t - t_k - d) / tau)``, which decays by
    ``exp(-Δt / tau)`` from one row to the next and takes each step as it switches.
    """
    n_axes, n = cmd.shape
    nd, nt = len(delays), len(taus)
    dc = np.diff(cmd, axis=1, prepend=0.0)
    switch = t[:, None] + delays[None, :]  # (rows, delays): when step k's change is felt
    seen_at = np.searchsorted(t, switch.ravel(), side="left")  # the first row at or after
    order = np.argsort(seen_at, kind="stable")  # by row, then by (step, delay)
    k_of, d_of = np.divmod(order, nd)
    seen_sorted = seen_at[order]
    starts = np.searchsorted(seen_sorted, np.arange(n + 1), side="left")
    # A row that sees two switches of the same delay (DebugOut jitter) must add both.
    pair_ids = seen_sorted * nd + d_of
    has_repeat = np.zeros(n + 1, dtype=bool)
    has_repeat[np.flatnonzero(np.bincount(pair_ids) > 1) // nd] = True
    inv_tau = 1.0 / taus
    u = np.zeros((nd, n_axes))  # delay first: the switches index it by delay
    z = np.zeros((nd, n_axes, nt))
    sx, sxx, sxy = (np.zeros((nd, n_axes, nt)) for _ in range(3))
    x, tmp = np.empty_like(z), np.empty_like(z)
    weights = masks.astype(np.float64)
    y0 = np.where(masks, y, 0.0)
    for j in range(n):
        if j:
            z *= np.exp(-(t[j] - t[j - 1]) * inv_tau)
        lo, hi = starts[j], starts[j + 1]
        if hi > lo:
            ks, ds = k_of[lo:hi], d_of[lo:hi]
            age = t[j] - switch[ks, ds]  # >= 0
            steps = dc[:, ks].T  # (pairs, axes)
            jump = steps[:, :, None] * np.exp(-age[:, None, None] * inv_tau)
            if has_repeat[j]:
                np.add.at(u, ds, steps)
                np.add.at(z, ds, jump)
            else:
                u[ds] += steps
                z[ds] += jump
        if not masks[:, j].any():
            continue
        np.subtract(u[:, :, None], z, out=x)
        w = weights[:, j][None, :, None]
        if not masks[:, j].all():
            x *= w  # an axis not fitted at this row adds nothing
        sx += x
        np.multiply(x, x, out=tmp)
        sxx += tmp
        np.multiply(x, y0[:, j][None, :, None], out=tmp)
        sxy += tmp
    n_fit = weights.sum(axis=1)[:, None, None]
    sy = y0.sum(axis=1)[:, None, None]
    syy = (y0 * y0).sum(axis=1)[:, None, None]
    shape = (n_axes, nd, nt)
    sums = [np.broadcast_to(v, shape) for v in (n_fit, sy, syy)]
    grid = [v.transpose(1, 0, 2) for v in (sx, sxx, sxy)]
    return np.stack([sums[0], grid[0], grid[1], grid[2], sums[1], sums[2]])


def _best(
    axis: str, sums: FloatArray, excitation_rad: float, delays: FloatArray, taus: FloatArray
) -> AttitudeFit:
    """The grid point of least residual for the axes of ``sums`` (one model, own offsets)."""
    n, sx, sxx, sxy, sy, syy = sums
    n_axes = sums.shape[1]
    samples = int(n[:, 0, 0].sum())
    unfitted = AttitudeFit(
        axis=axis,
        delay_s=math.nan,
        tau_s=math.nan,
        gain=math.nan,
        offsets_rad=(math.nan,) * n_axes,
        r2=math.nan,
        residual_rad=math.nan,
        samples=samples,
        excitation_rad=excitation_rad,
        poor=f"only {samples} rows to fit",
    )
    if samples < 3:
        return unfitted
    safe_n = np.maximum(n, 1.0)
    cxx = (sxx - sx * sx / safe_n).sum(axis=0)
    cxy = (sxy - sx * sy / safe_n).sum(axis=0)
    cyy = (syy - sy * sy / safe_n).sum(axis=0)
    excited = cxx > 1e-12 * max(float(cyy.max()), 1e-30)
    ssr = np.where(excited, cyy - cxy**2 / np.where(excited, cxx, 1.0), np.inf)
    i, j = np.unravel_index(int(np.argmin(ssr)), ssr.shape)
    if not math.isfinite(float(ssr[i, j])):
        return replace(unfitted, poor="the commanded angle never changes")
    gain = float(cxy[i, j] / cxx[i, j])
    offsets = tuple(
        float((sy[a, i, j] - gain * sx[a, i, j]) / safe_n[a, i, j]) for a in range(n_axes)
    )
    total = float(cyy[i, j])
    residual = max(float(ssr[i, j]), 0.0)
    r2 = 1.0 - residual / total if total > 0 else math.nan
    fit = AttitudeFit(
        axis=axis,
        delay_s=float(delays[i]),
        tau_s=float(taus[j]),
        gain=gain,
        offsets_rad=offsets,
        r2=r2,
        residual_rad=math.sqrt(residual / samples),
        samples=samples,
        excitation_rad=excitation_rad,
        poor="",
    )
    edge = i == len(delays) - 1 or j == len(taus) - 1
    return _judged(fit, edge)


def _judged(fit: AttitudeFit, edge: bool) -> AttitudeFit:
    """The fit with its ``poor`` reason filled in when the data cannot carry it."""
    reasons = []
    if fit.samples < MIN_FIT_SAMPLES:
        reasons.append(f"only {fit.samples} rows (need {MIN_FIT_SAMPLES})")
    if fit.excitation_rad < MIN_EXCITATION_RAD:
        reasons.append(
            f"little excitation (commanded angle std {fit.excitation_rad:.4f} rad < "
            f"{MIN_EXCITATION_RAD}: a calm hover; fly steps, e.g. 'sim hover --excite 0.2')"
        )
    if not fit.r2 >= MIN_R2:
        reasons.append(f"R² {fit.r2:.2f} < {MIN_R2}")
    if not GAIN_LIMITS[0] <= fit.gain <= GAIN_LIMITS[1]:
        reasons.append(f"gain {fit.gain:.2f} outside {GAIN_LIMITS[0]}..{GAIN_LIMITS[1]}")
    if edge:
        reasons.append("best point on the edge of the search grid")
    return replace(fit, poor="; ".join(reasons))
