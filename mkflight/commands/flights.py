"""``mkflight flights [DIR] [--json]``: one line per flight folder in ``logging.dir``.

Text: aligned columns, sorted by flight number: the folder, its start (UTC), duration,
exit code, end reason, hover precision (the truth's when a simulator wrote one, else the
flight's own estimate; ``t`` or ``e`` says which), software version and failsafes.
``--json``: one JSON array of flat records (:class:`~mkflight.logs.flight_list.FlightRecord`:
scalar fields, stable keys, ``null`` where unknown) that ``pandas.read_json`` and DuckDB's
``read_json`` load straight into a table.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from mkflight.commands.args import Command, Subparsers, add_json, config_options

if TYPE_CHECKING:
    from mkflight.logs.flight_list import FlightRecord

_HEADER = ("flight", "start (UTC)", "duration", "exit", "end", "precision x y z (m)", "version")


def _precision(r: FlightRecord) -> str:
    """The truth's std if known, else the estimate's, with ``t``/``e``; ``-`` for none."""
    for mark, values in (
        ("t", (r.truth_std_x_m, r.truth_std_y_m, r.truth_std_z_m)),
        ("e", (r.est_std_x_m, r.est_std_y_m, r.est_std_z_m)),
    ):
        if all(v is not None for v in values):
            return " ".join(f"{v:.4f}" for v in values if v is not None) + f" {mark}"
    return "-"


def _row(r: FlightRecord) -> tuple[str, ...]:
    start = (r.start_utc or "-").replace("T", " ")[:19]
    duration = "-" if r.duration_s is None else f"{r.duration_s:.1f} s"
    end = r.end_reason or r.status
    failsafes = "-" if r.failsafe_count is None else str(r.failsafe_count)
    if r.failsafe_kinds:
        failsafes += f": {r.failsafe_kinds}"
    return (
        r.folder,
        start,
        duration,
        "-" if r.exit_code is None else str(r.exit_code),
        end,
        _precision(r),
        r.mkflight_version or "-",
        failsafes,
    )


def format_table(records: list[FlightRecord]) -> list[str]:
    """The text lines: a header and one aligned row per flight; failsafes last, as text."""
    rows = [(*_HEADER, "failsafes"), *(_row(r) for r in records)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(_HEADER))]
    right = {2, 3}  # numbers: duration, exit
    lines = []
    for row in rows:
        cells = [
            cell.rjust(w) if i in right else cell.ljust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=False))
        ]
        lines.append("  ".join([*cells, row[-1]]).rstrip())
    return lines


def cmd_flights(
    *, log_dir: str | None, as_json: bool, config_path: str | None, overrides: list[str]
) -> int:
    """List the flight folders of ``log_dir`` (default: the config's ``logging.dir``).

    Raises:
        ConfigError: bad config or override (only read without ``DIR``).
        ReplayError: ``DIR`` is not a folder or cannot be listed.
    """
    from pathlib import Path

    from mkflight.config import load_config
    from mkflight.errors import ReplayError
    from mkflight.logs.flight_list import list_flights

    folder = Path(
        log_dir if log_dir is not None else load_config(config_path, overrides).logging.dir
    )
    if not folder.is_dir():
        msg = f"{folder}: no such folder of flights"
        raise ReplayError(msg)
    try:
        records = list_flights(folder)
    except OSError as err:
        msg = f"{folder}: cannot list: {err.strerror or err}"
        raise ReplayError(msg) from err
    if as_json:
        print(json.dumps([r.as_dict() for r in records], allow_nan=False, indent=1))
    elif not records:
        print(f"no flight folders in {folder}")
    else:
        print("\n".join(format_table(records)))
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``flights [DIR]``."""
    flights = subparsers.add_parser(
        "flights",
        parents=[config_options()],
        help="list the flight folders: start, duration, end, precision, failsafes",
        description="One line per flight folder in DIR (default: logging.dir), sorted by "
        "flight number: start time, duration, exit code, end reason, hover precision (t: "
        "against a simulator's truth, e: the flight's own estimate), software version, "
        "failsafes. Folders without a summary (a killed flight) are listed with what is "
        "known; other folders are skipped.",
    )
    flights.add_argument(
        "log_dir",
        nargs="?",
        metavar="DIR",
        help="a folder of flight folders (default: logging.dir)",
    )
    add_json(flights, "a JSON array of flat records (one per flight, null where unknown)")
    flights.set_defaults(func=Command(cmd_flights))
