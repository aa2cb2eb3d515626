"""``mkflight plot``: PNG figures of one flight folder (§O-P, Fig 18/19)."""

from __future__ import annotations

from pathlib import Path

from mkflight.commands.args import DOCUMENT, Command, Subparsers


def cmd_plot(*, log_dir: str, out_dir: str | None) -> int:
    """Draw a flight folder's figures as PNG files and print their paths, one a line.

    Args:
        log_dir: the flight folder (SPEC §6).
        out_dir: where the PNGs go (created); default ``LOG_DIR/plots``.

    Raises:
        PlotError: matplotlib is not installed (naming the extra), a table without rows,
            or the output folder cannot be written (exit 1).
        ReplayError: not a flight folder, a missing table or a malformed log, naming the
            file and line (exit 1).
    """
    from mkflight.analysis.plots import ensure_matplotlib, load_plottable, make_plots

    ensure_matplotlib()  # before reading anything: the most likely failure, said first
    flight = load_plottable(log_dir)
    out = Path(out_dir) if out_dir is not None else Path(log_dir) / "plots"
    for path in make_plots(flight, out):
        print(path)
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``plot LOGDIR``."""
    plot = subparsers.add_parser(
        "plot",
        help="draw a flight folder's figures as PNG files (needs the plot extra)",
        description=f"PNG figures of one flight folder (§O-P, Fig 18/19 of {DOCUMENT}): "
        "trajectory x-y, position and height with set-points, laser vs filtered velocity, "
        "commands and sticks, battery. Prints the paths. Needs matplotlib: pip install "
        "'mkflight[plot]'.",
    )
    plot.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    plot.add_argument(
        "-o", "--out-dir", metavar="DIR", help="where the PNGs go (default: LOGDIR/plots)"
    )
    plot.set_defaults(func=Command(cmd_plot))
