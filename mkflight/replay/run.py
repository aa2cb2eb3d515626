"""``mkflight replay``: a recorded flight back through mock serial ports (SPEC §6).

:func:`replay_flight` reads the flight folder (:mod:`~mkflight.replay.inputs`), starts
a lock-step event loop (:mod:`~mkflight.replay.vloop`) with two ptys fed from the
recording (:mod:`~mkflight.replay.feeder`), runs the flight daemon on them
(:class:`~mkflight.replay.daemon.ReplayApp`: the same pre-flight, link, driver, parser,
tasks and step as ``fly``) into a new flight folder, and compares what it sent with what
the original sent (:mod:`~mkflight.replay.compare`) and the two tables with the
original's.

The configuration is the one recorded in ``flight.json``, with ``--set`` on top (a
"what if"). The scan matcher's results are the recorded ones unless a ``--set`` changes
what the matcher sees or does (``mk`` calibration, ``laser``, ``scanmatch``) or
``--rematch`` asks for it: then the real matcher runs in-process on the replayed scans,
which costs ~1-2 ms a scan.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from mkflight.config import Config, apply_override, config_from_dict, parse_override
from mkflight.errors import ConfigError, ReplayError
from mkflight.flight.app import FlightReport
from mkflight.logs.flight import extern_control_frames
from mkflight.logs.raw import read_raw
from mkflight.replay.compare import compare_commands
from mkflight.replay.daemon import ReplayApp, replay_options
from mkflight.replay.feeder import Feeder
from mkflight.replay.inputs import RecordedFlight, read_recorded_flight
from mkflight.replay.report import ReplayReport, compare_tables, last_rows
from mkflight.replay.seed_run import is_seed_folder, replay_seed
from mkflight.replay.session import out_dir_for, run_lockstep
from mkflight.replay.vloop import VirtualClock

__all__ = ["ReplayReport", "replay_flight", "replay_seed"]

#: Config sections whose change alters what the scan matcher sees or computes.
MATCHER_SECTIONS = ("mk", "laser", "scanmatch")


#: Keys added after flights were recorded without them, with the value that does what those
#: flights did (the key's default may do otherwise): (section, key) -> value.
BEFORE_THE_KEY: dict[tuple[str, str], Any] = {
    ("mk", "confirm_every"): 1,  # every command was numbered for a confirm
}


def with_keys_of_their_time(recorded: dict[str, Any]) -> dict[str, Any]:
    """``recorded`` with each key of :data:`BEFORE_THE_KEY` it lacks set to what it did then."""
    for (section, key), value in BEFORE_THE_KEY.items():
        part = recorded.get(section)
        if isinstance(part, dict) and key not in part:
            part[key] = value
    return recorded


def replay_config(recorded: dict[str, Any], overrides: list[str], source: Path) -> Config:
    """The recorded configuration with ``--set`` items on top, the matcher in-process.

    Raises:
        ConfigError: a bad ``--set`` (unknown key, wrong type), naming it.
        ReplayError: the recorded configuration itself does not load (another version).
    """
    data = with_keys_of_their_time(msgspec.json.decode(msgspec.json.encode(recorded)))  # a copy
    try:
        base = config_from_dict(data, f"{source}/flight.json config")
    except ConfigError as err:
        msg = f"{err} (recorded by another mkflight version?)"
        raise ReplayError(msg) from err
    for item in overrides:
        parts, value = parse_override(item)
        apply_override(data, parts, value)
    cfg = config_from_dict(data, "recorded config with --set") if overrides else base
    return msgspec.structs.replace(
        cfg, scanmatch=msgspec.structs.replace(cfg.scanmatch, worker="inline")
    )


def matcher_changed(recorded: dict[str, Any], cfg: Config) -> bool:
    """Does ``cfg`` change what the scan matcher sees or does (its worker aside)?"""
    base = config_from_dict(
        with_keys_of_their_time(msgspec.json.decode(msgspec.json.encode(recorded)))
    )
    for name in MATCHER_SECTIONS:
        a, b = getattr(base, name), getattr(cfg, name)
        if name == "scanmatch":
            a = msgspec.structs.replace(a, worker="inline")
        if a != b:
            return True
    return False


def replay_flight(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    speed: float | None = None,
    rematch: bool = False,
    ptys: bool = False,
    on_progress: Callable[[int, int], None] | None = None,
) -> ReplayReport:
    """Replay the flight folder ``source`` into ``out_dir`` (see the module docstring).

    Args:
        source: the recorded flight folder.
        out_dir: the new flight folder (default :func:`default_out_dir`); must not exist
            or be empty.
        overrides: ``--set`` items (``control.kp_xy=1.2``).
        speed: pace the recorded time at this multiple of real time; None: as fast as
            the daemon consumes it.
        rematch: run the scan matcher on the replayed scans even if the recorded
            results would do.
        ptys: play through pseudo-terminals even when not paced (``speed`` None plays
            from memory otherwise: :mod:`~mkflight.replay.memport`).
        on_progress: called with (inputs delivered, inputs in all) now and then.

    Raises:
        ReplayError: the folder cannot be replayed (names the file and offset).
        ConfigError: a bad ``--set``.
    """
    overrides = list(overrides or [])
    if is_seed_folder(Path(source)):
        return replay_seed(source, out_dir, overrides=overrides, speed=speed)
    rec: RecordedFlight = read_recorded_flight(source)
    cfg = replay_config(rec.config, overrides, rec.folder)
    use_recorded = rec.has_poses and not rematch and not matcher_changed(rec.config, cfg)
    out = out_dir_for(rec.folder, out_dir)

    clock = VirtualClock(rec.start_ns)
    link_dir = Path(tempfile.mkdtemp(prefix="mkflight-replay-"))
    feeder = Feeder(
        rec.inputs,
        clock,
        link_dir,
        speed=speed,
        on_progress=None if on_progress is None else (lambda n: on_progress(n, feeder.total)),
        memory=speed is None and not ptys,
    )
    app = _replay_app(cfg, rec, out, feeder, clock, use_recorded_poses=use_recorded)
    feeder.set_stop(app.request_stop)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    report = run_lockstep(app, feeder, clock, link_dir)
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    if on_progress is not None:
        on_progress(feeder.total, feeder.total)
    return _report(
        rec,
        out,
        app,
        feeder,
        report,
        overrides=overrides,
        rematch=not use_recorded,
        wall_s=wall_s,
        cpu_s=cpu_s,
    )


def _replay_app(
    cfg: Config,
    rec: RecordedFlight,
    out: Path,
    feeder: Feeder,
    clock: VirtualClock,
    *,
    use_recorded_poses: bool,
) -> ReplayApp:
    """The daemon on the feeder's ports, writing into ``out``, held to the recording's timing."""
    opts = replay_options(feeder, out)
    return ReplayApp(
        cfg,
        opts,
        clock=clock,
        feeder=feeder,
        scans=rec.scans,
        use_recorded_poses=use_recorded_poses,
        ready_ns=rec.ready_ns,
        subscribe_ns=rec.subscribe_ns,
        step_stops=rec.step_stops,
        intact_end_ns=rec.intact_end_ns,
    )


def _warnings(rec: RecordedFlight, feeder: Feeder) -> list[str]:
    """What limits the comparison: the recording's own warnings, then the feed's."""
    warnings = list(rec.warnings)
    if not rec.completed:
        warnings.append(
            f"{rec.folder / 'flight.json'}: no summary: the flight was killed; what the "
            "replay sent after the recording ended is not compared"
        )
    if feeder.stats.pty_dropped_bytes:
        warnings.append(f"{feeder.stats.pty_dropped_bytes} bytes did not fit into a pty")
    if not rec.has_poses:
        warnings.append(
            f"{rec.folder / 'events.jsonl'}: no scan poses recorded (a flight from before "
            "replay existed): scans matched again, each entering at the next step; where "
            "the matcher's timing mattered in flight the check will differ"
        )
    if feeder.stats.dropped or feeder.stats.never_read_bytes:
        warnings.append(
            f"{feeder.stats.dropped} recorded chunks came after the replayed daemon had "
            f"closed the port; {feeder.stats.never_read_bytes} bytes were never read"
        )
    return warnings


def _report(
    rec: RecordedFlight,
    out: Path,
    app: ReplayApp,
    feeder: Feeder,
    report: FlightReport,
    *,
    overrides: list[str],
    rematch: bool,
    wall_s: float,
    cpu_s: float,
) -> ReplayReport:
    """Compare what the replay sent and wrote with the recording, up to where both are whole."""
    original = extern_control_frames(rec.recordings["mk"])
    replayed = extern_control_frames(read_raw(out / "mk.raw")) if (out / "mk.raw").exists() else []
    warnings = _warnings(rec, feeder)
    end_ns = None if rec.completed else rec.end_ns
    upto = None if rec.completed else last_rows(rec.folder)
    if rec.intact_end_ns is not None:
        end_ns = rec.intact_end_ns
        upto = app.rows_at_intact_end
    return ReplayReport(
        source=rec.folder,
        out_dir=out,
        flight=report,
        commands=compare_commands(original, replayed, end_ns=end_ns),
        tables=compare_tables(rec.folder, out, warnings, upto),
        overrides=overrides,
        rematch=rematch,
        recorded_s=rec.duration_s,
        wall_s=wall_s,
        cpu_s=cpu_s,
        feed=feeder.stats,
        matcher=app.replay_stats(),
        warnings=warnings,
        start_ns=rec.start_ns,
    )
