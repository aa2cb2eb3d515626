"""Horizontal acceleration from the attitude, checked by the accelerometers (SPEC §3).

Eq 15-16 of the 2011 QUT CyPhy MikroKopter documentation integrate the level-frame
acceleration the accelerometers give (eq 9-14). On a MikroKopter those carry the motors'
vibration, 5-30 AccNick counts (0.08-0.49 m/s²) in every sample, and the complementary
filter turns it into velocity noise that the velocity loop flies: on the nominal simulator
it is most of the hover error.

The FC's attitude hardly vibrates (its angles are the output of its own filter) and, for a
vehicle holding its height, sets the horizontal acceleration: the thrust ``g / (cos θ cos
φ)`` along the body's z axis gives, in the level frame, ``a_x = -g tan θ`` and ``a_y = g tan
φ / cos θ`` (:func:`tilt_acceleration`). What it misses — gusts, drag, the accelerometers'
and the horizon's offsets — is a disturbance ``d = a_meas - a_tilt`` that the
accelerometers see under their noise. Per axis, a scalar Kalman filter estimates it: ``d``
is a random walk that moves per step as much as turbulence of the envelope's strength and
time scale does (:data:`DISTURBANCE_STD_MPS2`, :data:`DISTURBANCE_TAU_S`; no pull towards
0, so a lasting push is followed in full), the measured vibration is the noise; the
estimator integrates ``a_tilt + d̂``. With quiet accelerometers the
gain is high and ``a_tilt + d̂`` follows them; with a worn prop it leans on the attitude.
A sample further than :data:`GATE_SIGMAS` from the expectation counts only that far.

Vertically the same, when the flight step gives the thrust model's acceleration
``g·(gas / hover_now - 1)`` (the gas commanded through the motors' lag, the hover gas
learned in HOLD scaled like the feed-forward; §M): in flight, with control. Otherwise
z is the accelerometer's own.

Constant offsets of ``a_model + d̂`` (the horizon's error through gravity, the
accelerometers' offsets) are learned and removed like those of the raw acceleration
(:mod:`mkflight.estimation.learner`). Pure.
"""

from __future__ import annotations

import math
from typing import Final

from mkflight.conversions import NS_PER_S

DISTURBANCE_STD_MPS2: Final = 0.25
"""Prior std of what the attitude misses (turbulence, drag), m/s^2 (the envelope's top)."""
DISTURBANCE_TAU_S: Final = 0.3
"""... and its correlation time, s."""
DISTURBANCE_Z_STD_MPS2: Final = 0.15
"""Prior std of what the thrust model misses vertically (turbulence, the learned hover
gas's error, ground effect), m/s^2."""
DEFAULT_NOISE_MPS2: Final = 0.3
"""The accelerometers' noise until the flight has measured it (one sample's std)."""
MIN_NOISE_MPS2: Final = 0.03
GATE_SIGMAS: Final = 4.0
MIN_GATE_MPS2: Final = 1.0
LASTING_TAU_S: Final = 20.0
"""The disturbance's lasting part (the accelerometers' offsets, a steady draught) is its
mean over this long; the rest is the turbulence the controller may counter."""
MAX_GAP_S: Final = 0.25
"""After a longer gap the disturbance starts again from the measurement."""
MIN_TILT_COS: Final = 0.5
"""The hover-thrust assumption is floored at this cos θ cos φ (60°): no division by ~0."""

Vec3 = tuple[float, float, float]


def tilt_acceleration(pitch_rad: float, roll_rad: float, g_mps2: float) -> tuple[float, float]:
    """Level-frame horizontal acceleration of a vehicle holding height at this attitude.

    The thrust ``g / (cos θ cos φ)`` along body -z, rotated by ``R_y(θ) R_x(φ)`` (SPEC §3):
    ``(-g tan θ, g tan φ / cos θ)``; FRD, forward and right along the heading.
    """
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    thrust = g_mps2 / max(cp * cr, MIN_TILT_COS)
    return -sp * cr * thrust, sr * thrust


class _Axis:
    """One axis's disturbance: a scalar Kalman filter on ``measured - model``."""

    __slots__ = ("d", "p", "q_std", "r")

    def __init__(self, q_std: float) -> None:
        self.q_std = q_std
        self.d = 0.0
        self.p = q_std * q_std
        self.r = DEFAULT_NOISE_MPS2**2

    def reset(self, measured: float) -> None:
        self.d, self.p = measured, self.r

    def update(self, measured: float, q_fraction: float) -> None:
        # a random walk that moves as much per step as the turbulence does: no pull
        # towards 0, so a lasting push (drag, a draught) is followed in full
        p = self.p + self.q_std * self.q_std * q_fraction
        s = p + self.r
        limit = max(GATE_SIGMAS * math.sqrt(s), MIN_GATE_MPS2)
        innovation = max(-limit, min(limit, measured - self.d))
        k = p / s
        self.d, self.p = self.d + k * innovation, (1.0 - k) * p


