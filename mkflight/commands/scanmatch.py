"""``mkflight scanmatch LOG [--odom FILE] [-o TRAJ]``: the scan matcher over a recorded log.

Reads a CARMEN log (``FLASER`` / ``ROBOTLASER1`` lines, plain or gzip), or one of our
own recordings (a flight folder, or its ``laser.raw``: :func:`~mkflight.logs.scans.read_scans`),
tracks the pose with :func:`~mkflight.scanmatch.log_tracking.track_records` (which beams,
which frame, the odometry prior) and writes ``t x y theta`` per scan in file order
(:mod:`mkflight.scanmatch.trajectory`), which scores directly against a ``.gt.txt`` with
``relpose_eval.py``.

Frames (SPEC §7): a CARMEN log's own (x forward, y left, theta counter-clockwise, from its
first logged pose); our recordings' W (x forward, y right, theta = psi clockwise, SPEC §1)
from 0 0 0 at the first scan, ``t`` the time each scan's front step was measured on the
flight's time base (:func:`~mkflight.logs.load_flight`'s ``t_s``, the ``scan`` events'),
so the output compares directly with the flight's own poses. ``--odom`` is read in the
same frame as the output.

Validity of a beam: finite and ``laser.min_range_m <= r <`` the log's own maximum range.
``--odom FILE`` is a ``t x y theta`` trajectory of the robot's odometry; the scans that
found no odometry sample within 1 ms are counted in the summary.

Malformed log lines are reported on stderr with their line numbers, counted, and skipped;
the other scans are still matched.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.commands.args import Command, Subparsers, config_options

if TYPE_CHECKING:
    from mkflight.config import Config
    from mkflight.scanmatch.carmen import LaserRecord
    from mkflight.scanmatch.geometry import FloatArray


def cmd_scanmatch(
    *,
    log: str,
    odom: str | None,
    out: str | None,
    config_path: str | None,
    overrides: list[str],
) -> int:
    """Run the scan matcher over ``log`` and write the trajectory (SPEC §7).

    Returns:
        0 on success (malformed lines and failed matches are reported, not fatal).

    Raises:
        ConfigError: bad config or override.
        ProtocolError: the log or the odometry file cannot be read, or the log holds no
            laser scan at all.
    """
    from mkflight.commands.progress import tty_bar
    from mkflight.config import load_config
    from mkflight.errors import MkflightError
    from mkflight.scanmatch.log_tracking import odom_in_math, poses_in_w, track_records
    from mkflight.scanmatch.trajectory import read_trajectory, write_trajectory

    cfg = load_config(config_path, overrides)
    ours = _is_recording(log)
    points = None
    if ours:
        records, points = _read_ours(log, cfg)
        malformed = 0
    else:
        records, malformed = _read_carmen(log, cfg)
    odom_data = read_trajectory(odom) if odom is not None else None
    if ours and odom_data is not None:
        odom_data = odom_in_math(odom_data)
    steps = (int(cfg.laser.scan_steps[0]), int(cfg.laser.scan_steps[1]))
    with tty_bar(len(records), "scan") as bar:
        tick = None if bar is None else (lambda: bar.update(1))
        tracked = track_records(
            records,
            scan_steps=steps,
            odom=odom_data,
            config=cfg.scanmatch,
            on_scan=tick,
            points=points,
        )
    if ours:
        tracked = poses_in_w(tracked)
    poses = [(s.t_s, s.pose) for s in tracked]
    if out is None:
        write_trajectory(poses, sys.stdout)
        sys.stdout.flush()
    else:
        try:
            with Path(out).open("w", encoding="utf-8") as fh:
                write_trajectory(poses, fh)
        except OSError as err:
            msg = f"{out}: cannot write trajectory: {err.strerror or err}"
            raise MkflightError(msg) from err
    invalid = sum(not s.result.valid for s in tracked[1:])
    degenerate = sum(s.result.degenerate for s in tracked)
    no_odom = sum(not s.used_odom for s in tracked[1:]) if odom_data is not None else 0
    summary = (
        f"scanmatch: {len(tracked)} scans, {invalid} invalid matches (prediction used), "
        f"{degenerate} degenerate, {malformed} malformed lines"
    )
    if odom_data is not None:
        summary += f", {no_odom} scans without odometry within 1 ms"
    print(summary, file=sys.stderr)
    return 0


def _is_recording(log: str) -> bool:
    """``log`` is one of our recordings: a folder, or a file starting as a raw recording.

    A file that cannot be opened is no recording: the CARMEN reader reports it.
    """
    from mkflight.logs.raw import MAGIC

    path = Path(log)
    if path.is_dir():
        return True
    try:
        with path.open("rb") as fh:
            return fh.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _read_carmen(log: str, cfg: Config) -> tuple[list[LaserRecord], int]:
    """The laser records of a CARMEN log, and how many malformed lines were skipped."""
    from mkflight.errors import ProtocolError
    from mkflight.scanmatch.carmen import read_carmen

    parsed = read_carmen(log, min_range_m=cfg.laser.min_range_m)
    for bad in parsed.malformed:
        print(f"{log}:{bad.line_no}: malformed line skipped: {bad.reason}", file=sys.stderr)
    if not parsed.records:
        msg = f"{log}: no FLASER or ROBOTLASER1 scan in the log"
        raise ProtocolError(msg)
    return parsed.records, len(parsed.malformed)


def _read_ours(log: str, cfg: Config) -> tuple[list[LaserRecord], list[FloatArray]]:
    """The scans of a flight folder or ``laser.raw``, and their points as in flight.

    In a flight folder (the file's own, for a ``laser.raw``) the scans come with the
    folder's time base and the FC's attitude from ``mk.raw``, and are levelled by it as in
    flight; a ``laser.raw`` alone is taken as level.
    """
    import numpy as np

    from mkflight.errors import ProtocolError, ReplayError
    from mkflight.logs import load_flight
    from mkflight.logs.scans import read_scans
    from mkflight.scanmatch.log_tracking import level_scan_points, records_from_scans

    path = Path(log)
    folder = path if path.is_dir() else path.parent
    try:
        flight = load_flight(folder) if path.is_dir() or path.name == "laser.raw" else None
    except ReplayError:
        if path.is_dir():
            raise
        flight = None  # a laser.raw outside a flight folder
    scans = flight.laser_scans if flight is not None else read_scans(path)
    if scans is None:
        msg = f"{folder / 'laser.raw'}: no such file (a flight folder's laser recording)"
        raise ReplayError(msg)
    for warning in scans.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if not len(scans):
        msg = f"{log}: no scan in the laser recording"
        raise ProtocolError(msg)
    stamp_s = (scans.stamp_t_ns - scans.t0_ns) / 1e9
    pitch = roll = np.zeros(len(scans))
    if flight is not None and len(flight.samples):
        samples = flight.samples
        pitch = np.interp(stamp_s, samples["t_s"], samples["pitch_rad"])
        roll = np.interp(stamp_s, samples["t_s"], samples["roll_rad"])
    records = records_from_scans(
        scans, min_range_m=cfg.laser.min_range_m, max_range_m=cfg.laser.max_range_m
    )
    return records, level_scan_points(scans, pitch, roll, cfg.laser)


def add_parser(subparsers: Subparsers) -> None:
    """``scanmatch LOG``."""
    match = subparsers.add_parser(
        "scanmatch",
        parents=[config_options()],
        help="run the scan matcher over a recorded laser log",
        description="Match every scan of a CARMEN log (FLASER/ROBOTLASER1 lines, plain or "
        ".gz) or of one of our recordings (a flight folder or its laser.raw) and write "
        "'t x y theta' per scan in the log's own frame (SPEC §7): CARMEN's from its first "
        "pose; ours W (x forward, y right, theta clockwise) from 0 0 0.",
    )
    match.add_argument(
        "log", metavar="LOG", help="the laser log: CARMEN, a flight folder or a laser.raw"
    )
    match.add_argument(
        "--odom", metavar="FILE", help="'t x y theta' odometry whose increments are the prior"
    )
    match.add_argument(
        "-o", "--output", dest="out", metavar="TRAJ", help="write here instead of stdout"
    )
    match.set_defaults(func=Command(cmd_scanmatch))
