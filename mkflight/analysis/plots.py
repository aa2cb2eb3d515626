"""The flight plots (seed §O-P, Fig 18/19): PNG figures of one flight folder.

A flight folder (SPEC §6) holds ``laser_100ms.log`` (TABLE III), ``imu_50ms.log``
(TABLE IV), ``events.jsonl`` (one ``step`` event per ~53 ms step: position, height,
set-points, gas, battery) and optionally ``truth.txt`` (``t x y z``, from the simulator).
:func:`load_flight` reads them into plain arrays; :func:`make_plots` draws these figures:

- ``trajectory.png``: the x-y path, estimate (and truth if there is a truth log), m.
- ``position.png``: x, y and height against time with their set-points, m.
- ``velocity.png``: body velocity x and y, laser (``B_Vel``) against the filter
  (``B_esti_Vel``), m/s: the seed's Fig 18/19.
- ``commands.png``: ControlPitch/Roll/Yaw, the sticks and the gas command, MK counts.
- ``battery.png``: battery voltage, V (only with an events log).

matplotlib is an optional extra (``pip install 'mkflight[plot]'``) and is imported inside
:func:`make_plots` only, with the non-interactive Agg canvas (no display, no pyplot state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mkflight.conversions import NS_PER_S
from mkflight.errors import MkflightError
from mkflight.logs import table3, table4
from mkflight.logs.events import read_events

if TYPE_CHECKING:
    from matplotlib.figure import Figure

INSTALL_HINT = "pip install 'mkflight[plot]'"
LASER_PERIOD_S = 0.1  # TABLE III: one row per 100 ms laser step
IMU_PERIOD_S = 0.05  # TABLE IV: one row per 50 ms step
DPI = 120

Array = npt.NDArray[np.float64]


class PlotError(MkflightError):
    """Plots cannot be made: matplotlib missing, or a flight folder without usable logs."""


@dataclass(frozen=True, slots=True)
class StepSeries:
    """The ``step`` events as columns; time from the first step, s (NaN: not set)."""

    t_s: Array
    x_m: Array
    y_m: Array
    height_m: Array
    sp_x_m: Array
    sp_y_m: Array
    sp_height_m: Array
    gas_counts: Array
    battery_v: Array


@dataclass(frozen=True, slots=True)
class FlightData:
    """One flight folder's logs as arrays (table columns keyed by their header names)."""

    folder: Path
    laser: dict[str, Array]
    imu: dict[str, Array]
    steps: StepSeries | None
    truth_xyz_m: Array | None


def ensure_matplotlib() -> None:
    """Import matplotlib, or raise :class:`PlotError` naming the extra to install."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as err:
        msg = f"plotting needs matplotlib, which is not installed: {INSTALL_HINT}"
        raise PlotError(msg) from err


def load_flight(folder: str | Path) -> FlightData:
    """Read a flight folder's tables, events and truth log.

    Raises:
        PlotError: the folder does not exist, or a table has no rows.
        ReplayError: a log is unreadable or malformed (naming file and line).
    """
    folder = Path(folder)
    if not folder.is_dir():
        msg = f"{folder}: not a flight folder (no such directory)"
        raise PlotError(msg)
    laser = _columns(table3.read_table3(folder / table3.FILE_NAME).rows, table3.COLUMNS)
    imu = _columns(table4.read_table4(folder / table4.FILE_NAME).rows, table4.COLUMNS)
    for name, cols in ((table3.FILE_NAME, laser), (table4.FILE_NAME, imu)):
        if len(cols["index"]) == 0:
            msg = f"{folder / name}: the log has no rows (an empty flight?)"
            raise PlotError(msg)
    events_path = folder / "events.jsonl"
    steps = _steps(events_path) if events_path.exists() else None
    truth_path = folder / "truth.txt"
    truth = _truth(truth_path) if truth_path.exists() else None
    return FlightData(folder, laser, imu, steps, truth)


def _columns(rows: npt.NDArray[np.void], names: tuple[str, ...]) -> dict[str, Array]:
    return {name: np.asarray(rows[name], dtype=np.float64) for name in names}


def _number(value: Any) -> float:
    """A JSON value as a float: numbers as they are, null and anything else NaN."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    return math.nan


