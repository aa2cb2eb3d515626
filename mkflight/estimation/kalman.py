"""One axis of the estimator's Kalman filter: position, velocity and disturbance (SPEC §3).

The complementary filter of the 2011 QUT CyPhy MikroKopter documentation (eq 15-17) blends
the laser's velocity — the difference of two poses, so the pose noise times √2 / 0.1 s —
with the integrated acceleration at a fixed gain k. On a MikroKopter whose accelerometers
carry the motors' vibration (5-30 AccNick counts) no fixed k is right: a high one lets the
differenced poses' noise through, a low one the integrated vibration. This filter takes each
source for what it is worth, with a gain from the noise *measured in flight*:

* state ``(p, v, d)`` per axis: position, velocity and the disturbance ``d`` — the
  acceleration the model misses (gusts, drag, the learned hover gas's error);
* the model's acceleration ``a`` (the attitude's ``-g tan θ`` and ``g tan φ / cos θ``, the
  thrust model vertically: :mod:`mkflight.estimation.tilt_accel`) is the known input:
  ``p' = p + v T + (a + d) T²/2``, ``v' = v + (a + d) T`` (eq 15-17 with ``a + d``);
  ``d`` is a random walk that moves per step as much as turbulence of the envelope's
  strength and time scale does (no pull towards 0: a lasting push is followed in full),
  and ``a`` itself is uncertain by white noise of ``model_std`` (the attitude's noise, the
  thrust's answer to the gas);
* measurements: the accelerometers' residual ``a_meas - a`` = ``d`` + vibration (each
  DebugOut sample, the vibration's variance as measured), and the laser's position (each
  scan, at the scan's time: the estimator replays the samples since), or the hat height.

With quiet accelerometers ``d`` follows them closely; with a worn prop the filter leans
on the model and the laser. The covariance is kept per axis as the six numbers of a
symmetric 3 x 3 matrix; pure functions of floats, no NumPy (a 3 x 3 in Python is faster than
NumPy's call overhead, and this runs at 20 Hz on a 1 GHz ARM board). The step's clamps are
conditional expressions in ``max``/``min``'s own order (so the same value for every input,
NaN included): a call of the builtins costs several times more, and they ran ~60 times a
step.
"""

from __future__ import annotations

import math
from typing import Final

import msgspec

JUMP_SIGMAS: Final = 10.0
JUMP_M: Final = 0.05
"""A position innovation beyond both ``JUMP_SIGMAS`` standard deviations and ``JUMP_M``
is a jump: the position is reset to the measurement (:func:`update_position`)."""
MIN_GATE_MPS2: Final = 1.0
"""An acceleration residual counts at most ``gate_sigmas`` standard deviations from the
expectation, and never less than this: a jolt (a landing gear's, a hand's) is clipped."""


class AxisNoise(msgspec.Struct, frozen=True, gc=False):
    """The noises of one axis (standard deviations; SI units).

    ``disturbance_std``/``disturbance_tau_s``: how strong and how quick the disturbance is
    (the random walk moves ``std·√(1 - e^(-2T/τ))`` per step of T); ``model_std``: white
    noise on the model's acceleration; ``acc_std``: one accelerometer sample's noise (the
    vibration measured in flight); ``gate_sigmas``: the residual's clipping.
    """

    disturbance_std: float
    disturbance_tau_s: float
    model_std: float
    acc_std: float
    gate_sigmas: float = 4.0


class AxisState(msgspec.Struct, gc=False):
    """``(p, v, d)`` and its covariance ``(pp, pv, pd, vv, vd, dd)`` (SI, one axis).

    Never changed once built (a new state per step); a plain Struct because it is built
    several times a step, and untracked by the garbage collector (it holds only floats).
    """

    p: float
    v: float
    d: float
    pp: float
    pv: float
    pd: float
    vv: float
    vd: float
    dd: float

    @classmethod
    def start(cls, p: float, p_std: float, v: float, v_std: float, d_std: float) -> AxisState:
        """A state known to these standard deviations, no disturbance, uncorrelated."""
        return cls(p, v, 0.0, p_std * p_std, 0.0, 0.0, v_std * v_std, 0.0, d_std * d_std)

    def finite(self) -> bool:
        """Every number finite.

        Their sum is: a NaN or an infinity carries through it, and a sum beyond 1e308 is
        as unusable.
        """
        return math.isfinite(
            self.p + self.v + self.d + self.pp + self.pv + self.pd + self.vv + self.vd + self.dd
        )


def predict(s: AxisState, a: float, dt_s: float, noise: AxisNoise) -> AxisState:
    """Step ``s`` by ``dt_s`` with the model's acceleration ``a`` held over the interval.

    ``F = [[1, T, T²/2], [0, 1, T], [0, 0, 1]]``, ``P' = F P Fᵀ + Q`` with ``Q`` the model's
    white acceleration (integrated over T) and the disturbance's random-walk step.
    """
    t = dt_s
    h = 0.5 * t * t
    acc = a + s.d
    pp, pv, pd, vv, vd, dd = s.pp, s.pv, s.pd, s.vv, s.vd, s.dd
    w = noise.model_std * noise.model_std  # white acceleration, held over T
    phi2 = math.exp(-2.0 * t / noise.disturbance_tau_s)
    qd = noise.disturbance_std**2 * (1.0 - phi2)
    return AxisState(
        s.p + s.v * t + h * acc,
        s.v + acc * t,
        s.d,
        pp + 2.0 * t * pv + 2.0 * h * pd + t * t * vv + 2.0 * t * h * vd + h * h * dd + w * h * h,
        pv + t * pd + t * vv + (t * t + h) * vd + h * t * dd + w * h * t,
        pd + t * vd + h * dd,
        vv + 2.0 * t * vd + t * t * dd + w * t * t,
        vd + t * dd,
        dd + qd,
    )


