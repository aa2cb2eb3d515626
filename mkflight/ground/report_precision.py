"""The report's hover precision beside the original paper's TABLE IX (§O-P).

The figures are :mod:`mkflight.analysis.precision`'s, as ``mkflight analyze precision``
prints them: the error is position minus set-point over the HOLD ``step`` events from
3 s after HOLD began, against the flight's estimate and, when the folder has the
simulator's ``truth.txt``, against the truth. TABLE IX's rows are given as the paper
gives them: RMS for MIT and ETHZ, std for GRASP and QUT.
"""

from __future__ import annotations

from dataclasses import dataclass
from html import escape

import numpy as np

from mkflight.analysis.precision import (
    SEED_TABLE_IX,
    SETTLE_S,
    AnalysisInputError,
    HoldSamples,
    Precision,
    hold_samples,
    precision,
    with_truth,
)
from mkflight.ground.report_html import Cell, CellLike, missing, num, para, section, table
from mkflight.ground.report_timeline import nice_ticks
from mkflight.logs.flight import FlightData
from mkflight.logs.schema import FlightSummary

#: This flight's figures are shown to 0.1 mm; TABLE IX's as the paper prints them.
PRECISION_SPEC = ".4f"
STATS = ("std", "rms", "mean", "max")
_STAT_NAME = {"std": "std", "rms": "RMS", "mean": "mean", "max": "max |err|"}


@dataclass(frozen=True, slots=True)
class HoverPrecision:
    """The flight's precision against its estimate and against the truth; why one is missing.

    ``estimate`` or ``truth`` is None when it cannot be measured; ``*_missing`` then says why.
    """

    estimate: Precision | None
    truth: Precision | None
    estimate_missing: str
    truth_missing: str


def _truth_samples(flight: FlightData, samples: HoldSamples) -> HoldSamples:
    """The HOLD samples with the truth's position (nearest row; times on ``t_s``'s axis)."""
    assert flight.truth is not None
    shifted = HoldSamples(
        samples.t_ns - (flight.t0_ns or 0), samples.position_m, samples.setpoint_m
    )
    rows = np.column_stack([flight.truth[k] for k in ("t_s", "x_m", "y_m", "height_m")]).astype(
        np.float64
    )
    return with_truth(shifted, rows.reshape(-1, 4))


def hover_precision(flight: FlightData) -> HoverPrecision:
    """Measure the HOLD precision of ``flight`` (module docstring)."""
    samples = hold_samples(flight.events)
    estimate: Precision | None = None
    truth: Precision | None = None
    estimate_missing = truth_missing = ""
    try:
        estimate = precision(samples, "estimate")
    except AnalysisInputError as err:
        estimate_missing = f"no hover precision: {err}"
        if not flight.events:
            estimate_missing = (
                "no hover precision: the folder has no events.jsonl (the HOLD steps and "
                "set-points are in it)"
            )
    if estimate is None:
        pass  # no HOLD steps: nothing to hold the truth against either
    elif flight.truth is None:
        truth_missing = "no truth.txt in the folder (a real flight): precision of the estimate only"
    else:
        try:
            truth = precision(_truth_samples(flight, samples), "truth")
        except AnalysisInputError as err:
            truth_missing = f"truth.txt has no row near the HOLD steps: {err}"
    return HoverPrecision(estimate, truth, estimate_missing, truth_missing)


def _rows(label: str, p: Precision) -> list[list[CellLike]]:
    rows: list[list[CellLike]] = []
    for stat in STATS:
        values = [getattr(a, f"{stat}_m") for a in (p.x, p.y, p.z)]
        rows.append(
            [
                Cell(label),
                Cell(_STAT_NAME[stat]),
                *(num(v, PRECISION_SPEC) for v in values),
                num(p.samples),
            ]
        )
    return rows


_AXIS_COLOURS = (("x", "#1f77b4"), ("y", "#ff7f0e"), ("z", "#2ca02c"))
_BAR_H = 8.0
_LABEL_W = 250.0
_CHART_W = 900.0  # as wide as the CSS shows it: one unit a pixel


def _bar_rows(hp: HoverPrecision) -> list[tuple[str, tuple[float, float, float], bool]]:
    """Each bar group: its label, the x, y, z values (m), and whether it is this flight's."""
    rows: list[tuple[str, tuple[float, float, float], bool]] = []
    for label, p in (("this flight, truth", hp.truth), ("this flight, estimate", hp.estimate)):
        if p is not None:
            rows.append((f"{label} (std)", (p.x.std_m, p.y.std_m, p.z.std_m), True))
    rows += [(f"{r.name} ({r.kind})", (r.x_m, r.y_m, r.z_m), False) for r in SEED_TABLE_IX]
    return rows


