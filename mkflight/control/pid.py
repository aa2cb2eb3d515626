"""A small pure PID (eq 24-25; SPEC §4 "all PIDs").

Eq 24-25 are those of the 2011 QUT CyPhy MikroKopter documentation.

* Derivative on the measurement, not on the error, so a set-point step never kicks the
  output: ``d = -kd * dmeasurement/dt`` (or ``-kd * rate`` when the caller has a measured
  rate, e.g. the estimator's velocity as the derivative of position, like PX4).
* The integral is kept in output units (``ki * sum(e * dt)``) and clamped to
  ``+-integral_limit``, separately from the output clamp ``[output_min, output_max]``.
* Optional anti-windup (conditional integration): no integration while the output is
  saturated and the error would push it further into the same limit.
* ``dt_s`` comes from timestamps; ``dt_s <= 0`` or non-finite means no integration and no
  derivative on that step (the proportional part still acts).
* NaN never enters the state: a non-finite error, measurement, rate or feed-forward
  leaves the state unchanged and gives ``valid=False`` with ``output = NaN``. The caller
  must not send anything made from an invalid result (SPEC §5 row 1).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import msgspec

from mkflight.frames import wrap_pi


@dataclass(frozen=True, slots=True)
class PidGains:
    """Gains and limits of one PID loop.

    Attributes:
        kp: proportional gain (output units per error unit).
        ki: integral gain (output units per error unit per second).
        kd: derivative gain (output units per measurement unit per second).
        integral_limit: bound on the integral term, in output units (>= 0).
        output_min: lower output clamp, applied to feed-forward + P + I + D.
        output_max: upper output clamp.
        anti_windup: stop integrating while saturated in the error's direction.
        angle: the measurement is an angle: its step-to-step difference is wrapped to
            (-pi, pi] before differentiating (yaw, eq 24).
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    integral_limit: float = math.inf
    output_min: float = -math.inf
    output_max: float = math.inf
    anti_windup: bool = True
    angle: bool = False


class PidState(msgspec.Struct, gc=False):
    """What a PID remembers: the integral term (output units) and the last measurement.

    Never changed once built; a plain Struct, untracked by the garbage collector (it holds
    two numbers): seven are built a step.
    """

    integral: float = 0.0
    prev_measurement: float | None = None


class PidResult(msgspec.Struct, gc=False):
    """One PID step's output, its parts and the next state.

    ``valid`` is False iff an input was non-finite; then ``output``, ``p``, ``i``, ``d`` are
    NaN, ``saturation`` is 0 and ``state`` is the unchanged input state.
    ``saturation`` is -1/+1 when the output was clamped at its lower/upper limit.
    """

    output: float
    state: PidState
    p: float
    i: float
    d: float
    saturation: int
    valid: bool


_Build = TypeVar("_Build", bound=Callable[..., "PidGains"])
_MEMO_SIZE = 32


def gains_of_config(build: _Build) -> _Build:
    """``build(config, *numbers)`` remembered per config object (and numbers).

    The gains are a pure function of a frozen config, asked for on every step: the same
    object gives the same gains. The config is kept with them, so that its id is not
    reused while remembered; a few configs at most (tests make many: the oldest go).
    """
    memo: dict[tuple[Any, ...], tuple[object, PidGains]] = {}

    @functools.wraps(build)
    def gains(cfg: object, *args: Any) -> PidGains:
        key = (id(cfg), *args)
        hit = memo.get(key)
        if hit is not None and hit[0] is cfg:
            return hit[1]
        if len(memo) >= _MEMO_SIZE:
            del memo[next(iter(memo))]
        g = build(cfg, *args)
        memo[key] = (cfg, g)
        return g

    return cast("_Build", gains)


def clamp(value: float, lo: float, hi: float) -> float:
    """``value`` limited to ``[lo, hi]`` (finite ``value`` assumed)."""
    return lo if value < lo else hi if value > hi else value


def _invalid(state: PidState) -> PidResult:
    nan = math.nan
    return PidResult(nan, state, nan, nan, nan, 0, valid=False)


def pid_update(
    gains: PidGains,
    state: PidState,
    *,
    error: float,
    measurement: float,
    dt_s: float,
    rate: float | None = None,
    feedforward: float = 0.0,
) -> PidResult:
    """Advance one PID step (eq 24-25 with derivative on measurement).

    Args:
        gains: the loop's gains and limits.
        state: the state returned by the previous step (``PidState()`` to start).
        error: set-point minus measurement (already wrapped for angles).
        measurement: the measured value; its change gives the derivative.
        dt_s: seconds since the previous step, from timestamps.
        rate: the measurement's time derivative if measured directly; then the
            derivative term is ``-kd * rate`` and ``dt_s`` is not needed for it.
        feedforward: added to P + I + D before the output clamp (e.g. hover gas).

    Returns:
        The clamped output and its parts; ``valid=False`` (state unchanged, NaN output)
        if ``error``, ``measurement``, ``rate`` or ``feedforward`` is non-finite.
    """
    isfinite = math.isfinite
    if not (isfinite(error) and isfinite(measurement) and isfinite(feedforward)):
        return _invalid(state)
    if rate is not None and not isfinite(rate):
        return _invalid(state)
    dt_ok = dt_s > 0.0 and isfinite(dt_s)
    kp, ki, kd, lo, hi = gains.kp, gains.ki, gains.kd, gains.output_min, gains.output_max

    p = kp * error
    d = 0.0
    if kd != 0.0:
        if rate is not None:
            d = -kd * rate
        elif dt_ok and state.prev_measurement is not None:
            delta = measurement - state.prev_measurement
            if gains.angle:
                delta = wrap_pi(delta)
            d = -kd * delta / dt_s
        if not isfinite(d):  # an absurdly small dt_s: drop the derivative, keep the state clean
            d = 0.0

    integral = state.integral
    if dt_ok and ki != 0.0:
        unsat = feedforward + p + integral + d
        step = ki * error * dt_s
        blocked = gains.anti_windup and (
            (unsat >= hi and step > 0.0) or (unsat <= lo and step < 0.0)
        )
        if not blocked and isfinite(step):
            integral = clamp(integral + step, -gains.integral_limit, gains.integral_limit)

    raw = feedforward + p + integral + d
    if not isfinite(raw):  # finite inputs, overflowing gains: refuse rather than clamp
        return _invalid(state)
    output = lo if raw < lo else hi if raw > hi else raw
    saturation = 1 if raw > hi else -1 if raw < lo else 0
    return PidResult(output, PidState(integral, measurement), p, integral, d, saturation, True)


def pid_reset(integral: float = 0.0) -> PidState:
    """A fresh state, optionally pre-loading the integral (bumpless hand-over)."""
    return PidState(integral=integral if math.isfinite(integral) else 0.0)
