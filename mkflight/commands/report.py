"""``mkflight report LOGDIR``: one self-contained HTML page of a flight folder."""

from __future__ import annotations

from pathlib import Path

from mkflight.commands.args import DOCUMENT, Command, Subparsers


def cmd_report(*, log_dir: str, out: str | None) -> int:
    """Write the flight folder's HTML report and print its path.

    Args:
        log_dir: the flight folder (SPEC §6); any that ``load_flight`` reads, down to the
            original system's two tables alone.
        out: the HTML file to write; default ``LOG_DIR/report.html``.

    Raises:
        ReplayError: not a flight folder, or a malformed log, naming the file and line
            (exit 1).
        ReportError: the HTML file cannot be written (exit 1).
    """
    from mkflight.ground.report import FILE_NAME, ReportError, build_report, write_report
    from mkflight.ground.report_plots import plot_images
    from mkflight.logs.flight import load_flight

    flight = load_flight(log_dir)
    path = Path(out) if out is not None else Path(log_dir) / FILE_NAME
    html = build_report(flight, plot_images(flight))
    try:
        print(write_report(path, html))
    except ReportError as err:
        if out is not None:
            raise
        msg = f"{err} (-o FILE writes it elsewhere)"  # a flight folder the service owns
        raise ReportError(msg) from err
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``report LOGDIR``."""
    report = subparsers.add_parser(
        "report",
        help="one self-contained HTML page of a flight folder (plots need the report extra)",
        description="An HTML report of one flight folder, to open in any browser offline: "
        "how the flight ended, its duration and battery, the versions; a timeline of the "
        "phases and failsafes; the hover precision beside TABLE IX (§O-P) of "
        f"{DOCUMENT}; step latency, jitter, missed steps and CPU; the link counters; and "
        "the plots of 'mkflight plot', inline (with matplotlib: pip install "
        "'mkflight[report]'). What the folder lacks is said on the page. Prints the "
        "file's path.",
    )
    report.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    report.add_argument(
        "-o", "--out", metavar="FILE", help="the HTML file to write (default: LOGDIR/report.html)"
    )
    report.set_defaults(func=Command(cmd_report))
