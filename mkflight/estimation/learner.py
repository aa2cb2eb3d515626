"""What the flight learns of its airframe while it holds: biases, hover gas, vibration.

An airframe on its first flight differs from the configuration in every constant (the
envelope of :mod:`mkflight.sim.airframe`: hover gas 82-115 counts, accelerometer offsets of
±10 counts, a horizon off by 0.02 rad, vibration of 5-30 counts). While the vehicle holds on
the laser, three of them are observable with simple averages, because a vehicle that holds
its height and position does not accelerate on average:

* **accelerometer bias** (level frame, the output of eq 9-14 of the 2011 QUT CyPhy
  MikroKopter documentation): the mean level-frame acceleration is the sum of the
  accelerometer offsets and the horizon error seen through gravity (``g·sin(bias)``). It is
  measured first on the floor before take-off (motors off: no vibration, the classic
  calibration at rest), then refined in HOLD. The estimator subtracts it, so the
  complementary filter's velocity (eq 15-17) is not off by ``bias / k`` (a height offset of
  2 cm on the nominal simulator for a 0.14 m/s² AccZ offset), and a descent without the
  laser integrates an unbiased AccZ;
* **hover gas**: the mean gas command over HOLD, normalised like the altitude loop's
  feed-forward (``hover_gas · (V_hover / V) / (cos θ cos φ)``, §M) to the gas that
  would hold the weight level at ``control.hover_voltage_v``. It is what the blind
  descent's thrust model and ``mkflight tune`` use;
* **vibration**: the accelerometer noise per body axis, from successive differences
  (``std(f_k - f_{k-1}) / √2`` removes anything slower than a sample): the trust the
  estimator gives the accelerometers (:func:`filter_gains`).

Averages are exponential with :data:`LEARN_TAU_S` (bias, hover gas) and
:data:`NOISE_TAU_S` (vibration), started as plain means, updated only on the steps the
caller marks as steady (HOLD, laser valid, no failsafe, slow vertical speed), and count
as learned after :data:`MIN_LEARN_S` of them. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from typing import Final

import msgspec

from mkflight.conversions import NS_PER_S

Vec3 = tuple[float, float, float]

LEARN_TAU_S: Final = 10.0
"""Averaging time of the biases and the hover gas (s): long against a gust, short
against a pack's sag."""
NOISE_TAU_S: Final = 5.0
"""Averaging time of the vibration (s)."""
MIN_LEARN_S: Final = 5.0
"""Steady time before a learned value is used (s)."""
MIN_REST_S: Final = 0.5
REST_WEIGHT_Z: Final = 10.0
"""A second at rest counts this many in the vertical bias's mean: motors off, AccZ reads
its offset to a few hundredths of m/s² at once, while in HOLD the vibration and the
vehicle's own accelerations make a mean over 10 s uncertain by ~0.05 m/s² — which a blind
descent integrates for seconds. The tilt of the floor spoils x and y at rest, not z."""
"""Time at rest before the biases are used (s): without vibration they settle at once."""
UPDATE_EVERY: Final = 5
"""The learned figures are recomputed every this many samples (they move over seconds)."""
MAX_SAMPLE_GAP_S: Final = 0.2
"""Two samples further apart are not successive (no difference, no averaging weight)."""
MAX_DIFF_MPS2: Final = 50.0
"""A sample-to-sample change beyond this is clamped (a glitch, not vibration)."""
MAX_BIAS_MPS2: Final = 3.0
MAX_GAS_COUNTS: Final = 255.0
"""The gas is a byte: a normalised hover gas beyond it is clamped."""
"""A learned bias beyond this is not a bias (a stuck sensor): it is clamped."""


def _clip(x: float, limit: float) -> float:
    """``max(-limit, min(limit, x))`` in the builtins' order (NaN gives ``limit``), cheaper."""
    x = x if x < limit else limit
    return x if x > -limit else -limit


class TimeMean:
    """An exponential mean over time that starts as a plain mean (no start-up bias)."""

    __slots__ = ("_decay", "span_s", "tau_s", "value")

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.value = 0.0
        self.span_s = 0.0  # time accumulated so far
        self._decay: tuple[float, float] = (0.0, 0.0)  # (dt, 1 - e^(-dt/τ)) of the last step

    def add(self, x: float, dt_s: float) -> None:
        """Add ``x`` held for ``dt_s``: the weight is ``dt/span`` early, ``1-e^(-dt/τ)`` later."""
        self.span_s += dt_s
        if self._decay[0] != dt_s:  # the FC's period repeats: one exp per new interval
            self._decay = (dt_s, 1.0 - math.exp(-dt_s / self.tau_s))
        early, decay = dt_s / self.span_s, self._decay[1]
        weight = decay if decay > early else early  # max(early, decay)
        self.value += weight * (x - self.value)


class LearnedAirframe(msgspec.Struct, frozen=True, gc=False):
    """What has been learned so far (None: not yet, see :data:`MIN_LEARN_S`).

    Attributes:
        bias_level_mps2: mean level-frame acceleration in HOLD (FRD: forward, right,
            down along the heading), the accelerometer offsets plus the horizon error.
        hover_gas_counts: gas holding the weight at ``hover_voltage_v``, level.
        vibration_mps2: accelerometer noise per body axis (x, y, z), one sample's std.
        steady_s: how long the learning has run.
    """

    bias_level_mps2: Vec3 | None
    hover_gas_counts: float | None
    vibration_mps2: Vec3 | None
    steady_s: float

    def as_dict(self) -> dict[str, object]:
        """Plain values for ``flight.json`` (``learned``), rounded."""

        def r(v: Vec3 | None, n: int) -> list[float] | None:
            return None if v is None else [round(x, n) for x in v]

        return {
            "bias_level_mps2": r(self.bias_level_mps2, 4),
            "hover_gas_counts": None
            if self.hover_gas_counts is None
            else round(self.hover_gas_counts, 2),
            "vibration_mps2": r(self.vibration_mps2, 4),
            "steady_s": round(self.steady_s, 2),
        }


