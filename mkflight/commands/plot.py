"""``mkflight plot``: PNG figures of one flight folder (seed §O-P, Fig 18/19)."""

from __future__ import annotations

from pathlib import Path

from mkflight.analysis.plots import ensure_matplotlib, load_flight, make_plots


def cmd_plot(*, log_dir: str, out_dir: str | None) -> int:
    """Draw a flight folder's figures as PNG files and print their paths, one a line.

    Args:
        log_dir: the flight folder (SPEC §6).
        out_dir: where the PNGs go (created); default ``LOG_DIR/plots``.

    Raises:
        PlotError: matplotlib is not installed (naming the extra), no such folder, an
            empty log, or the output folder cannot be written (exit 1).
        ReplayError: a malformed log, naming the file and line (exit 1).
    """
    ensure_matplotlib()  # before reading anything: the most likely failure, said first
    flight = load_flight(log_dir)
    out = Path(out_dir) if out_dir is not None else Path(log_dir) / "plots"
    for path in make_plots(flight, out):
        print(path)
    return 0
