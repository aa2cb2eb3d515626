"""Hover precision from a flight folder: mean, std, RMS and max error.

This is §O-P and TABLE IX of the 2011 QUT CyPhy MikroKopter documentation.

The error is position minus set-point, per axis (x, y in the world frame W, height up;
SPEC §1), over the HOLD phase of the ``step`` events (``events.jsonl``, SPEC §6). The
position is the ground truth of a ``t x y z`` file (z = height up, nearest time within
:data:`TRUTH_TOLERANCE_S`) when one is given, otherwise the flight's own estimate (which
measures how well the controller tracks its estimate, not how well the vehicle holds its
place). As ``mkflight sim hover`` does (:data:`mkflight.sim.hover.SETTLE_S`), samples count
from :data:`SETTLE_S` after HOLD begins, so the take-off's overshoot is not precision.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mkflight.conversions import NS_PER_S
from mkflight.errors import MkflightError
from mkflight.logs.events import Event
from mkflight.logs.schema import Step

SETTLE_S = 3.0
"""Samples count from this long after HOLD begins (as ``sim hover`` measures)."""

TRUTH_TOLERANCE_S = 0.03
"""A truth row is used for a step only if it is this close in time (s)."""

FloatArray = npt.NDArray[np.float64]


class AnalysisInputError(MkflightError):
    """An analysis input (a log or a truth file) is missing, empty or malformed (exit 1)."""


@dataclass(frozen=True, slots=True)
class TableIXRow:
    """One row of TABLE IX (hovering), in m; ``kind`` is ``RMS`` or ``std``."""

    name: str
    kind: str
    x_m: float
    y_m: float
    z_m: float


SEED_TABLE_IX: tuple[TableIXRow, ...] = (
    TableIXRow("MIT (RANGE) 2010", "RMS", 0.06, 0.06, 0.02),
    TableIXRow("GRASP Lab. 2011", "std", 0.0849, 0.0911, 0.0554),
    TableIXRow("ETHZ (ASL) 2011", "RMS", 0.12, 0.12, 0.01),
    TableIXRow("QUT 2011", "std", 0.075368, 0.080849, 0.031913),
)
"""TABLE IX's hovering rows (Freiburg and Oxford give only Error_Z = ±0.1 m)."""


@dataclass(frozen=True, slots=True)
class HoldSamples:
    """The HOLD steps used: time (ns), position and set-point, each (n, 3): x, y, height."""

    t_ns: npt.NDArray[np.int64]
    position_m: FloatArray
    setpoint_m: FloatArray


@dataclass(frozen=True, slots=True)
class AxisStats:
    """Statistics of one axis' error (m): mean, std (population), RMS, max of |error|."""

    mean_m: float
    std_m: float
    rms_m: float
    max_m: float


@dataclass(frozen=True, slots=True)
class Precision:
    """The hover precision: per-axis statistics and the number of samples."""

    x: AxisStats
    y: AxisStats
    z: AxisStats
    samples: int
    source: str

    def as_dict(self) -> dict[str, float | int | str]:
        """The ``--json`` object: ``std_x_m`` ... ``max_z_m``, ``samples``, ``source``."""
        out: dict[str, float | int | str] = {}
        for stat in ("mean", "std", "rms", "max"):
            for axis, s in (("x", self.x), ("y", self.y), ("z", self.z)):
                out[f"{stat}_{axis}_m"] = round(getattr(s, f"{stat}_m"), 6)
        out["samples"] = self.samples
        out["source"] = self.source
        return out


def _num(value: float | None) -> float:
    """A step's number, NaN for null."""
    return math.nan if value is None else value


def hold_samples(events: Sequence[Event], settle_s: float = SETTLE_S) -> HoldSamples:
    """The HOLD ``step`` events from ``settle_s`` after HOLD begins, with the estimate.

    HOLD begins at the first HOLD step with a set-point and a finite estimate (``sim
    hover``: HOLD with a valid pose). A step whose estimate is ``null`` is left out.
    """
    t: list[int] = []
    pos: list[tuple[float, float, float]] = []
    sp: list[tuple[float, float, float]] = []
    start_ns: int | None = None
    for e in events:
        if not isinstance(e, Step) or e.phase != "HOLD":
            continue
        p = (_num(e.x_m), _num(e.y_m), _num(e.height_m))
        s = (_num(e.sp_x_m), _num(e.sp_y_m), _num(e.sp_height_m))
        if not all(math.isfinite(v) for v in (*p, *s)):
            continue
        if start_ns is None:
            start_ns = e.t_ns
        if e.t_ns - start_ns >= settle_s * NS_PER_S:
            t.append(e.t_ns)
            pos.append(p)
            sp.append(s)
    return HoldSamples(
        np.asarray(t, dtype=np.int64),
        np.asarray(pos, dtype=np.float64).reshape(-1, 3),
        np.asarray(sp, dtype=np.float64).reshape(-1, 3),
    )