def _steps(path: Path) -> StepSeries | None:
    steps = [e for e in read_events(path).events if e.event == "step"]
    if not steps:
        return None
    t0 = steps[0].t_ns

    def col(key: str) -> Array:
        return np.array([_number(e.fields.get(key)) for e in steps], dtype=np.float64)

    return StepSeries(
        t_s=np.array([(e.t_ns - t0) / NS_PER_S for e in steps], dtype=np.float64),
        x_m=col("x_m"),
        y_m=col("y_m"),
        height_m=col("height_m"),
        sp_x_m=col("sp_x_m"),
        sp_y_m=col("sp_y_m"),
        sp_height_m=col("sp_height_m"),
        gas_counts=col("gas_counts"),
        battery_v=col("battery_v"),
    )


def _truth(path: Path) -> Array | None:
    """The truth log's x, y, z columns (``t x y z`` with a header line), or None if empty."""
    try:
        data = np.loadtxt(path, skiprows=1, ndmin=2, dtype=np.float64)
    except (OSError, ValueError) as err:
        msg = f"{path}: cannot read the truth log ('t x y z' rows): {err}"
        raise PlotError(msg) from err
    if data.shape[0] == 0:
        return None
    if data.shape[1] != 4:
        msg = f"{path}: expected 4 columns 't x y z', got {data.shape[1]}"
        raise PlotError(msg)
    return np.asarray(data[:, 1:4], dtype=np.float64)


def make_plots(flight: FlightData, out_dir: str | Path) -> list[Path]:
    """Draw every figure of ``flight`` into ``out_dir`` (created) as PNG; return the paths.

    Raises:
        PlotError: matplotlib is not installed, or ``out_dir`` cannot be written.
    """
    ensure_matplotlib()
    figures: list[tuple[str, Figure]] = [
        ("trajectory", _trajectory(flight)),
        ("position", _position(flight)),
        ("velocity", _velocity(flight)),
        ("commands", _commands(flight)),
    ]
    if flight.steps is not None:
        figures.append(("battery", _battery(flight.steps)))
    return save_figures(figures, out_dir)