def _correct(
    s: AxisState, innovation: float, var: float, row: tuple[float, float, float]
) -> AxisState:
    """The Kalman update for a measurement of one state.

    ``row`` is that state's row of the covariance (``P Hᵀ``), ``var`` the innovation's
    variance (``H P Hᵀ + R``): ``x += K·innovation`` and ``P -= K·rowᵀ``, ``K = row / var``.
    """
    r0, r1, r2 = row
    kp, kv, kd = r0 / var, r1 / var, r2 / var
    return AxisState(
        s.p + kp * innovation,
        s.v + kv * innovation,
        s.d + kd * innovation,
        s.pp - kp * r0,
        s.pv - kp * r1,
        s.pd - kp * r2,
        s.vv - kv * r1,
        s.vd - kv * r2,
        s.dd - kd * r2,
    )


def update_acceleration(s: AxisState, residual: float, noise: AxisNoise) -> AxisState:
    """Correct ``s`` with one accelerometer residual ``a_meas - a`` (measures ``d``)."""
    var = s.dd + noise.acc_std * noise.acc_std
    limit = max(noise.gate_sigmas * math.sqrt(var), MIN_GATE_MPS2)
    innovation = max(-limit, min(limit, residual - s.d))
    return _correct(s, innovation, var, (s.pd, s.vd, s.dd))


def predict_update(
    s: AxisState, a: float, dt_s: float, noise: AxisNoise, residual: float | None
) -> AxisState:
    """:func:`predict`, then :func:`update_acceleration` with ``residual`` (None: none).

    The same arithmetic in the same order, so the same numbers to the bit, with one state
    built instead of two: the estimator runs this for every axis of every knot it
    (re)computes, several times a step.
    """
    t = dt_s
    h = 0.5 * t * t
    d = s.d
    acc = a + d
    pp, pv, pd, vv, vd, dd = s.pp, s.pv, s.pd, s.vv, s.vd, s.dd
    w = noise.model_std * noise.model_std  # white acceleration, held over T
    phi2 = math.exp(-2.0 * t / noise.disturbance_tau_s)
    qd = noise.disturbance_std**2 * (1.0 - phi2)
    p1 = s.p + s.v * t + h * acc
    v1 = s.v + acc * t
    pp1 = pp + 2.0 * t * pv + 2.0 * h * pd + t * t * vv + 2.0 * t * h * vd + h * h * dd + w * h * h
    pv1 = pv + t * pd + t * vv + (t * t + h) * vd + h * t * dd + w * h * t
    pd1 = pd + t * vd + h * dd
    vv1 = vv + 2.0 * t * vd + t * t * dd + w * t * t
    vd1 = vd + t * dd
    dd1 = dd + qd
    if residual is None:
        return AxisState(p1, v1, d, pp1, pv1, pd1, vv1, vd1, dd1)
    var = dd1 + noise.acc_std * noise.acc_std
    gate = noise.gate_sigmas * math.sqrt(var)
    limit = MIN_GATE_MPS2 if gate < MIN_GATE_MPS2 else gate  # max(gate, MIN_GATE_MPS2)
    r = residual - d
    r = r if r < limit else limit  # max(-limit, min(limit, r)), as the builtins order it
    innovation = r if r > -limit else -limit
    kp, kv, kd = pd1 / var, vd1 / var, dd1 / var  # _correct with the row (pd, vd, dd)
    return AxisState(
        p1 + kp * innovation,
        v1 + kv * innovation,
        d + kd * innovation,
        pp1 - kp * pd1,
        pv1 - kp * vd1,
        pd1 - kp * dd1,
        vv1 - kv * vd1,
        vd1 - kv * dd1,
        dd1 - kd * dd1,
    )


def is_jump(innovation: float, var: float) -> bool:
    """``innovation`` (of variance ``var``) is a jump, not noise (:data:`JUMP_SIGMAS`)."""
    gate = JUMP_SIGMAS * math.sqrt(var)
    return abs(innovation) > (gate if gate > JUMP_M else JUMP_M)  # max(JUMP_M, gate)


def update_position(s: AxisState, z: float, std: float) -> AxisState:
    """Correct ``s`` with a position measurement ``z`` of noise ``std`` (laser, hat).

    A jump (:func:`is_jump`) is not weighed but taken: the position becomes ``z`` (the
    velocity and the disturbance stay), as the complementary filter would take it. A
    hat over a table's edge or the original system's tables' take-off step must not become a
    velocity of metres per second.
    """
    var = s.pp + std * std
    innovation = z - s.p
    gate = JUMP_SIGMAS * math.sqrt(var)  # is_jump and _correct written out: 3 calls a scan
    if abs(innovation) > (gate if gate > JUMP_M else JUMP_M):
        return AxisState(z, s.v, s.d, std * std, 0.0, 0.0, s.vv, s.vd, s.dd)
    pp, pv, pd = s.pp, s.pv, s.pd  # the row P Hᵀ
    kp, kv, kd = pp / var, pv / var, pd / var
    return AxisState(
        s.p + kp * innovation,
        s.v + kv * innovation,
        s.d + kd * innovation,
        pp - kp * pp,
        pv - kp * pv,
        pd - kp * pd,
        s.vv - kv * pv,
        s.vd - kv * pd,
        s.dd - kd * pd,
    )


__all__ = [
    "AxisNoise",
    "AxisState",
    "is_jump",
    "predict",
    "predict_update",
    "update_acceleration",
    "update_position",
]
