"""Height and vertical speed without the hat: a thrust model checked by AccZ (SPEC §3, §5).

While the laser's hat gives the height, the complementary filter of eq 17 (§ and eq: the
2011 QUT CyPhy MikroKopter documentation) holds the vertical channel. When it stops (a
stalled laser), the estimator can only integrate AccZ, and the FC's AccZ carries the motors'
vibration: its integral is a random walk of ``sigma·√(T·t)`` — 0.16 m/s after 3.3 s at 0.39
m/s² (a worn prop), enough to turn a 0.3 m/s descent into a 0.5 m/s touchdown.

The vehicle's own thrust model does not vibrate. The gas is known (it is our command) and
the hover gas was learned in HOLD (:mod:`mkflight.estimation.learner`), so the model
acceleration is ``a_model = g·(gas_lagged / hover_now - 1) - k_drag·v`` with
``hover_now`` the learned hover gas scaled like the feed-forward (battery, tilt; §M),
``gas_lagged`` the command through the motors' lag and a typical drag. What the model
misses — gusts, the airframe's own drag, the model's error — is a disturbance ``w`` that
AccZ measures, noisily:

    state (h, v, w):  h' = v,  v' = a_model + w,  w' = -w/τ_w + noise  (Ornstein-Uhlenbeck)
    measurement:      AccZ_up - a_model = w + n,   n ~ N(0, sigma_n²), sigma_n: the vibration

a three-state Kalman filter, its gain from the noise measured in flight: with a
quiet accelerometer it follows AccZ closely, with a noisy one it leans on the model, and
the disturbance's mean reversion keeps the noise from random-walking into the velocity.
A sample far from what the filter expects (a jolt) is clipped (:data:`GATE_SIGMAS`). Over
3.3 s of hover the filter's speed wanders 10-30 % less than AccZ's plain integral (more
with more vibration); what keeps a descent soft is the floor detection of
:mod:`mkflight.control.descent`, not this alone.
Without usable FC samples it runs on the model alone. Pure: time comes in as ``t_ns``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from mkflight.conversions import NS_PER_S

DISTURBANCE_STD_MPS2: Final = 0.15
"""Prior std of what the thrust model misses (gusts, drag, its own error), m/s^2."""
DISTURBANCE_TAU_S: Final = 1.0
"""... and its correlation time, s (a lasting error of the model is followed within ~1 s)."""
DRAG_PER_S: Final = 0.3
"""The vertical drag the model assumes (an airframe's is 0.15-0.5 /s): ``-k·v``."""
THRUST_TAU_S: Final = 0.05
"""The motors' lag from gas to thrust assumed by the model, s."""
MAX_DT_S: Final = 0.25
"""A longer gap between steps is integrated over this only."""
GATE_SIGMAS: Final = 4.0
"""An AccZ sample further than this many standard deviations from the expectation (and
than :data:`MIN_GATE_MPS2`) counts only that far (Huber-like clipping): a single jolt
must not become a velocity."""
MIN_GATE_MPS2: Final = 1.0
HAT_NOISE_M: Final = 0.005
"""A hat height's noise as the filter takes it (the median of 84 beams, and its age), m."""
MAX_GAS_COUNTS: Final = 255.0
"""The gas is a byte."""
MAX_MODEL_ACCEL_G: Final = 3.0
"""The model's acceleration is clamped to this many g (absurd inputs stay finite)."""
MIN_NOISE_MPS2: Final = 0.05
"""Floor of the measurement noise (a quiet or unlearned accelerometer is not perfect)."""

Mat3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True, slots=True)
class VerticalState:
    """Height (m, up), vertical speed (m/s, up) and the model's disturbance (m/s^2)."""

    height_m: float
    vz_up_mps: float
    disturbance_mps2: float


