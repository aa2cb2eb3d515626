"""Accelerometer scale factor from tilt measurements (§D, eq 7, TABLE I and II).

§D, eq 7 and TABLE I and II are those of the 2011 QUT CyPhy MikroKopter documentation,
which tilts the vehicle to known angles and reads the MK's raw AccNick / AccRoll counts.
A static accelerometer measures gravity's component along its axis, and the MK counts carry
the opposite sign of our angles (SPEC §1), so ``counts = -k·sin(angle)`` with ``k`` in
counts per g. The least-squares ``k`` over all rows is ``k = -Σ c·s / Σ s²`` (s = sin angle).

Input format (pure text, parsed here; the command reads the file): one row per line, two
columns ``angle_deg counts`` separated by spaces, tabs or commas; an optional header line
(a first line with no number in it, e.g. ``angle_deg,counts``); blank lines and ``#``
comments (whole-line or trailing) are ignored.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from mkflight.errors import MkflightError

_SEPARATORS = re.compile(r"[,\s]+")


class CalibrationInputError(MkflightError):
    """A calibration table cannot be used: a malformed row, no rows, no tilted row."""


@dataclass(frozen=True, slots=True)
class CalibrationRow:
    """One measurement: the true tilt angle and the MK's raw count at it.

    Attributes:
        angle_deg: true pitch (or roll) angle in degrees, our sign convention (SPEC §1).
        counts: raw MK accelerometer value (AccNick or AccRoll), MK counts.
        line: 1-based line number in the source, for messages.
    """

    angle_deg: float
    counts: float
    line: int


@dataclass(frozen=True, slots=True)
class AccFit:
    """The least-squares fit of ``counts = -k·sin(angle)`` (eq 7).

    Attributes:
        k_counts_per_g: scale factor, MK counts per g (§D: 606.3 nick, 603.44 roll).
        residual_rms_counts: root mean square of the per-row errors, counts.
        rows: the rows fitted, in input order.
        errors_counts: per row, measured minus fitted counts.
    """

    k_counts_per_g: float
    residual_rms_counts: float
    rows: tuple[CalibrationRow, ...]
    errors_counts: tuple[float, ...]

    def fitted_counts(self, row: CalibrationRow) -> float:
        """The model's counts at ``row``'s angle: ``-k·sin(angle)``."""
        return -self.k_counts_per_g * math.sin(math.radians(row.angle_deg))


def _number(token: str) -> float | None:
    try:
        value = float(token)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def parse_rows(text: str, source: str) -> list[CalibrationRow]:
    """Parse a calibration table (format in the module docstring).

    Args:
        text: the file's contents.
        source: the file's name, used in error messages.

    Returns:
        The rows in input order (possibly empty).

    Raises:
        CalibrationInputError: a row that is not exactly two finite numbers; the message
            names ``source`` and the line number.
    """
    rows: list[CalibrationRow] = []
    seen_content = False
    for number, raw in enumerate(text.splitlines(), start=1):
        content = raw.split("#", 1)[0].strip()
        if not content:
            continue
        fields = _SEPARATORS.split(content)
        values = [_number(f) for f in fields]
        first = not seen_content
        seen_content = True
        if first and not any(_is_numeric(f) for f in fields):
            continue  # the optional header line
        if len(fields) != 2 or values[0] is None or values[1] is None:
            msg = (
                f"{source}:{number}: malformed row {raw.strip()!r}: expected two finite "
                "numbers 'angle_deg counts' separated by spaces, tabs or a comma"
            )
            raise CalibrationInputError(msg)
        rows.append(CalibrationRow(angle_deg=values[0], counts=values[1], line=number))
    return rows


def _is_numeric(token: str) -> bool:
    """Whether ``token`` is any float literal, including nan/inf (not a header word)."""
    try:
        float(token)
    except ValueError:
        return False
    return True


def fit_acc_scale(rows: Sequence[CalibrationRow], source: str = "table") -> AccFit:
    """Least-squares ``k`` of ``counts = -k·sin(angle)`` over all rows (eq 7).

    Args:
        rows: the measurements (every row counts once; TABLE I and II's printed "Mean" rows are
            not measurements and should not be included).
        source: the data's name, used in error messages.

    Returns:
        ``k`` (counts/g), the residual RMS (counts) and the per-row errors.

    Raises:
        CalibrationInputError: no rows, or no row with a non-zero angle (k undefined).
    """
    if not rows:
        msg = f"{source}: no data rows (expected lines of 'angle_deg counts')"
        raise CalibrationInputError(msg)
    sines = [math.sin(math.radians(r.angle_deg)) for r in rows]
    sum_ss = math.fsum(s * s for s in sines)
    if sum_ss < 1e-12:
        msg = f"{source}: every row is at 0 degrees: the scale factor needs tilted rows"
        raise CalibrationInputError(msg)
    k = -math.fsum(r.counts * s for r, s in zip(rows, sines, strict=True)) / sum_ss
    errors = tuple(r.counts + k * s for r, s in zip(rows, sines, strict=True))
    rms = math.sqrt(math.fsum(e * e for e in errors) / len(errors))
    return AccFit(
        k_counts_per_g=k,
        residual_rms_counts=rms,
        rows=tuple(rows),
        errors_counts=errors,
    )
