"""Yaw hold (SPEC §4; §J eq 24): PID on the wrapped heading error -> MK yaw counts.

§J and eq 24 are those of the 2011 QUT CyPhy MikroKopter documentation. The MK's yaw input
is a RATE stick, so the PID's output is a rate command in counts (``kp_yaw`` counts/rad).
Our psi is clockwise (nose right positive) and the MK's yaw the opposite (SPEC §1), hence
``counts = mk.signs.yaw * u`` with the default sign -1. The error ``wrap_pi(psi* - psi)``
takes the short way round (179 deg vs -179 deg is -2 deg), and the derivative wraps the
measurement's step too, so crossing +-pi never kicks.
"""

from __future__ import annotations

import msgspec

from mkflight.config import ControlConfig, MkConfig
from mkflight.control.limits import all_finite, counts_from_value
from mkflight.control.pid import PidGains, PidState, gains_of_config, pid_update
from mkflight.frames import wrap_pi


class YawResult(msgspec.Struct, frozen=True, gc=False):
    """One yaw step: the wrapped error, the rate command (our sign) and the MK counts."""

    error_rad: float
    rate_cmd_counts: float
    yaw_counts: int
    state: PidState


@gains_of_config
def yaw_gains(control: ControlConfig) -> PidGains:
    """Eq 24's gains; output and integral within +-``control.yaw_max_counts``."""
    lim = float(control.yaw_max_counts)
    return PidGains(
        kp=control.kp_yaw,
        ki=control.ki_yaw,
        kd=control.kd_yaw,
        integral_limit=lim,
        output_min=-lim,
        output_max=lim,
        angle=True,
    )


def yaw_step(
    control: ControlConfig,
    mk: MkConfig,
    state: PidState,
    *,
    yaw_sp_rad: float,
    yaw_rad: float,
    dt_s: float,
) -> YawResult | None:
    """One yaw PID step (eq 24, ``e = wrap_pi(psi* - psi)``).

    Returns:
        The result, or None if ``yaw_sp_rad`` or ``yaw_rad`` is non-finite (state unchanged).
    """
    if not all_finite(yaw_sp_rad, yaw_rad):
        return None
    error = wrap_pi(yaw_sp_rad - yaw_rad)
    res = pid_update(yaw_gains(control), state, error=error, measurement=yaw_rad, dt_s=dt_s)
    if not res.valid:
        return None
    counts = counts_from_value(mk.signs.yaw * res.output, control.yaw_max_counts)
    return YawResult(error, res.output, counts, res.state)
