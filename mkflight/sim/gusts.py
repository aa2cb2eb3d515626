"""Gusts as a deterministic function of ``(gust_seed, t)`` (SPEC §8): seeded OU series on a grid.

The simulated air has two Ornstein-Uhlenbeck disturbances, three axes each (world frame W):

* the **wind** velocity (correlation time ``wind_tau_s``), felt through the drag;
* a **disturbance acceleration** (correlation time ``gust_tau_s``): turbulence on the rotors.

Both are a pure function of the flight's ``gust_seed`` and the time ``t``, never of how a
caller steps through time: two flights of the same airframe and ``gust_seed`` meet the
same gusts whether they step 5 ms or 100 ms at a time, in 10 or 10,000 calls (the oracle
of ``sim envelope`` relies on this). How:

* each of the six channels is a **unit-variance** OU series sampled exactly on a fixed grid
  of :data:`GRID_S` (10 ms): ``x[k+1] = a x[k] + sqrt(1 - a^2) n[k]``, ``a = exp(-GRID_S /
  tau)``, ``n`` standard normal, ``x[0]`` from the stationary distribution; the caller
  scales it by the standard deviation it wants (so only the correlation times are part of
  the series' identity);
* between grid points the value is interpolated linearly (a correlation time well above
  10 ms loses < 1 % of its variance to the interpolation);
* the grid is cut into chunks of :data:`CHUNK_POINTS` (10.24 s). Chunk ``c``'s noise comes
  from ``numpy.random.default_rng([seed, 0x6057, c + 1])`` and its first value is the last
  of chunk ``c - 1`` (the stationary draw of ``[seed, 0x6057, 0]`` for chunk 0), so any
  chunk can be regenerated from its start value alone. Start values are kept for every
  chunk made (six floats per 10 s); chunk values only for the newest :data:`KEPT_CHUNKS`, so
  a flight of hours holds a few hundred kB, and a caller going back in time (a test stepping
  twice from one state) gets the same values again, regenerated.

The series is generated lazily, in chunk order the first time; reading it costs a few
float operations per query (:meth:`GustSeries.chunk` once per 10 s, then list indexing),
so the vehicle's integration loop reads it at every 5 ms sub-step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final, Protocol

import numpy as np

GRID_S: Final = 0.01  # the OU series' sampling step (exact OU transitions between points)
CHUNK_POINTS: Final = 1024  # grid intervals per chunk (10.24 s)
KEPT_CHUNKS: Final = 4  # chunks of values kept in memory (older ones are regenerated)
CHANNELS: Final = 6  # wind x, y, z (wind_tau_s), acceleration x, y, z (accel_tau_s)
_STREAM: Final = 0x6057  # spawn key of the gust streams, apart from every other seeded draw

Chunk = tuple[list[float], list[float], list[float], list[float], list[float], list[float]]
Unit6 = tuple[float, float, float, float, float, float]
Vec3 = tuple[float, float, float]
_ZERO: Final[Vec3] = (0.0, 0.0, 0.0)


class GustParams(Protocol):
    """The airframe constants the gusts read (:class:`~mkflight.sim.vehicle.VehicleParams`).

    A protocol, so that this module needs nothing of the vehicle's records, which hold a
    :class:`GustSeries` themselves.
    """

    @property
    def gusts(self) -> bool:
        """Gusts on (False: still air)."""
        ...

    @property
    def wind_std_mps(self) -> float:
        """Standard deviation of the horizontal wind velocity, m/s."""
        ...

    @property
    def wind_std_z_mps(self) -> float:
        """Standard deviation of the vertical wind velocity, m/s."""
        ...

    @property
    def wind_tau_s(self) -> float:
        """Correlation time of the wind, s."""
        ...

    @property
    def gust_accel_std_mps2(self) -> float:
        """Standard deviation of the horizontal disturbance acceleration, m/s^2."""
        ...

    @property
    def gust_accel_z_ratio(self) -> float:
        """The vertical disturbance acceleration's standard deviation over the horizontal's."""
        ...

    @property
    def gust_tau_s(self) -> float:
        """Correlation time of the disturbance acceleration, s."""
        ...


@dataclass(frozen=True, slots=True)
class GustSeries:
    """The six unit-variance OU series of one flight's air (module docstring).

    Equal (and interchangeable) when seed and correlation times are equal: the cache is
    an implementation detail, the values are fixed by the key.
    """

    seed: int
    wind_tau_s: float
    accel_tau_s: float
    _starts: list[Unit6] = field(default_factory=list, compare=False, repr=False)
    _chunks: dict[int, Chunk] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        """Reject correlation times that are not finite and positive."""
        for name in ("wind_tau_s", "accel_tau_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f"GustSeries: {name} must be finite and > 0, got {value}"
                raise ValueError(msg)

    def chunk(self, c: int) -> Chunk:
        """Chunk ``c``'s values: six lists of ``CHUNK_POINTS + 1`` grid points (both ends).

        Point ``i`` of chunk ``c`` is the series at ``t = (c * CHUNK_POINTS + i) * GRID_S``.
        """
        got = self._chunks.get(c)
        if got is not None:
            return got
        if c < 0:
            msg = f"GustSeries: chunk {c} is before t = 0"
            raise ValueError(msg)
        while len(self._starts) <= c:  # first visit: make every chunk before, in order
            self._starts.append(self._next_start())
        values = self._generate(c, self._starts[c])
        if len(self._chunks) >= KEPT_CHUNKS:
            del self._chunks[next(iter(self._chunks))]  # the oldest made
        self._chunks[c] = values
        return values

    def unit_at(self, t_s: float) -> Unit6:
        """The six unit-variance values at ``t_s`` (linear between grid points; t < 0: t = 0)."""
        u = max(t_s, 0.0) / GRID_S
        k = int(u)
        f = u - k
        c, i = divmod(k, CHUNK_POINTS)
        ch = self.chunk(c)
        return (
            ch[0][i] + f * (ch[0][i + 1] - ch[0][i]),
            ch[1][i] + f * (ch[1][i + 1] - ch[1][i]),
            ch[2][i] + f * (ch[2][i + 1] - ch[2][i]),
            ch[3][i] + f * (ch[3][i + 1] - ch[3][i]),
            ch[4][i] + f * (ch[4][i + 1] - ch[4][i]),
            ch[5][i] + f * (ch[5][i + 1] - ch[5][i]),
        )

    def _next_start(self) -> Unit6:
        """The start value of the next chunk not yet started (``len(_starts)``)."""
        c = len(self._starts)
        if c == 0:
            n = np.random.default_rng([self.seed, _STREAM, 0]).standard_normal(CHANNELS)
            return (
                float(n[0]),
                float(n[1]),
                float(n[2]),
                float(n[3]),
                float(n[4]),
                float(n[5]),
            )
        prev = self.chunk(c - 1)
        return (prev[0][-1], prev[1][-1], prev[2][-1], prev[3][-1], prev[4][-1], prev[5][-1])

    def _generate(self, c: int, start: Unit6) -> Chunk:
        """Chunk ``c`` from its start value: exact OU transitions on the grid."""
        noise = np.random.default_rng([self.seed, _STREAM, c + 1]).standard_normal(
            (CHANNELS, CHUNK_POINTS)
        )
        out: list[list[float]] = []
        for ch in range(CHANNELS):
            tau = self.wind_tau_s if ch < 3 else self.accel_tau_s
            a = math.exp(-GRID_S / tau)
            b = math.sqrt(1.0 - a * a)
            x = start[ch]
            values = [x]
            append = values.append
            for n in noise[ch].tolist():
                x = a * x + b * n
                append(x)
            out.append(values)
        return (out[0], out[1], out[2], out[3], out[4], out[5])


def gust_series(params: GustParams, gust_seed: int) -> GustSeries | None:
    """The flight's gust series (``None`` in still air, ``params.gusts`` off)."""
    if not params.gusts:
        return None
    return GustSeries(gust_seed, params.wind_tau_s, params.gust_tau_s)


def gusts_at(series: GustSeries | None, params: GustParams, t_s: float) -> tuple[Vec3, Vec3]:
    """``(wind_w_mps, gust_w_mps2)`` at ``t_s``: the series scaled by ``params``' stds."""
    if series is None or not params.gusts:
        return _ZERO, _ZERO
    u = series.unit_at(t_s)
    sw, sz = params.wind_std_mps, params.wind_std_z_mps
    sa = params.gust_accel_std_mps2
    saz = sa * params.gust_accel_z_ratio
    return (sw * u[0], sw * u[1], sz * u[2]), (sa * u[3], sa * u[4], saz * u[5])
