"""``mkflight analyze precision|latency LOGDIR``: the seed's §O-P and §F analyses of a flight."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mkflight.analysis.latency import SEED_LAG_STEPS, WEAK_PEAK_R, estimate_latency
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
from mkflight.logs.table3 import FILE_NAME as TABLE3_FILE
from mkflight.logs.table3 import read_table3
from mkflight.logs.table4 import FILE_NAME as TABLE4_FILE
from mkflight.logs.table4 import read_table4


def _existing(folder: Path, name: str) -> Path:
    """``folder/name``, checked to exist and not be empty."""
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
    try:
        return path.read_text(encoding="utf-8")
    except OSError as err:
        msg = f"{path}: cannot read: {err.strerror or err}"
        raise AnalysisInputError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{path}: not UTF-8 text (byte {err.start}): {err.reason}"
        raise AnalysisInputError(msg) from err


def cmd_analyze_precision(*, log_dir: str, truth: str | None, as_json: bool) -> int:
    """Print the hover precision of a flight folder beside the seed's TABLE IX (§O-P).

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
    p = precision(samples, source)
    if as_json:
        print(json.dumps(p.as_dict()))
        return 0
    print(
        f"hover precision of {folder} (seed §O-P): {p.samples} HOLD steps from "
        f"{SETTLE_S:g} s after HOLD began, position = {source}, error = position - set-point"
    )
    print(f"{'':28}{'x m':>10}{'y m':>10}{'z m':>10}")
    for stat in ("mean", "std", "rms", "max"):
        vals = [getattr(a, f"{stat}_m") for a in (p.x, p.y, p.z)]
        label = "max |err|" if stat == "max" else stat
        print(f"  this flight  {label:<14}" + "".join(f"{v:10.4f}" for v in vals))
    print("seed TABLE IX (hovering):")
    for row in SEED_TABLE_IX:
        print(f"  {row.name:<18} {row.kind:<7}{row.x_m:10.4f}{row.y_m:10.4f}{row.z_m:10.4f}")
    return 0


def cmd_analyze_latency(*, log_dir: str, as_json: bool) -> int:
    """Print the command-to-velocity lag of a flight by cross-correlation (seed §F, Fig 8).

    Args:
        log_dir: the flight folder (its ``imu_50ms.log`` and ``laser_100ms.log``).
        as_json: one object with ``lag_steps``, ``lag_s``, ``curve`` (lags 0..20), and the
            per-axis ``lag_x_steps``, ``curve_x``, ``lag_y_steps``, ``curve_y``.

    Raises:
        AnalysisInputError: a missing or empty log, or no correlation (exit 1).
        ReplayError: a malformed table row (file and line; exit 1).
    """
    folder = Path(log_dir)
    t4 = read_table4(_existing(folder, TABLE4_FILE)).rows
    t3 = read_table3(_existing(folder, TABLE3_FILE)).rows
    for rows, name in ((t4, TABLE4_FILE), (t3, TABLE3_FILE)):
        if len(rows) < 3:
            msg = f"{folder / name}: {len(rows)} rows, too few to correlate"
            raise AnalysisInputError(msg)
    # The rows' times: the step events' (one per TABLE IV row), else index x 50 ms.
    t4_s = None
    events_path = folder / EVENTS_FILE
    if events_path.is_file() and events_path.stat().st_size > 0:
        steps = [e.t_ns for e in read_events(events_path).events if e.event == "step"]
        if len(steps) == len(t4):
            t4_s = np.asarray(steps, dtype=np.float64) / 1e9
    lat = estimate_latency(
        t4_s=t4_s,
        index4=np.asarray(t4["index"], dtype=np.float64),
        control_pitch_counts=np.asarray(t4["ControlPitch"], dtype=np.float64),
        control_roll_counts=np.asarray(t4["ControlRoll"], dtype=np.float64),
        index3=np.asarray(t3["index"], dtype=np.float64),
        b_vel_x_mps=np.asarray(t3["B_Vel.x"], dtype=np.float64),
        b_vel_y_mps=np.asarray(t3["B_Vel.y"], dtype=np.float64),
    )
    if as_json:
        print(json.dumps(lat.as_dict()))
        return 0
    print(
        f"response lag of {folder} (seed §F, Fig 8): {lat.lag_steps} steps = "
        f"{lat.lag_s * 1000:.0f} ms at {lat.period_s * 1000:.1f} ms a step "
        f"(x: {lat.lag_x_steps}, y: {lat.lag_y_steps}; "
        f"the seed: ~{SEED_LAG_STEPS} steps = {SEED_LAG_STEPS * 50} ms)"
    )
    print(
        "  commanded tilt -> body velocity: attitude delay and lag plus the integration "
        "to velocity; not a pure transport delay"
    )
    if lat.peak_r < WEAK_PEAK_R:
        print(
            f"  weak peak (r = {lat.peak_r:.2f} < {WEAK_PEAK_R}): too little excitation "
            "(a calm closed-loop hover); fly steps or stick inputs for a reliable lag"
        )
    print(f"  {'lag':>4} {'ms':>5} {'r':>7} {'r_x':>7} {'r_y':>7}")
    for k in range(len(lat.curve)):
        r = [f"{float(a[k]):7.3f}" for a in (lat.curve, lat.curve_x, lat.curve_y)]
        mark = "  <- peak" if k == lat.lag_steps else ""
        print(f"  {k:4d} {k * lat.period_s * 1000:5.0f} {' '.join(r)}{mark}")
    return 0