class VerticalDeadReckoning:
    """The model-aided vertical channel (module docstring), started at the hat's loss."""

    def __init__(
        self,
        *,
        t_ns: int,
        height_m: float,
        vz_up_mps: float,
        hover_gas_counts: float,
        gas_counts: float,
        noise_mps2: float | None,
        g_mps2: float,
    ) -> None:
        """Start from the last estimate with the hat.

        Args:
            t_ns: now.
            height_m: the height now (m, up); NaN: 0.
            vz_up_mps: the vertical speed now (m/s, up); NaN: 0.
            hover_gas_counts: the gas holding the weight at the hover voltage, level.
            gas_counts: the gas flying now (the thrust's start).
            noise_mps2: the accelerometer noise (AccZ, one sample's std); None: unknown.
            g_mps2: gravity.
        """
        self._t_ns = t_ns
        self._hover = hover_gas_counts if hover_gas_counts > 0 else 1.0
        self._g = g_mps2
        self._thrust_gas = gas_counts
        noise = noise_mps2 if noise_mps2 is not None and math.isfinite(noise_mps2) else 0.3
        self._r = max(noise, MIN_NOISE_MPS2) ** 2
        h = height_m if math.isfinite(height_m) else 0.0
        v = vz_up_mps if math.isfinite(vz_up_mps) else 0.0
        self._x = (h, v, 0.0)
        q = DISTURBANCE_STD_MPS2**2
        self._p: Mat3 = ((1e-4, 0.0, 0.0), (0.0, 1e-3, 0.0), (0.0, 0.0, q))

    @property
    def state(self) -> VerticalState:
        """The estimate now."""
        return VerticalState(*self._x)

    def correct_height(self, height_m: float, *, age_s: float = 0.0) -> None:
        """A hat height taken ``age_s`` ago (m, up): a Kalman update of the height.

        The height is carried to now with the current speed (eq 18-20's one-sample
        prediction); a reading far from the expectation counts only so far (gated).
        """
        if not (math.isfinite(height_m) and math.isfinite(age_s)):
            return
        h, v, w = self._x
        z = height_m + v * max(0.0, min(age_s, MAX_DT_S))
        p = self._p
        s = p[0][0] + HAT_NOISE_M**2
        e = z - h
        limit = max(GATE_SIGMAS * math.sqrt(s), 0.05)
        e = max(-limit, min(limit, e))
        k = (p[0][0] / s, p[1][0] / s, p[2][0] / s)
        self._x = (h + k[0] * e, v + k[1] * e, w + k[2] * e)
        row0 = p[0]
        self._p = (
            (p[0][0] - k[0] * row0[0], p[0][1] - k[0] * row0[1], p[0][2] - k[0] * row0[2]),
            (p[1][0] - k[1] * row0[0], p[1][1] - k[1] * row0[1], p[1][2] - k[1] * row0[2]),
            (p[2][0] - k[2] * row0[0], p[2][1] - k[2] * row0[1], p[2][2] - k[2] * row0[2]),
        )

    def set_velocity(self, vz_up_mps: float) -> None:
        """Take this vertical speed (m/s, up): a probe found the vehicle falling."""
        if math.isfinite(vz_up_mps):
            h, _, w = self._x
            self._x = (h, vz_up_mps, w)

    def rest(self) -> None:
        """The vehicle is known to rest on the floor now: height 0, speed 0, no disturbance."""
        self._x = (0.0, 0.0, 0.0)
        q = DISTURBANCE_STD_MPS2**2
        self._p = ((1e-4, 0.0, 0.0), (0.0, 1e-3, 0.0), (0.0, 0.0, q))

    def model_accel(self, gas_factor: float) -> float:
        """The thrust model's vertical acceleration now (m/s^2, up)."""
        hover_now = self._hover * gas_factor
        if not hover_now > 0.0:
            return 0.0
        a = self._g * (self._thrust_gas / hover_now - 1.0)
        return min(max(a, -MAX_MODEL_ACCEL_G * self._g), MAX_MODEL_ACCEL_G * self._g)

    def step(
        self,
        t_ns: int,
        *,
        gas_counts: float,
        gas_factor: float,
        acc_up_mps2: float | None,
    ) -> VerticalState:
        """Advance to ``t_ns`` and correct with AccZ.

        Args:
            t_ns: this sample's time.
            gas_counts: the gas the FC flew since the last step (our last command).
            gas_factor: the feed-forward's factor ``(V_hover / V) / (cos θ cos φ)``.
            acc_up_mps2: the level-frame vertical acceleration measured now (bias
                removed, m/s^2, up), or None when the FC's sample is unusable.
        """
        dt = min(max(0.0, (t_ns - self._t_ns) / NS_PER_S), MAX_DT_S)
        self._t_ns = t_ns
        factor = gas_factor if math.isfinite(gas_factor) and 0.0 < gas_factor < 10.0 else 1.0
        if math.isfinite(gas_counts):
            gas_counts = min(max(gas_counts, 0.0), MAX_GAS_COUNTS)
            self._thrust_gas += (gas_counts - self._thrust_gas) * (
                1.0 - math.exp(-dt / THRUST_TAU_S)
            )
        a_model = self.model_accel(factor) - DRAG_PER_S * self._x[1]
        self._predict(dt, a_model)
        if acc_up_mps2 is not None and math.isfinite(acc_up_mps2):
            self._update(acc_up_mps2 - a_model)
        return self.state

    def _predict(self, dt: float, a_model: float) -> None:
        """X = F x + B a_model;  P = F P Fᵀ + Q (w held over dt, then decayed)."""
        h, v, w = self._x
        phi = math.exp(-dt / DISTURBANCE_TAU_S)
        half = 0.5 * dt * dt
        self._x = (h + v * dt + half * (a_model + w), v + dt * (a_model + w), phi * w)
        f: Mat3 = ((1.0, dt, half), (0.0, 1.0, dt), (0.0, 0.0, phi))
        fp = _mul(f, self._p)
        p = _mul(fp, _transpose(f))
        q_w = DISTURBANCE_STD_MPS2**2 * (1.0 - phi * phi)
        self._p = (p[0], p[1], (p[2][0], p[2][1], p[2][2] + q_w))

    def _update(self, innovation_mps2: float) -> None:
        """The AccZ measurement of w (H = [0, 0, 1])."""
        p = self._p
        s = p[2][2] + self._r
        k = (p[0][2] / s, p[1][2] / s, p[2][2] / s)
        e = innovation_mps2 - self._x[2]
        limit = max(GATE_SIGMAS * math.sqrt(s), MIN_GATE_MPS2)  # a jolt is not a gust: clip
        e = max(-limit, min(limit, e))
        h, v, w = self._x
        self._x = (h + k[0] * e, v + k[1] * e, w + k[2] * e)
        row2 = p[2]
        self._p = (
            (p[0][0] - k[0] * row2[0], p[0][1] - k[0] * row2[1], p[0][2] - k[0] * row2[2]),
            (p[1][0] - k[1] * row2[0], p[1][1] - k[1] * row2[1], p[1][2] - k[1] * row2[2]),
            (p[2][0] - k[2] * row2[0], p[2][1] - k[2] * row2[1], p[2][2] - k[2] * row2[2]),
        )


def _mul(a: Mat3, b: Mat3) -> Mat3:
    rows = [tuple(sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)) for i in range(3)]
    return (
        (rows[0][0], rows[0][1], rows[0][2]),
        (rows[1][0], rows[1][1], rows[1][2]),
        (rows[2][0], rows[2][1], rows[2][2]),
    )


def _transpose(a: Mat3) -> Mat3:
    return (
        (a[0][0], a[1][0], a[2][0]),
        (a[0][1], a[1][1], a[2][1]),
        (a[0][2], a[1][2], a[2][2]),
    )