def precision_svg(hp: HoverPrecision) -> str:
    """This flight's std per axis as bars beside TABLE IX's, on one scale in m."""
    rows = _bar_rows(hp)
    top_m = max(max(v) for _, v, _ in rows) * 1.05
    group_h = 3 * _BAR_H + 8.0
    height = 30.0 + group_h * len(rows) + 24.0
    scale = (_CHART_W - _LABEL_W - 20.0) / top_m
    parts = [
        f'<svg viewBox="0 0 {_CHART_W:.0f} {height:.0f}" class="bars" role="img" '
        'aria-label="hover precision beside TABLE IX" font-family="sans-serif" font-size="13">'
    ]
    for i, (axis, colour) in enumerate(_AXIS_COLOURS):
        x = _LABEL_W + 60.0 * i
        parts.append(
            f'<rect x="{x:.0f}" y="6" width="10" height="10" fill="{colour}"/>'
            f'<text x="{x + 14:.0f}" y="15">{axis}</text>'
        )
    axis_y = 30.0 + group_h * len(rows)
    for tick_m in nice_ticks(0.0, top_m):
        x = _LABEL_W + tick_m * scale
        parts.append(
            f'<line x1="{x:.1f}" y1="26" x2="{x:.1f}" y2="{axis_y:.1f}" stroke="#dddddd"/>'
            f'<text x="{x:.1f}" y="{axis_y + 16:.1f}" text-anchor="middle">'
            f"{tick_m:g}</text>"
        )
    for g, (label, values, mine) in enumerate(rows):
        y0 = 30.0 + g * group_h
        weight = ' font-weight="bold"' if mine else ""
        parts.append(
            f'<text x="{_LABEL_W - 8}" y="{y0 + 1.5 * _BAR_H + 4:.1f}" text-anchor="end"'
            f"{weight}>{escape(label)}</text>"
        )
        for k, ((axis, colour), v) in enumerate(zip(_AXIS_COLOURS, values, strict=True)):
            y = y0 + k * _BAR_H
            parts.append(
                f'<rect x="{_LABEL_W}" y="{y:.1f}" width="{max(v * scale, 0.5):.1f}" '
                f'height="{_BAR_H - 1}" fill="{colour}"><title>'
                f"{escape(f'{label} {axis}: {v:g} m')}</title></rect>"
            )
    parts.append(
        f'<text x="{_LABEL_W - 18}" y="{axis_y + 16:.1f}" text-anchor="end">m</text></svg>'
    )
    return "".join(parts)


def precision_section(flight: FlightData, hp: HoverPrecision) -> str:
    """The section: this flight's rows (truth, estimate), then TABLE IX's hovering rows."""
    rows: list[list[CellLike]] = []
    classes: list[str] = []
    for label, p in (("this flight, truth", hp.truth), ("this flight, estimate", hp.estimate)):
        if p is not None:
            rows += _rows(label, p)
            classes += ["mine"] * len(STATS)
    for r in SEED_TABLE_IX:
        rows.append(
            [Cell(r.name), Cell(r.kind), *(num(v, "g") for v in (r.x_m, r.y_m, r.z_m)), Cell("")]
        )
        classes.append("")
    body = [
        para(
            f"Error = position - set-point over HOLD, from {SETTLE_S:g} s after HOLD began "
            "(x, y in the world frame, z = height), m. The paper's TABLE IX gives RMS or std "
            "per system; compare like with like."
        ),
        table(("", "statistic", "x m", "y m", "z m", "samples"), rows, row_classes=classes),
        precision_svg(hp),
    ]
    body += [missing(m) for m in (hp.estimate_missing, hp.truth_missing) if m]
    summary = flight.info.summary if flight.info is not None else None
    if isinstance(summary, FlightSummary) and summary.precision_estimate is not None:
        pe = summary.precision_estimate
        body.append(
            para(
                f"The daemon's own view at the end (flight.json, std of the estimate about "
                f"the set-point over {pe.samples} HOLD steps): x {pe.std_x_m:.4f} m, "
                f"y {pe.std_y_m:.4f} m, z {pe.std_z_m:.4f} m."
            )
        )
    return section("precision", "Hover precision (§O-P, TABLE IX)", body)