def parse_truth(text: str, path: str) -> FloatArray:
    """Parse a ``t x y z`` truth file (s, m, m, m; z = height up): an (n, 4) array.

    An optional header line (the first line, if not numbers), blank lines and ``#``
    comments are skipped; rows must be in increasing time.

    Raises:
        AnalysisInputError: a row that is not four finite numbers, time not increasing,
            or no rows; names the file and line.
    """
    rows: list[tuple[float, float, float, float]] = []
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        try:
            values = [float(p) for p in parts]
        except ValueError:
            if line_no == 1:
                continue  # the header
            msg = f"{path}:{line_no}: expected 't x y z' numbers, got {raw.strip()[:80]!r}"
            raise AnalysisInputError(msg) from None
        if len(values) != 4 or not all(math.isfinite(v) for v in values):
            msg = f"{path}:{line_no}: expected 4 finite numbers 't x y z', got {raw.strip()[:80]!r}"
            raise AnalysisInputError(msg)
        if rows and values[0] <= rows[-1][0]:
            msg = f"{path}:{line_no}: time {values[0]} not after the previous {rows[-1][0]}"
            raise AnalysisInputError(msg)
        rows.append((values[0], values[1], values[2], values[3]))
    if not rows:
        msg = f"{path}: no 't x y z' rows"
        raise AnalysisInputError(msg)
    return np.asarray(rows, dtype=np.float64)


def with_truth(
    samples: HoldSamples, truth: FloatArray, tolerance_s: float = TRUTH_TOLERANCE_S
) -> HoldSamples:
    """Replace the estimate by the truth row nearest in time (within ``tolerance_s``).

    Steps with no truth row that close are left out.
    """
    t_s = samples.t_ns.astype(np.float64) / NS_PER_S
    tt = truth[:, 0]
    right = np.clip(np.searchsorted(tt, t_s), 0, len(tt) - 1)
    left = np.clip(right - 1, 0, len(tt) - 1)
    nearest = np.where(np.abs(tt[left] - t_s) <= np.abs(tt[right] - t_s), left, right)
    keep = np.abs(tt[nearest] - t_s) <= tolerance_s
    return HoldSamples(samples.t_ns[keep], truth[nearest[keep], 1:4], samples.setpoint_m[keep])


def _axis(err: FloatArray) -> AxisStats:
    return AxisStats(
        mean_m=float(np.mean(err)),
        std_m=float(np.std(err)),
        rms_m=float(np.sqrt(np.mean(err * err))),
        max_m=float(np.max(np.abs(err))),
    )


def precision(samples: HoldSamples, source: str) -> Precision:
    """Mean, std (population, as TABLE IX's ``Std``), RMS and max |error| per axis.

    Raises:
        AnalysisInputError: no samples.
    """
    n = len(samples.t_ns)
    if n == 0:
        msg = f"no HOLD samples from {SETTLE_S:g} s after HOLD began ({source})"
        raise AnalysisInputError(msg)
    err = samples.position_m - samples.setpoint_m
    return Precision(_axis(err[:, 0]), _axis(err[:, 1]), _axis(err[:, 2]), n, source)


def folder_truth_precision(folder: Path) -> Precision | None:
    """A flight folder's HOLD precision against the simulator's ``truth.txt``, or None.

    None when it cannot be measured: no truth, no HOLD, an unreadable file. What ``fly``
    prints after a simulated flight and ``mkflight flights`` lists.
    """
    from mkflight.logs import events as events_log
    from mkflight.logs.flight import TRUTH

    truth = folder / TRUTH
    if not truth.is_file():
        return None
    try:
        samples = hold_samples(events_log.read_events(folder / events_log.FILE_NAME).events)
        rows = parse_truth(truth.read_text(encoding="utf-8"), str(truth))
        return precision(with_truth(samples, rows), "truth")
    except (AnalysisInputError, MkflightError, OSError, UnicodeDecodeError):
        return None