def save_figures(figures: list[tuple[str, Figure]], out_dir: str | Path) -> list[Path]:
    """Write each ``(name, figure)`` as ``out_dir/name.png`` (folder created); the paths.

    Raises:
        PlotError: ``out_dir`` or a file in it cannot be written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f"{out}: cannot create the plot folder: {err.strerror or err}"
        raise PlotError(msg) from err
    paths: list[Path] = []
    for name, fig in figures:
        FigureCanvasAgg(fig)
        path = out / f"{name}.png"
        try:
            fig.savefig(path, dpi=DPI)
        except OSError as err:
            msg = f"{path}: cannot write: {err.strerror or err}"
            raise PlotError(msg) from err
        paths.append(path)
    return paths


def _figure(rows: int, title: str, *, height_in: float = 3.0) -> Figure:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 1.0 + height_in * rows), layout="constrained")
    fig.suptitle(title)
    return fig


def _laser_t(flight: FlightData) -> Array:
    return flight.laser["index"] * LASER_PERIOD_S


def _imu_t(flight: FlightData) -> tuple[Array, str]:
    """TABLE IV's time axis: the step events' times when one step event per row, else nominal.

    The FC's DebugOut period is ~53 ms (``mk.debug_interval_10ms``), so ``index x 50 ms``
    drifts against the events' clock; row ``index`` k is the k-th step.
    """
    index = flight.imu["index"].astype(np.int64)
    steps = flight.steps
    if steps is not None and index.min() >= 1 and index.max() <= len(steps.t_s):
        return steps.t_s[index - 1], "t (s)"
    return flight.imu["index"] * IMU_PERIOD_S, "t = index x 50 ms (s)"


def _trajectory(flight: FlightData) -> Figure:
    fig = _figure(1, f"Trajectory: {flight.folder.name}", height_in=6.0)
    ax = fig.add_subplot()
    ax.plot(
        flight.laser["CurrentPosition.x"],
        flight.laser["CurrentPosition.y"],
        label="estimate (TABLE III)",
    )
    if flight.truth_xyz_m is not None:
        ax.plot(flight.truth_xyz_m[:, 0], flight.truth_xyz_m[:, 1], label="truth", alpha=0.7)
    if flight.steps is not None:
        ok = np.isfinite(flight.steps.sp_x_m) & np.isfinite(flight.steps.sp_y_m)
        if ok.any():
            ax.plot(
                flight.steps.sp_x_m[ok],
                flight.steps.sp_y_m[ok],
                "k+",
                markersize=12,
                label="set-point",
            )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True)
    ax.legend()
    return fig


def _position(flight: FlightData) -> Figure:
    steps = flight.steps
    if steps is None:  # the seed's tables alone: the estimate, no height or set-point
        fig = _figure(2, "Position vs time (TABLE III)")
        axes = fig.subplots(2, 1, sharex=True)
        t = _laser_t(flight)
        for ax, key, label in zip(
            axes, ("CurrentPosition.x", "CurrentPosition.y"), ("x (m)", "y (m)"), strict=True
        ):
            ax.plot(t, flight.laser[key], label="estimate")
            ax.set_ylabel(label)
            ax.grid(True)
            ax.legend()
        axes[-1].set_xlabel("t = index x 100 ms (s)")
        return fig
    fig = _figure(3, "Position and height vs time")
    axes = fig.subplots(3, 1, sharex=True)
    series = (
        (steps.x_m, steps.sp_x_m, "x (m)"),
        (steps.y_m, steps.sp_y_m, "y (m)"),
        (steps.height_m, steps.sp_height_m, "height (m)"),
    )
    for ax, (value, setpoint, label) in zip(axes, series, strict=True):
        ax.plot(steps.t_s, value, label="estimate")
        ax.plot(steps.t_s, setpoint, "--", label="set-point")
        ax.set_ylabel(label)
        ax.grid(True)
        ax.legend()
    axes[-1].set_xlabel("t (s)")
    return fig


def _velocity(flight: FlightData) -> Figure:
    fig = _figure(2, "Body velocity: laser vs filtered (Fig 18/19)")
    axes = fig.subplots(2, 1, sharex=True)
    t = _laser_t(flight)
    for ax, axis in zip(axes, ("x", "y"), strict=True):
        ax.plot(t, flight.laser[f"B_Vel.{axis}"], ".-", markersize=3, label=f"B_Vel.{axis} (laser)")
        ax.plot(t, flight.laser[f"B_esti_Vel.{axis}"], label=f"B_esti_Vel.{axis} (filtered)")
        ax.set_ylabel(f"v_{axis} (m/s)")
        ax.grid(True)
        ax.legend()
    axes[-1].set_xlabel("t = index x 100 ms (s)")
    return fig


def _commands(flight: FlightData) -> Figure:
    rows = 3 if flight.steps is not None else 2
    fig = _figure(rows, "Commands and sticks (TABLE IV)")
    axes = fig.subplots(rows, 1, sharex=True)
    t, t_label = _imu_t(flight)
    for name in ("ControlPitch", "ControlRoll", "ControlYaw"):
        axes[0].plot(t, flight.imu[name], label=name)
    axes[0].set_ylabel("control (counts)")
    for name in ("StickPitch", "StickRoll", "StickYaw", "StickThrust"):
        axes[1].plot(t, flight.imu[name], label=name)
    axes[1].set_ylabel("stick (counts)")
    if flight.steps is not None:
        axes[2].plot(flight.steps.t_s, flight.steps.gas_counts, label="gas")
        axes[2].set_ylabel("gas (counts)")
    axes[-1].set_xlabel(t_label)
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="upper right", fontsize="small")
    return fig


def _battery(steps: StepSeries) -> Figure:
    fig = _figure(1, "Battery")
    ax = fig.add_subplot()
    ax.plot(steps.t_s, steps.battery_v)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("battery (V)")
    ax.grid(True)
    return fig
