"""``mkflight replay LOGDIR``: a recorded flight back through mock ports (SPEC §6, §7).

Prints what the replay found: the determinism check (ExternControl frames and tables
against the original's; the first difference with its time and both frames) or, with
``--set``, how the commands differ; the pace reached; and every warning about the input
(a truncated recording is replayed as far as it is readable). Exit 0 when the replay ran
and, without ``--set``, reproduced the original exactly (a folder of the original
system's two tables: when it ran); 1 when it did not, or when the input cannot be replayed (the file
and byte offset named); 2 on bad usage (a bad ``--set``, an ``--out`` in use).

A folder with only the original system's TABLE III and IV is replayed as
:mod:`mkflight.replay.seed` describes, and the report sets each column of the replay's
tables beside the original's.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mkflight.cli_types import positive, printable
from mkflight.commands.args import Command, Subparsers, add_json
from mkflight.conversions import NS_PER_S
from mkflight.errors import ReplayError

if TYPE_CHECKING:
    from mkflight.replay.compare import CommandComparison
    from mkflight.replay.report import ReplayReport


def _updater(bar: Any) -> Callable[[int, int], None] | None:
    """``on_progress`` for :func:`replay_flight` drawing on ``bar`` (None: no bar)."""
    if bar is None:
        return None

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    return update


def _decoded(wire: bytes | None) -> str:
    from mkflight.mk.codec import FrameParser
    from mkflight.mk.messages import ExternControl

    if wire is None:
        return "(none)"
    frames = [f for f in FrameParser().feed(wire) if f.cmd == "b"]
    if not frames:
        return wire.decode("ascii", "replace")
    c = ExternControl.decode(frames[0])
    text = wire.decode("ascii", "replace").rstrip("\r")
    return f"{text}  nick {c.nick} roll {c.roll} yaw {c.yaw} gas {c.gas} config {c.config}"


def _t(t_ns: int | None, start_ns: int) -> str:
    return "-" if t_ns is None else f"{(t_ns - start_ns) / NS_PER_S:.3f} s"


def _command_lines(c: CommandComparison, start_ns: int, what_if: bool) -> list[str]:
    after = f"; {c.n_after_end} more after the recording ended" if c.n_after_end else ""
    lines = [
        f"ExternControl: {c.n_identical} of {c.n_original} recorded frames identical "
        f"({c.n_replayed} sent in the replay{after})"
    ]
    if c.first is not None:
        f = c.first
        lines += [
            f"  first difference: frame {f.index + 1}, at {_t(f.t_original_ns, start_ns)} "
            f"(original) / {_t(f.t_replayed_ns, start_ns)} (replay) after the recording began",
            f"    original  {_decoded(f.original)}",
            f"    replayed  {_decoded(f.replayed)}",
        ]
    if what_if or c.first is not None:
        for ch in c.channels:
            if ch.frames_differing:
                lines.append(
                    f"  {ch.name:<6} differs in {ch.frames_differing} frames: mean |diff| "
                    f"{ch.mean_abs:.2f}, max {ch.max_abs} counts (mean {ch.mean_original:.2f} "
                    f"-> {ch.mean_replayed:.2f})"
                )
    return lines


def _seed_lines(r: ReplayReport) -> list[str]:
    s = r.seed
    if s is None:
        return []
    lines = [
        f"original tables: {s.imu_rows_played} of {s.imu_rows} TABLE IV rows played as DebugOut, "
        f"{s.laser_rows} TABLE III poses stood in for the scan matcher",
        f"  {'column':<22} {'rows':>5} {'rms diff':>10} {'max diff':>10} {'corr':>6}",
    ]
    for c in [*s.imu, *s.laser]:
        corr = "-" if c.correlation != c.correlation else f"{c.correlation:.3f}"
        lines.append(
            f"  {c.name:<22} {c.n:>5} {c.rms_diff:>10.4g} {c.max_abs_diff:>10.4g} {corr:>6}"
        )
    lines.append("  (ours - original; the replay's flight began at its own take-off)")
    return lines


def report_lines(r: ReplayReport) -> list[str]:
    """The human-readable report."""
    if r.seed is not None:
        return [
            f"replayed the original system's tables {r.source} -> {r.out_dir}",
            f"  {r.recorded_s:.1f} s flown in {r.wall_s:.2f} s (CPU {r.cpu_s:.2f} s)",
            f"  flight: {r.flight.reason} (exit {r.flight.exit_code})",
            *(["  what if: " + ", ".join(r.overrides)] if r.overrides else []),
            *_seed_lines(r),
        ]
    pace = f"{r.speedup:.0f}x real time"
    lines = [
        f"replayed {r.source} -> {r.out_dir}",
        f"  {r.recorded_s:.1f} s recorded in {r.wall_s:.2f} s ({pace}; CPU {r.cpu_s:.2f} s); "
        f"scan poses: {'matched again' if r.rematch else 'as recorded'}",
        f"  flight: {r.flight.reason} (exit {r.flight.exit_code})",
    ]
    if r.overrides:
        lines.append("  what if: " + ", ".join(r.overrides))
    lines += _command_lines(r.commands, r.start_ns, bool(r.overrides))
    for t in r.tables:
        if t.equal:
            lines.append(f"{t.name}: {t.rows_replayed} rows, identical")
        else:
            lines += [
                f"{t.name}: {t.rows_original} rows recorded, {t.rows_replayed} replayed; "
                f"first difference on line {t.first_difference}",
                f"    original  {t.original_line}",
                f"    replayed  {t.replayed_line}",
            ]
    if not r.overrides:
        lines.append(
            "determinism check: " + ("passed (byte-identical)" if r.deterministic else "FAILED")
        )
    return lines


def report_json(r: ReplayReport) -> dict[str, Any]:
    """The report as one JSON-able object."""
    c = r.commands
    first = None
    if c.first is not None:
        first = {
            "frame": c.first.index + 1,
            "t_original_s": None
            if c.first.t_original_ns is None
            else (c.first.t_original_ns - r.start_ns) / NS_PER_S,
            "t_replayed_s": None
            if c.first.t_replayed_ns is None
            else (c.first.t_replayed_ns - r.start_ns) / NS_PER_S,
            "original": None
            if c.first.original is None
            else c.first.original.decode("ascii", "replace"),
            "replayed": None
            if c.first.replayed is None
            else c.first.replayed.decode("ascii", "replace"),
        }
    return {
        "source": str(r.source),
        "out_dir": str(r.out_dir),
        "overrides": r.overrides,
        "deterministic": r.deterministic,
        "flight_exit_code": r.flight.exit_code,
        "flight_reason": r.flight.reason,
        "recorded_s": r.recorded_s,
        "wall_s": r.wall_s,
        "cpu_s": r.cpu_s,
        "speedup": r.speedup,
        "rematch": r.rematch,
        "commands": {
            "original": c.n_original,
            "replayed": c.n_replayed,
            "identical": c.n_identical,
            "first_difference": first,
            "channels": {
                ch.name: {
                    "frames_differing": ch.frames_differing,
                    "mean_abs": ch.mean_abs,
                    "max_abs": ch.max_abs,
                    "mean_original": ch.mean_original,
                    "mean_replayed": ch.mean_replayed,
                }
                for ch in c.channels
            },
        },
        "tables": {
            t.name: {
                "rows_original": t.rows_original,
                "rows_replayed": t.rows_replayed,
                "first_difference_line": t.first_difference,
            }
            for t in r.tables
        },
        "matcher": r.matcher,
        "feed": {
            "inputs": r.feed.delivered,
            "dropped": r.feed.dropped,
            "never_read_bytes": r.feed.never_read_bytes,
        },
        "warnings": r.warnings,
        "seed": None
        if r.seed is None
        else {
            "imu_rows_played": r.seed.imu_rows_played,
            "imu_rows": r.seed.imu_rows,
            "laser_rows": r.seed.laser_rows,
            "columns": {
                c.name: {
                    "rows": c.n,
                    "rms_diff": c.rms_diff,
                    "max_abs_diff": c.max_abs_diff,
                    "correlation": c.correlation,
                }
                for c in [*r.seed.imu, *r.seed.laser]
            },
        },
    }


def cmd_replay(
    *,
    log_dir: str,
    speed: float | None,
    overrides: list[str],
    out: str | None,
    rematch: bool,
    as_json: bool,
    ptys: bool = False,
) -> int:
    """Replay ``log_dir`` (see the module docstring).

    Raises:
        ReplayError: the folder cannot be replayed (file and offset named).
        ConfigError: a bad ``--set`` or a non-empty ``--out``.
    """
    from mkflight.commands.progress import tty_bar
    from mkflight.logs.flight_json import json_safe
    from mkflight.replay.run import replay_flight

    with tty_bar(0, "rec") as bar:
        report = replay_flight(
            log_dir,
            out,
            overrides=overrides,
            speed=speed,
            rematch=rematch,
            ptys=ptys,
            on_progress=None if as_json else _updater(bar),
        )
    # The report quotes the log (a stop reason, table rows): escaped, nothing a terminal obeys.
    for w in report.warnings:
        print(f"warning: {printable(w)}", file=sys.stderr)
    if as_json:
        print(json.dumps(json_safe(report_json(report)), allow_nan=False))
    else:
        print("\n".join(printable(line) for line in report_lines(report)))
    if report.seed is None and not overrides and not report.deterministic:
        msg = "determinism check failed: the replay did not reproduce the recorded commands"
        raise ReplayError(msg)
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``replay LOGDIR`` (SPEC §6, §7)."""
    replay = subparsers.add_parser(
        "replay",
        help="replay a recorded flight through mock serial ports into the daemon",
        description="Plays a flight folder's recorded FC and URG bytes (mk.raw, laser.raw) "
        "into the unchanged flight daemon (from memory with --fast, the default; through two "
        "pseudo-terminals with --speed or --ptys), on a lock-step clock "
        "that gives every byte its recorded time, and writes a new flight folder. With the "
        "recorded configuration the ExternControl bytes and both tables must come out "
        "identical (the determinism check: exit 1 and the first difference if not); with "
        "--set it shows what the controller would have sent instead. The scan poses are "
        "the recorded ones unless --set changes the mk, laser or scanmatch sections or "
        "--rematch is given.",
    )
    replay.add_argument("log_dir", metavar="LOGDIR", help="the recorded flight folder")
    pace = replay.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed",
        type=positive,
        metavar="X",
        help="play at X times the recorded pace (1 = real time)",
    )
    pace.add_argument(
        "--fast", action="store_true", help="as fast as the daemon takes it (the default)"
    )
    replay.add_argument(
        "--set",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        dest="overrides",
        help="what if: override a key of the recorded config, e.g. --set control.kp_xy=1.2",
    )
    replay.add_argument(
        "--out", metavar="DIR", help="the new flight folder (default LOGDIR-replay)"
    )
    replay.add_argument(
        "--rematch", action="store_true", help="run the scan matcher again on the replayed scans"
    )
    replay.add_argument(
        "--ptys",
        action="store_true",
        help="play through two pseudo-terminals and the real serial stack even with --fast "
        "(slower; --speed always does)",
    )
    add_json(replay, "the report as one JSON object")
    replay.set_defaults(func=Command(cmd_replay))
