"""``mkflight analyze precision|latency LOGDIR``: two analyses of a flight.

They are §O-P (hover precision, TABLE IX) and §F (response lag, Fig 8) of
the 2011 QUT CyPhy MikroKopter documentation.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.commands.args import DOCUMENT, Command, Subparsers, add_json, subcommands
from mkflight.conversions import MS_PER_S, NS_PER_S

if TYPE_CHECKING:
    import numpy as np

    from mkflight.analysis.latency import LagCurve
    from mkflight.logs.schema import KnownEvent

# The analyses (numpy, the log readers) are imported inside the functions that run them:
# every mkflight call imports this module to build its parser.


def _existing(folder: Path, name: str) -> Path:
    """``folder/name``, checked to exist and not be empty."""
    from mkflight.analysis.precision import AnalysisInputError

    if not folder.is_dir():
        msg = f"{folder}: not a flight folder (no such directory)"
        raise AnalysisInputError(msg)
    path = folder / name
    if not path.is_file():
        msg = f"{path}: missing from the flight folder"
        raise AnalysisInputError(msg)
    if path.stat().st_size == 0:
        msg = f"{path}: empty log"
        raise AnalysisInputError(msg)
    return path


def _read_text(path: Path) -> str:
    from mkflight.analysis.precision import AnalysisInputError

    try:
        return path.read_text(encoding="utf-8")
    except OSError as err:
        msg = f"{path}: cannot read: {err.strerror or err}"
        raise AnalysisInputError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{path}: not UTF-8 text (byte {err.start}): {err.reason}"
        raise AnalysisInputError(msg) from err


def cmd_analyze_precision(*, log_dir: str, truth: str | None, as_json: bool) -> int:
    """Print the hover precision of a flight folder beside TABLE IX (§O-P).

    Args:
        log_dir: the flight folder (its ``events.jsonl``: set-points, estimates, phases).
        truth: a ``t x y z`` file (s, m; z = height up) to measure the truth instead of
            the estimate, nearest time within 30 ms; e.g. the simulator's ``truth.txt``.
        as_json: one object with ``mean_*``, ``std_*``, ``rms_*``, ``max_*`` (``_x_m``,
            ``_y_m``, ``_z_m``), ``samples`` and ``source``.

    Raises:
        AnalysisInputError: a missing or empty file, a malformed truth row (file and
            line), or no HOLD samples (exit 1).
        ReplayError: a malformed events line (file and line; exit 1).
    """
    from mkflight.analysis.precision import (
        SEED_TABLE_IX,
        SETTLE_S,
        AnalysisInputError,
        hold_samples,
        parse_truth,
        precision,
        with_truth,
    )
    from mkflight.logs.events import FILE_NAME as EVENTS_FILE
    from mkflight.logs.events import read_events

    folder = Path(log_dir)
    events = read_events(_existing(folder, EVENTS_FILE))
    samples = hold_samples(events.events)
    source = "estimate"
    if truth is not None:
        truth_path = Path(truth)
        if not truth_path.is_file():
            msg = f"{truth_path}: no such truth file"
            raise AnalysisInputError(msg)
        samples = with_truth(samples, parse_truth(_read_text(truth_path), str(truth_path)))
        source = "truth"
    try:
        p = precision(samples, source)
    except AnalysisInputError as err:  # say which file had nothing to measure
        cut = " (its last line was cut short)" if events.truncated else ""
        msg = f"{folder / EVENTS_FILE}{cut}: {err}"
        raise AnalysisInputError(msg) from err
    if as_json:
        print(json.dumps(p.as_dict()))
        return 0
    print(
        f"hover precision of {folder} (§O-P): {p.samples} HOLD steps from "
        f"{SETTLE_S:g} s after HOLD began, position = {source}, error = position - set-point"
    )
    print(f"{'':28}{'x m':>10}{'y m':>10}{'z m':>10}")
    for stat in ("mean", "std", "rms", "max"):
        vals = [getattr(a, f"{stat}_m") for a in (p.x, p.y, p.z)]
        label = "max |err|" if stat == "max" else stat
        print(f"  this flight  {label:<14}" + "".join(f"{v:10.4f}" for v in vals))
    print("TABLE IX (hovering):")
    for row in SEED_TABLE_IX:
        print(f"  {row.name:<18} {row.kind:<7}{row.x_m:10.4f}{row.y_m:10.4f}{row.z_m:10.4f}")
    return 0


def _row_times_s(folder: Path, kind: type[KnownEvent], rows: int) -> np.ndarray | None:
    """The table rows' times (s) from their events, if the log has exactly one per row.

    A TABLE IV row's event is its ``Step``; a TABLE III row's the ``Scan`` that made it
    (one with an ``index``: a scan that made no row has none).
    """
    import numpy as np

    from mkflight.logs.events import FILE_NAME as EVENTS_FILE
    from mkflight.logs.events import read_events
    from mkflight.logs.schema import Scan

    path = folder / EVENTS_FILE
    if not path.is_file() or path.stat().st_size == 0:
        return None
    times = [
        e.t_ns
        for e in read_events(path).events
        if isinstance(e, kind) and not (isinstance(e, Scan) and e.index is None)
    ]
    if len(times) != rows:
        return None
    return np.asarray(times, dtype=np.float64) / NS_PER_S


def _print_curve(name: str, curve: LagCurve, period_s: float) -> None:
    print(
        f"  {name:<13}{curve.lag_steps:3d} steps = "
        f"{curve.lag_fine_steps * period_s * MS_PER_S:4.0f} ms"
        f"  r {curve.peak_r:5.2f}  (x: {curve.lag_x_steps}, y: {curve.lag_y_steps})"
    )


def cmd_analyze_latency(*, log_dir: str, as_json: bool) -> int:
    """Print the vehicle's response lag by cross-correlation (§F, Fig 8).

    Args:
        log_dir: the flight folder (its ``imu_50ms.log`` and ``laser_100ms.log``; the
            ``step`` and ``scan`` events' times when present).
        as_json: one object: ``lag_steps``, ``lag_s``, ``peak_r``, ``period_s``, and per
            curve (``acceleration``, ``attitude``, ``velocity``) its lag and curves.

    Raises:
        AnalysisInputError: a missing or empty log, or no correlation (exit 1).
        ReplayError: a malformed table row (file and line; exit 1).
    """
    import numpy as np

    from mkflight.analysis.latency import (
        IMU_PERIOD_S,
        LASER_PERIOD_S,
        SEED_LAG_STEPS,
        WEAK_PEAK_R,
        estimate_latency,
    )
    from mkflight.analysis.precision import AnalysisInputError
    from mkflight.logs.schema import Scan, Step
    from mkflight.logs.table3 import FILE_NAME as TABLE3_FILE
    from mkflight.logs.table3 import read_table3
    from mkflight.logs.table4 import FILE_NAME as TABLE4_FILE
    from mkflight.logs.table4 import read_table4

    folder = Path(log_dir)
    t4 = read_table4(_existing(folder, TABLE4_FILE)).rows
    t3 = read_table3(_existing(folder, TABLE3_FILE)).rows
    for rows, name in ((t4, TABLE4_FILE), (t3, TABLE3_FILE)):
        if len(rows) < 3:
            msg = f"{folder / name}: {len(rows)} rows, too few to correlate"
            raise AnalysisInputError(msg)
    # The rows' times: the events' when there is one per row; else the indices' nominal ones.
    t4_s = _row_times_s(folder, Step, len(t4))
    t3_s = _row_times_s(folder, Scan, len(t3))
    if t4_s is None or t3_s is None:
        t4_s = np.asarray(t4["index"], dtype=np.float64) * IMU_PERIOD_S
        t3_s = (np.asarray(t3["index"], dtype=np.float64) - 1.0) * LASER_PERIOD_S
    lat = estimate_latency(
        t4_s=t4_s,
        control_pitch_counts=np.asarray(t4["ControlPitch"], dtype=np.float64),
        control_roll_counts=np.asarray(t4["ControlRoll"], dtype=np.float64),
        angle_pitch_rad=np.asarray(t4["AnglePitch"], dtype=np.float64),
        angle_roll_rad=np.asarray(t4["AngleRoll"], dtype=np.float64),
        t3_s=t3_s,
        b_vel_x_mps=np.asarray(t3["B_Vel.x"], dtype=np.float64),
        b_vel_y_mps=np.asarray(t3["B_Vel.y"], dtype=np.float64),
    )
    if as_json:
        print(json.dumps(lat.as_dict()))
        return 0
    print(
        f"response lag of {folder}: {lat.lag_steps} steps = {lat.lag_s * MS_PER_S:.0f} ms at "
        f"{lat.period_s * MS_PER_S:.1f} ms a step (Fig 8: ~{SEED_LAG_STEPS} steps = "
        f"{SEED_LAG_STEPS * 50} ms)"
    )
    _print_curve("acceleration", lat.acceleration, lat.period_s)
    if lat.attitude is not None:
        _print_curve("attitude", lat.attitude, lat.period_s)
    if lat.velocity is not None:
        _print_curve("velocity", lat.velocity, lat.period_s)
    print("  acceleration: commanded tilt -> laser body acceleration (the response lag)")
    print("  attitude: -> the FC's angles; velocity: Fig 8's curve (adds the integration)")
    if lat.peak_r < WEAK_PEAK_R:
        print(
            f"  weak peak (r = {lat.peak_r:.2f} < {WEAK_PEAK_R}): too little excitation "
            "(a calm closed-loop hover); fly steps ('sim hover --excite 0.2') or stick inputs"
        )
    curves = [lat.acceleration, lat.attitude, lat.velocity]
    print(f"  {'lag':>4} {'ms':>5} {'r_acc':>7} {'r_att':>7} {'r_vel':>7}")
    for k in range(len(lat.acceleration.curve)):
        r = [" " * 7 if c is None else f"{float(c.curve[k]):7.3f}" for c in curves]
        mark = "  <- peak" if k == lat.lag_steps else ""
        print(f"  {k:4d} {k * lat.period_s * MS_PER_S:5.0f} {' '.join(r)}{mark}")
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``analyze precision LOGDIR`` and ``analyze latency LOGDIR``."""
    analyze = subparsers.add_parser(
        "analyze",
        help="hover precision and response lag of a flight folder (§O-P, §F)",
        description=f"The analyses of {DOCUMENT} on a flight folder: hover precision "
        "(§O-P, TABLE IX) and response lag (§F, Fig 8).",
    )
    analyze_commands = subcommands(analyze, "analyze_command")
    precision = analyze_commands.add_parser(
        "precision",
        help="hover precision (mean, std, RMS, max error) beside TABLE IX",
        description="Mean, std, RMS and max of the x, y and height error about the set-point "
        "during HOLD (from 3 s after HOLD begins, as 'sim hover' measures), against the "
        f"flight's estimate or a 't x y z' truth file (§O-P, TABLE IX of {DOCUMENT}).",
    )
    precision.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    precision.add_argument(
        "--truth", metavar="FILE", help="'t x y z' ground truth (z = height up), e.g. truth.txt"
    )
    add_json(precision)
    precision.set_defaults(func=Command(cmd_analyze_precision))
    latency = analyze_commands.add_parser(
        "latency",
        help="the vehicle's response lag by cross-correlation (§F, Fig 8)",
        description="Normalised cross-correlation of the commanded pitch (roll) with the "
        "laser's body-frame acceleration along x (y), i.e. the body velocity differenced, for "
        "lags 0..20 steps: the peak is the response lag (delay + lag of the attitude loop). "
        "Also the FC's own angles against the command, and the curve of Fig 8 (§F) of "
        f"{DOCUMENT} (command against velocity, which adds the integration). Needs "
        "excitation: a calm hover barely moves ('sim hover --excite 0.2').",
    )
    latency.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    add_json(latency)
    latency.set_defaults(func=Command(cmd_analyze_latency))