class AirframeLearner:
    """Biases, hover gas and vibration from the steady part of a flight (module docstring)."""

    def __init__(self, hover_voltage_v: float) -> None:
        """Normalise the hover gas to ``hover_voltage_v`` (``control.hover_voltage_v``)."""
        self._hover_voltage_v = hover_voltage_v
        self._bias = (TimeMean(LEARN_TAU_S), TimeMean(LEARN_TAU_S), TimeMean(LEARN_TAU_S))
        self._hover = TimeMean(LEARN_TAU_S)
        self._noise = (TimeMean(NOISE_TAU_S), TimeMean(NOISE_TAU_S), TimeMean(NOISE_TAU_S))
        self._last: tuple[int, Vec3] | None = None  # the previous sample (t_ns, its source)
        self._last_kind = True  # the previous sample's source: the body specific force
        self._steady_s = 0.0
        self._rest_s = 0.0
        self._learned: LearnedAirframe | None = None  # the last figures (None: out of date)
        self._since_update = 0

    def observe(
        self,
        t_ns: int,
        *,
        acc_level_mps2: Vec3,
        f_body_mps2: Vec3,
        gas_factor: float,
        gas_counts: float,
        steady: bool,
        at_rest: bool = False,
        noise_source_mps2: Vec3 | None = None,
    ) -> None:
        """One IMU step: learn from it if ``steady`` (or, for the biases, ``at_rest``).

        Args:
            t_ns: the sample's time.
            acc_level_mps2: its level-frame acceleration (eq 9-14, gravity removed, FRD),
                WITHOUT any bias correction.
            f_body_mps2: its body specific force (the accelerometers, FRD).
            gas_factor: the feed-forward's factor for this step,
                ``(V_hover / V) / (cos θ cos φ)``: the hover gas is ``gas / gas_factor``.
            gas_counts: the gas the FC flew during this sample (the last command).
            steady: HOLD on a valid laser, no failsafe, slow vertical speed: learn all.
            at_rest: standing on the floor with the motors off before take-off: learn the
                biases only (no vibration then, so they are exact at once).
            noise_source_mps2: what the vibration is measured on (default the body
                specific force): the accelerations less what the attitude and the thrust
                model explain, whose successive differences are the vibration without the
                vehicle's own motion (the raw AccZ's read 0.57 for a true 0.32 m/s², the
                thrust answering the gas).
        """
        source = f_body_mps2 if noise_source_mps2 is None else noise_source_mps2
        kind = noise_source_mps2 is None
        last, self._last = self._last, (t_ns, source)
        same_kind, self._last_kind = kind == self._last_kind, kind
        if last is None or not (steady or at_rest):
            return
        dt_s = (t_ns - last[0]) / NS_PER_S
        if not 0.0 < dt_s <= MAX_SAMPLE_GAP_S:
            return
        values = (*acc_level_mps2, *f_body_mps2, gas_factor, gas_counts)
        if not all(map(math.isfinite, values)) or (steady and gas_factor <= 0.0):
            return
        self._since_update += 1
        if self._learned is None or self._since_update >= UPDATE_EVERY:
            self._learned, self._since_update = None, 0
        if not steady:
            self._rest_s += dt_s
        bx, by, bz = self._bias
        ax, ay, az = acc_level_mps2
        bx.add(_clip(ax, MAX_DIFF_MPS2), dt_s)
        by.add(_clip(ay, MAX_DIFF_MPS2), dt_s)
        bz.add(_clip(az, MAX_DIFF_MPS2), dt_s * (1.0 if steady else REST_WEIGHT_Z))
        if not steady:
            return
        self._steady_s += dt_s
        hover = gas_counts / gas_factor
        if math.isfinite(hover):
            hover = hover if hover < MAX_GAS_COUNTS else MAX_GAS_COUNTS  # min, then max
            self._hover.add(hover if hover > 0.0 else 0.0, dt_s)
        for mean, f, f0 in zip(self._noise, source, last[1], strict=True):
            if not same_kind:  # the source changed: no difference this once
                break
            diff = _clip(f - f0, MAX_DIFF_MPS2)
            mean.add(0.5 * diff * diff, dt_s)

    @property
    def ready(self) -> bool:
        """Learned long enough to be used (:data:`MIN_LEARN_S`)."""
        return self._steady_s >= MIN_LEARN_S

    def learned(self) -> LearnedAirframe:
        """The values learned so far (None: not yet), refreshed every :data:`UPDATE_EVERY`.

        The biases after :data:`MIN_REST_S` at rest or :data:`MIN_LEARN_S` steady, the
        hover gas and the vibration after :data:`MIN_LEARN_S` steady.
        """
        if self._learned is not None:
            return self._learned

        def clamp(v: float) -> float:
            return max(-MAX_BIAS_MPS2, min(MAX_BIAS_MPS2, v))

        bias: Vec3 | None = None
        if self._rest_s >= MIN_REST_S or self.ready:
            bx, by, bz = (clamp(m.value) for m in self._bias)
            bias = (bx, by, bz)
        if not self.ready:
            self._learned = LearnedAirframe(bias, None, None, self._steady_s)
        else:
            nx, ny, nz = (math.sqrt(max(m.value, 0.0)) for m in self._noise)
            self._learned = LearnedAirframe(bias, self._hover.value, (nx, ny, nz), self._steady_s)
        return self._learned