class TiltAcceleration:
    """``a_model + d̂`` per axis (module docstring): x, y from the attitude, z from thrust."""

    def __init__(self, g_mps2: float) -> None:
        """Start with no disturbance known and the default noise."""
        self._g = g_mps2
        self._axes = (
            _Axis(DISTURBANCE_STD_MPS2),
            _Axis(DISTURBANCE_STD_MPS2),
            _Axis(DISTURBANCE_Z_STD_MPS2),
        )
        self._t_ns: int | None = None
        self._z_model = False  # the last sample had a thrust model (else: z as measured)
        self._lasting = [0.0, 0.0]
        self._lasting_s = 0.0
        self._q: tuple[float, float] = (0.0, 0.0)  # (dt, the random walk's share of q)
        self.residual_mps2: tuple[float, float, float | None] = (0.0, 0.0, None)
        """The last sample's ``measured - model`` per axis (z: None without the thrust
        model): what the accelerometers add to the models, vibration included."""

    @property
    def disturbance_mps2(self) -> tuple[float, float]:
        """The disturbance estimated now (level frame, x and y)."""
        return self._axes[0].d, self._axes[1].d

    @property
    def turbulence_mps2(self) -> tuple[float, float]:
        """The disturbance less its lasting part (level frame, x and y)."""
        return self._axes[0].d - self._lasting[0], self._axes[1].d - self._lasting[1]

    def set_noise(self, noise_x_mps2: float, noise_y_mps2: float, noise_z_mps2: float) -> None:
        """The accelerometers' measured noise (one sample's std); non-finite: kept."""
        for axis, n in zip(self._axes, (noise_x_mps2, noise_y_mps2, noise_z_mps2), strict=True):
            if math.isfinite(n):
                axis.r = max(n, MIN_NOISE_MPS2) ** 2

    def blend(
        self,
        t_ns: int,
        acc_level_mps2: Vec3,
        pitch_rad: float,
        roll_rad: float,
        thrust_up_mps2: float | None = None,
    ) -> Vec3:
        """This sample's level-frame acceleration (FRD): ``a_model + d̂`` per axis.

        ``thrust_up_mps2``: the thrust model's vertical acceleration now (up, gravity
        included: 0 at the hover gas), or None: z as the accelerometer measured it. All
        inputs finite (the estimator checks); times strictly increasing.
        """
        a_tilt = tilt_acceleration(pitch_rad, roll_rad, self._g)
        dt_s = math.inf if self._t_ns is None else (t_ns - self._t_ns) / NS_PER_S
        self._t_ns = t_ns
        fresh = 0.0 < dt_s <= MAX_GAP_S
        model = [a_tilt[0], a_tilt[1], 0.0]
        use_z = thrust_up_mps2 is not None and math.isfinite(thrust_up_mps2)
        if use_z and thrust_up_mps2 is not None:
            model[2] = -thrust_up_mps2  # FRD: down positive
        out = [0.0, 0.0, acc_level_mps2[2]]
        residual: list[float | None] = [None, None, None]
        if fresh and self._q[0] != dt_s:  # 1 - φ², φ = e^(-dt/τ): one exp per new interval
            phi = math.exp(-dt_s / DISTURBANCE_TAU_S)
            self._q = (dt_s, 1.0 - phi * phi)
        for i, axis in enumerate(self._axes):
            if i == 2 and not use_z:
                continue
            measured = acc_level_mps2[i] - model[i]
            residual[i] = measured
            if not fresh or (i == 2 and not self._z_model):
                axis.reset(measured)
            else:
                axis.update(measured, self._q[1])
            out[i] = model[i] + axis.d
        self._z_model = use_z
        self.residual_mps2 = (residual[0] or 0.0, residual[1] or 0.0, residual[2])
        if fresh:
            span = self._lasting_s + dt_s
            w = max(dt_s / span, dt_s / LASTING_TAU_S)  # 1 - e^(-x) ≈ x for dt << 20 s
            for i in (0, 1):
                self._lasting[i] += w * (self._axes[i].d - self._lasting[i])
            self._lasting_s = span
        return out[0], out[1], out[2]
