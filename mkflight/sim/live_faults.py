"""The live simulator's fault schedule: ``KIND@T[:ARG]`` strings (``mkflight sim --fault``).

:data:`FAULT_KINDS` lists the kinds and their arguments; :func:`parse_fault` turns a
string into a :class:`Fault` (``KIND:ARG@T`` is accepted too) or a
:class:`~mkflight.errors.ConfigError` naming the string and the valid kinds;
:func:`parse_faults` orders a schedule by time. :class:`~mkflight.sim.live.LiveSim` fires
them through the emulators' own fault methods.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from mkflight.conversions import NS_PER_S
from mkflight.errors import ConfigError
from mkflight.sim.fc import DEFAULT_BOOT_NS


@dataclass(frozen=True, slots=True)
class FaultKind:
    """One fault kind: its argument's name and type, and whether it must be given."""

    arg_name: str | None = None
    integer: bool = False
    required: bool = True
    default: float | None = None

    def usage(self, kind: str) -> str:
        """``kind``, ``kind:ARG`` or ``kind[:ARG]``."""
        if self.arg_name is None:
            return kind
        return f"{kind}:{self.arg_name}" if self.required else f"{kind}[:{self.arg_name}]"


FAULT_KINDS: Final[dict[str, FaultKind]] = {
    "fc-vanish": FaultKind(),  # the FC's USB adapter is pulled
    "fc-replug": FaultKind(),  # ... and plugged back in
    "fc-silent": FaultKind("DUR_S"),  # the FC's TX line is dead for DUR_S
    "fc-reboot": FaultKind("BOOT_S", required=False, default=DEFAULT_BOOT_NS / NS_PER_S),
    "fc-garbage": FaultKind("NBYTES", integer=True),  # random bytes before the next frame
    "fc-corrupt": FaultKind("NFRAMES", integer=True),  # the next frames with a bad CRC
    "laser-vanish": FaultKind(),
    "laser-replug": FaultKind(),  # a USB-powered URG restarts (SCIP 1.1, timer 0)
    "laser-stall": FaultKind("DUR_S"),  # no scans for DUR_S, commands still answered
    "laser-garbage": FaultKind("NBYTES", integer=True),  # random bytes and a LF
    "laser-badsum": FaultKind("NSCANS", integer=True),  # the next replies with a bad sum
    "battery": FaultKind("VOLTS"),  # the FC reads VOLTS from then on
    "pilot-nick": FaultKind("COUNTS", integer=True),  # the pilot moves the nick stick
}
_FORMAT: Final = "KIND@T[:ARG] (T: seconds after the start)"


def _valid_kinds() -> str:
    return ", ".join(spec.usage(kind) for kind, spec in FAULT_KINDS.items())


@dataclass(frozen=True, slots=True)
class Fault:
    """A fault to inject ``at_s`` seconds after the start; ``arg`` as :data:`FAULT_KINDS`."""

    at_s: float
    kind: str
    arg: float | None = None

    def __str__(self) -> str:
        """The canonical ``KIND@T[:ARG]`` text."""
        if self.arg is None:
            return f"{self.kind}@{self.at_s:g}"
        return f"{self.kind}@{self.at_s:g}:{self.arg:g}"


def parse_fault(text: str) -> Fault:
    """Parse ``KIND@T[:ARG]`` (or ``KIND:ARG@T``): e.g. ``laser-stall@5:1.5``.

    Raises:
        ConfigError: not that form, an unknown kind, a missing, extra or out-of-range
            argument, or a negative or non-finite time; names the string and the valid
            kinds.
    """
    result = _parse(text)
    if isinstance(result, str):
        msg = f"fault {text!r}: {result}; format {_FORMAT}, kinds: {_valid_kinds()}"
        raise ConfigError(msg)
    return result


def _parse(text: str) -> Fault | str:
    """The fault, or what is wrong with ``text``."""
    left, at, right = text.strip().partition("@")
    if not at:
        return "no '@T'"
    kind, _, arg_left = left.partition(":")
    t_text, _, arg_right = right.partition(":")
    if arg_left and arg_right:
        return "two arguments"
    spec = FAULT_KINDS.get(kind)
    if spec is None:
        return f"unknown kind {kind!r}"
    try:
        at_s = float(t_text)
    except ValueError:
        return f"time {t_text!r} is not a number"
    if not (math.isfinite(at_s) and at_s >= 0.0):
        return f"time {t_text!r} must be finite and >= 0"
    arg_text = arg_left or arg_right
    if spec.arg_name is None:
        return f"{kind} takes no argument" if arg_text else Fault(at_s, kind)
    if not arg_text:
        return f"{kind} needs {spec.arg_name}" if spec.required else Fault(at_s, kind, spec.default)
    try:
        arg = float(int(arg_text)) if spec.integer else float(arg_text)
    except ValueError:
        return f"{spec.arg_name} {arg_text!r} is not {'an integer' if spec.integer else 'a number'}"
    zero_ok = spec.arg_name == "VOLTS"
    if not math.isfinite(arg) or arg < 0.0 or (arg == 0.0 and not zero_ok):
        return f"{spec.arg_name} {arg_text!r} must be finite and {'>=' if zero_ok else '>'} 0"
    return Fault(at_s, kind, arg)


def parse_faults(items: Iterable[Fault | str]) -> list[Fault]:
    """Parse every string (see :func:`parse_fault`); all ordered by time (stable).

    Raises:
        ConfigError: the first bad string.
    """
    faults = (f if isinstance(f, Fault) else parse_fault(f) for f in items)
    return sorted(faults, key=lambda f: f.at_s)


__all__ = ["FAULT_KINDS", "Fault", "FaultKind", "parse_fault", "parse_faults"]
