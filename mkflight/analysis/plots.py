"""The flight plots (§O-P, Fig 18/19 of the 2011 QUT CyPhy MikroKopter documentation).

PNG figures of one flight folder (SPEC §6) as :func:`mkflight.logs.load_flight` reads it:
``laser_100ms.log`` (TABLE III) and ``imu_50ms.log`` (TABLE IV), both required, and when
present the ``step`` events of ``events.jsonl`` (one per ~53 ms step: position, height,
set-points, gas, battery) and the simulator's ``truth.txt``. :func:`make_plots` draws:

- ``trajectory.png``: the x-y path, estimate (and truth if there is a truth log), m.
- ``position.png``: x, y and height against time with their set-points, m.
- ``velocity.png``: body velocity x and y, laser (``B_Vel``) against the filter
  (``B_esti_Vel``), m/s, as Fig 18/19.
- ``commands.png``: ControlPitch/Roll/Yaw, the sticks and the gas command, MK counts.
- ``battery.png``: battery voltage, V (only with step events).

Time axes: seconds from the first ``step`` event where the figure shows steps; TABLE III
rows at their nominal ``index x 100 ms``.

matplotlib is an optional extra (``pip install 'mkflight[plot]'``) and is imported inside
:func:`make_plots` only, with the non-interactive Agg canvas (no display, no pyplot state).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mkflight.errors import MkflightError, ReplayError
from mkflight.logs import table3, table4
from mkflight.logs.flight import FlightData, load_flight

if TYPE_CHECKING:
    from matplotlib.figure import Figure

INSTALL_HINT = "pip install 'mkflight[plot]'"
LASER_PERIOD_S = 0.1  # TABLE III: one row per 100 ms laser step
IMU_PERIOD_S = 0.05  # TABLE IV: one row per 50 ms step
DPI = 120

Array = npt.NDArray[np.float64]
#: A structured array: rows with named columns (``steps["x_m"]``).
Records = npt.NDArray[Any]


class PlotError(MkflightError):
    """Plots cannot be made: matplotlib missing, or a flight folder without usable logs."""


def ensure_matplotlib() -> None:
    """Import matplotlib, or raise :class:`PlotError` naming the extra to install."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as err:
        msg = f"plotting needs matplotlib, which is not installed: {INSTALL_HINT}"
        raise PlotError(msg) from err


def load_plottable(folder: str | Path) -> FlightData:
    """:func:`~mkflight.logs.load_flight`, checked to hold both tables with rows.

    Raises:
        ReplayError: not a flight folder, a table missing (naming it), or a log that is
            unreadable or malformed (naming file and line).
        PlotError: a table has no rows.
    """
    path = Path(folder)
    tables = (table3.FILE_NAME, table4.FILE_NAME)
    if path.is_dir():  # else load_flight says it is not a flight folder
        for name in tables:
            if not (path / name).is_file():
                msg = f"{path / name}: cannot read: missing from the flight folder"
                raise ReplayError(msg)
    flight = load_flight(path)
    for name, rows in zip(tables, (flight.laser, flight.imu), strict=True):
        if len(rows) == 0:
            msg = f"{path / name}: the log has no rows (an empty flight?)"
            raise PlotError(msg)
    return flight


def make_plots(flight: FlightData, out_dir: str | Path) -> list[Path]:
    """Draw every figure of ``flight`` into ``out_dir`` (created) as PNG; return the paths.

    Raises:
        PlotError: matplotlib is not installed, or ``out_dir`` cannot be written.
    """
    return save_figures(flight_figures(flight), out_dir)


def flight_figures(flight: FlightData) -> list[tuple[str, Figure]]:
    """Every figure of ``flight`` (module docstring), each with its file's name sans ``.png``.

    Raises:
        PlotError: matplotlib is not installed.
    """
    ensure_matplotlib()
    steps = _steps(flight)
    figures: list[tuple[str, Figure]] = [
        ("trajectory", _trajectory(flight, steps)),
        ("position", _position(flight, steps)),
        ("velocity", _velocity(flight)),
        ("commands", _commands(flight, steps)),
    ]
    if steps is not None:
        figures.append(("battery", _battery(steps)))
    return figures


def _steps(flight: FlightData) -> Records | None:
    """The ``step`` events with ``t_s`` from the first one, or None without any."""
    if len(flight.steps) == 0:
        return None
    steps = flight.steps.copy()
    steps["t_s"] -= steps["t_s"][0]
    return steps


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


def _imu_t(flight: FlightData, steps: Records | None) -> tuple[Array, str]:
    """TABLE IV's time axis: the step events' times when one step event per row, else nominal.

    The FC's DebugOut period is ~53 ms (``mk.debug_interval_10ms``), so ``index x 50 ms``
    drifts against the events' clock; row ``index`` k is the k-th step.
    """
    index = flight.imu["index"].astype(np.int64)
    if steps is not None and index.min() >= 1 and index.max() <= len(steps):
        return steps["t_s"][index - 1], "t (s)"
    return flight.imu["index"] * IMU_PERIOD_S, "t = index x 50 ms (s)"


def _trajectory(flight: FlightData, steps: Records | None) -> Figure:
    fig = _figure(1, f"Trajectory: {flight.path.name}", height_in=6.0)
    ax = fig.add_subplot()
    ax.plot(
        flight.laser["CurrentPosition.x"],
        flight.laser["CurrentPosition.y"],
        label="estimate (TABLE III)",
    )
    truth = flight.truth
    if truth is not None and len(truth) > 0:
        ax.plot(truth["x_m"], truth["y_m"], label="truth", alpha=0.7)
    if steps is not None:
        ok = np.isfinite(steps["sp_x_m"]) & np.isfinite(steps["sp_y_m"])
        if ok.any():
            ax.plot(
                steps["sp_x_m"][ok],
                steps["sp_y_m"][ok],
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


def _position(flight: FlightData, steps: Records | None) -> Figure:
    if steps is None:  # the original system's two tables: the estimate, no height or set-point
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
        (steps["x_m"], steps["sp_x_m"], "x (m)"),
        (steps["y_m"], steps["sp_y_m"], "y (m)"),
        (steps["height_m"], steps["sp_height_m"], "height (m)"),
    )
    for ax, (value, setpoint, label) in zip(axes, series, strict=True):
        ax.plot(steps["t_s"], value, label="estimate")
        ax.plot(steps["t_s"], setpoint, "--", label="set-point")
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


def _commands(flight: FlightData, steps: Records | None) -> Figure:
    rows = 3 if steps is not None else 2
    fig = _figure(rows, "Commands and sticks (TABLE IV)")
    axes = fig.subplots(rows, 1, sharex=True)
    t, t_label = _imu_t(flight, steps)
    for name in ("ControlPitch", "ControlRoll", "ControlYaw"):
        axes[0].plot(t, flight.imu[name], label=name)
    axes[0].set_ylabel("control (counts)")
    for name in ("StickPitch", "StickRoll", "StickYaw", "StickThrust"):
        axes[1].plot(t, flight.imu[name], label=name)
    axes[1].set_ylabel("stick (counts)")
    if steps is not None:
        axes[2].plot(steps["t_s"], steps["gas_counts"], label="gas")
        axes[2].set_ylabel("gas (counts)")
    axes[-1].set_xlabel(t_label)
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="upper right", fontsize="small")
    return fig


def _battery(steps: Records) -> Figure:
    fig = _figure(1, "Battery")
    ax = fig.add_subplot()
    ax.plot(steps["t_s"], steps["battery_v"])
    ax.set_xlabel("t (s)")
    ax.set_ylabel("battery (V)")
    ax.grid(True)
    return fig
