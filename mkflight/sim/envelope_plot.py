"""The envelope's figures (``sim envelope --plot DIR``): precision and touchdowns vs parameters.

- ``precision.png``: std x and y over the oracle's against the airframe's delay + lag,
  with the 1.25 criterion; and std x, y against delay + lag with the 0.03 m floor;
- ``height.png``: std z against the vibration (AccNick counts), with the 0.01 m limit;
- ``touchdown.png``: every touchdown speed against the vibration and against the ground
  effect, by flight (defaults, laser stall, tuned), with the 0.5 m/s limit.

matplotlib is the optional plot extra, imported here only, drawn on the Agg canvas.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.analysis.plots import ensure_matplotlib, save_figures
from mkflight.sim.envelope import AirframeRun
from mkflight.sim.envelope_report import CRITERIA, Criteria

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def _drawn(run: AirframeRun, key: str) -> float:
    return run.drawn.get(key, math.nan)


def _response(run: AirframeRun) -> float:
    return _drawn(run, "attitude_delay_s") + _drawn(run, "attitude_tau_s")


def _ratio(std_m: float, oracle_m: float) -> float:
    return std_m / oracle_m if oracle_m > 0 else math.nan


def _figure(rows: int, title: str) -> Figure:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 1.0 + 3.2 * rows), layout="constrained")
    fig.suptitle(title)
    return fig


def _limit(ax: Axes, value: float, label: str) -> None:
    ax.axhline(value, color="red", linestyle="--", linewidth=1.0, label=label)


def _precision(runs: Sequence[AirframeRun], c: Criteria) -> Figure:
    fig = _figure(2, "Hover precision (truth, defaults) against the attitude response")
    ax1, ax2 = fig.subplots(2, 1)
    x = [_response(r) for r in runs]
    ax1.plot(x, [_ratio(r.defaults.std_x_m, r.oracle.std_x_m) for r in runs], "o", label="x")
    ax1.plot(x, [_ratio(r.defaults.std_y_m, r.oracle.std_y_m) for r in runs], "s", label="y")
    _limit(ax1, c.oracle_factor, f"{c.oracle_factor} x oracle")
    ax1.set_ylabel("std / oracle's std")
    ax2.plot(x, [r.defaults.std_x_m for r in runs], "o", label="std x")
    ax2.plot(x, [r.defaults.std_y_m for r in runs], "s", label="std y")
    ax2.plot(x, [r.oracle.std_x_m for r in runs], "x", color="gray", label="oracle x")
    ax2.plot(x, [r.oracle.std_y_m for r in runs], "+", color="gray", label="oracle y")
    _limit(ax2, c.floor_m, f"{c.floor_m} m")
    ax2.set_ylabel("std (m)")
    for ax in (ax1, ax2):
        ax.set_xlabel("attitude delay + lag (s)")
        ax.grid(True)
        ax.legend()
    return fig


def _height(runs: Sequence[AirframeRun], c: Criteria) -> Figure:
    fig = _figure(1, "Height precision (truth, defaults) against vibration")
    ax = fig.subplots()
    vib = [_drawn(r, "vibration_counts") for r in runs]
    ax.plot(vib, [r.defaults.std_z_m for r in runs], "o", label="defaults")
    ax.plot(vib, [r.tuned.std_z_m for r in runs], "s", label="tuned", alpha=0.6)
    _limit(ax, c.max_std_z_m, f"{c.max_std_z_m} m")
    ax.set_xlabel("vibration on AccNick/AccRoll (counts)")
    ax.set_ylabel("std z (m)")
    ax.grid(True)
    ax.legend()
    return fig


def _touchdown(runs: Sequence[AirframeRun], c: Criteria) -> Figure:
    fig = _figure(2, "Touchdown speed (truth) against vibration and ground effect")
    axes = fig.subplots(2, 1)
    for ax, key, label in zip(
        axes,
        ("vibration_counts", "ground_effect"),
        ("vibration on AccNick/AccRoll (counts)", "ground effect (thrust fraction)"),
        strict=True,
    ):
        for name, marker in (("defaults", "o"), ("stall", "v"), ("tuned", "s")):
            xs: list[float] = []
            ys: list[float] = []
            for r in runs:
                flight = getattr(r, name)
                for v in flight.touchdowns_mps:
                    xs.append(_drawn(r, key))
                    ys.append(v)
            ax.plot(xs, ys, marker, linestyle="none", label=name, alpha=0.7)
        _limit(ax, c.max_touchdown_mps, f"{c.max_touchdown_mps} m/s")
        ax.set_xlabel(label)
        ax.set_ylabel("touchdown (m/s)")
        ax.grid(True)
        ax.legend()
    return fig


def envelope_plots(
    runs: Sequence[AirframeRun],
    out_dir: str | Path,
    criteria: Criteria = CRITERIA,
) -> list[Path]:
    """Draw the envelope's figures into ``out_dir`` (created); return the PNG paths.

    Raises:
        PlotError: matplotlib is not installed, or ``out_dir`` cannot be written.
    """
    ensure_matplotlib()
    figures = [
        ("precision", _precision(runs, criteria)),
        ("height", _height(runs, criteria)),
        ("touchdown", _touchdown(runs, criteria)),
    ]
    return save_figures(figures, out_dir)
