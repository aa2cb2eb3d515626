"""Command limits (SPEC §4): tilt-norm clamp, angle -> MK counts, gas saturation.

The MK takes signed bytes for nick/roll/yaw and an unsigned byte for gas. §K of the 2011 QUT
CyPhy MikroKopter documentation shows that a negative gas wrapped into that byte sends the
vehicle up at full power, so every conversion here clamps first and then rounds, and refuses
non-finite input with a ``ValueError`` instead of producing a number: the controllers check
finiteness before calling, so reaching that error is a bug, never a command.
"""

from __future__ import annotations

import math

from mkflight.config import ControlConfig
from mkflight.msgs import Command

MK_STICK_LIMIT_COUNTS = 127
"""Largest |nick|, |roll|, |yaw| command we send (signed byte, symmetric)."""


def all_finite(*values: float) -> bool:
    """True if every value is a finite number (not NaN, not +-inf)."""
    return all(map(math.isfinite, values))  # no generator's frame: several times a step


def clamp_norm(x: float, y: float, max_norm: float) -> tuple[float, float, bool]:
    """Scale ``(x, y)`` down to length ``max_norm`` if longer; keeps the direction.

    Returns:
        ``(x, y, clamped)``; ``clamped`` is True if the vector was shortened.
    """
    norm = math.hypot(x, y)
    if norm <= max_norm:
        return x, y, False
    scale = max_norm / norm
    return x * scale, y * scale, True


def counts_from_value(value: float, limit_counts: int) -> int:
    """Round ``value`` to an int after clamping it to ``+-limit_counts``.

    Raises:
        ValueError: ``value`` is NaN or infinite.
    """
    if not math.isfinite(value):
        msg = f"refusing to convert non-finite value {value} into MK counts"
        raise ValueError(msg)
    limit = float(limit_counts)
    clamped = -limit if value < -limit else limit if value > limit else value
    return round(clamped)  # within +-limit_counts: the bound is a whole number


def angle_to_counts(angle_rad: float, sign: int, counts_per_rad: float) -> int:
    """Our angle (SPEC §1) -> MK stick counts: ``sign * angle * counts_per_rad``, +-127.

    ``sign`` is ``mk.signs.<axis>`` (default -1: the MK's nick/roll are the negation of our
    pitch/roll, §B/§C, which divide by the scale factor 120 counts/rad).

    Raises:
        ValueError: ``angle_rad`` is NaN or infinite.
    """
    if not math.isfinite(angle_rad):
        msg = f"refusing to convert non-finite angle {angle_rad} into MK counts"
        raise ValueError(msg)
    value = sign * angle_rad * counts_per_rad
    if math.isinf(value):  # a finite but absurd angle: saturate, keep the sign
        value = math.copysign(float(MK_STICK_LIMIT_COUNTS), value)
    return counts_from_value(value, MK_STICK_LIMIT_COUNTS)


def gas_to_counts(gas: float, gas_max: int) -> int:
    """Gas -> the unsigned gas byte, saturated to ``[0, gas_max]`` (§K: 0..130).

    Never wraps: -5 gives 0, 300 gives ``gas_max``.

    Raises:
        ValueError: ``gas`` is NaN or infinite.
    """
    if not math.isfinite(gas):
        msg = f"refusing to convert non-finite gas {gas} into MK counts"
        raise ValueError(msg)
    clamped = 0.0 if gas < 0.0 else float(gas_max) if gas > gas_max else gas
    return round(clamped)  # within [0, gas_max]: the bounds are whole numbers


TILT_ROUNDING_COUNTS = math.sqrt(0.5)
"""How much rounding nick and roll to whole counts (0.5 each at most) can lengthen the tilt."""


def tilt_limit_counts(control: ControlConfig, counts_per_rad: float) -> float:
    """The longest tilt ``hypot(nick, roll)`` in counts a command may have (SPEC §4).

    ``control.max_tilt_rad * counts_per_rad`` (the clamp on the tilt vector, converted at
    ``mk.counts_per_rad``) plus :data:`TILT_ROUNDING_COUNTS`: 36.7 counts with the
    defaults. The MK's own +-127 per axis is far looser; checking it alone passes every
    signed byte but -128.
    """
    return control.max_tilt_rad * counts_per_rad + TILT_ROUNDING_COUNTS


def command_within_limits(
    cmd: Command, control: ControlConfig, *, counts_per_rad: float | None = None
) -> bool:
    """True if every field of ``cmd`` is an int inside the range SPEC §4 allows.

    nick/roll within +-127, yaw within +-``control.yaw_max_counts``, gas within
    ``[0, control.gas_max]``; with ``counts_per_rad`` (``mk.counts_per_rad``) also the
    configured tilt, ``hypot(nick, roll) <=`` :func:`tilt_limit_counts` (pass it: without
    it nick and roll are held only to the byte's range). ``bool`` is not accepted as an int.
    """
    fields = (cmd.nick_counts, cmd.roll_counts, cmd.yaw_counts, cmd.gas_counts)
    if any(type(v) is not int for v in fields):
        return False
    tilt_counts = math.hypot(cmd.nick_counts, cmd.roll_counts)
    if counts_per_rad is not None and tilt_counts > tilt_limit_counts(control, counts_per_rad):
        return False
    return (
        abs(cmd.nick_counts) <= MK_STICK_LIMIT_COUNTS
        and abs(cmd.roll_counts) <= MK_STICK_LIMIT_COUNTS
        and abs(cmd.yaw_counts) <= control.yaw_max_counts
        and 0 <= cmd.gas_counts <= control.gas_max
    )
