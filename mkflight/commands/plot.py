"""``mkflight plot``: PNG figures of one flight folder (§O-P, Fig 18/19)."""

from __future__ import annotations

from pathlib import Path


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

