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

import asyncio
import contextlib
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from mkflight.config import (
    Config,
    apply_override,
    config_from_dict,
    load_config,
    parse_override,
)
from mkflight.control.phases import Phase
from mkflight.errors import ConfigError, ReplayError
from mkflight.flight.app import FlightOptions, FlightReport
from mkflight.flight.step import ImuStepOutput
from mkflight.logs.events import read_events
from mkflight.logs.flight import extern_control_frames
from mkflight.logs.raw import read_raw
from mkflight.logs.table3 import COLUMNS as TABLE3_COLUMNS
from mkflight.logs.table3 import read_table3
from mkflight.logs.table4 import COLUMNS as TABLE4_COLUMNS
from mkflight.logs.table4 import read_table4
from mkflight.replay.compare import CommandComparison, compare_commands
from mkflight.replay.daemon import ReplayApp
from mkflight.replay.feeder import Feeder, FeedStats
from mkflight.replay.inputs import RecordedFlight, read_recorded_flight
from mkflight.replay.seed import (
    ColumnComparison,
    SeedClock,
    SeedFc,
    SeedMatcher,
    compare_columns,
    seed_urg,
)
from mkflight.replay.vloop import LockstepLoop, VirtualClock
from mkflight.safety.failsafe import StopRequest

TABLES = ("imu_50ms.log", "laser_100ms.log")
SEED_START_NS = 1_000 * 1_000_000_000  # a seed replay's lock-step clock starts here (any)
#: Config sections whose change alters what the scan matcher sees or computes.
MATCHER_SECTIONS = ("mk", "laser", "scanmatch")


@dataclass(frozen=True, slots=True)
class TableComparison:
    """One table of the replay against the original's: equal, or the first differing row."""

    name: str
    rows_original: int
    rows_replayed: int
    first_difference: int | None  # 1-based line number, None when equal
    original_line: str = ""
    replayed_line: str = ""

    @property
    def equal(self) -> bool:
        """The files are the same, line for line."""
        return self.first_difference is None


@dataclass(slots=True)
class ReplayReport:
    """What :func:`replay_flight` found."""

    source: Path
    out_dir: Path
    flight: FlightReport
    commands: CommandComparison
    tables: list[TableComparison]
    overrides: list[str]
    rematch: bool
    recorded_s: float
    wall_s: float
    cpu_s: float
    feed: FeedStats
    matcher: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    start_ns: int = 0
    #: a seed (tables only) replay: its tables against the seed's, column by column
    seed: SeedComparison | None = None

    @property
    def speedup(self) -> float:
        """Recorded seconds per wall-clock second."""
        return self.recorded_s / self.wall_s if self.wall_s > 0 else float("inf")

    @property
    def deterministic(self) -> bool:
        """Every command byte and every table row reproduced (never, for seed tables)."""
        return self.seed is None and self.commands.identical and all(t.equal for t in self.tables)


@dataclass(frozen=True, slots=True)
class SeedComparison:
    """A seed replay's tables against the seed's (rows paired from take-off on)."""

    imu_rows_played: int
    imu_rows: int
    laser_rows: int
    imu: list[ColumnComparison]
    laser: list[ColumnComparison]


def replay_config(recorded: dict[str, Any], overrides: list[str], source: Path) -> Config:
    """The recorded configuration with ``--set`` items on top, the matcher in-process.

    Raises:
        ConfigError: a bad ``--set`` (unknown key, wrong type), naming it.
        ReplayError: the recorded configuration itself does not load (another version).
    """
    data = msgspec.json.decode(msgspec.json.encode(recorded))  # a deep copy
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
    base = config_from_dict(msgspec.json.decode(msgspec.json.encode(recorded)))
    for name in MATCHER_SECTIONS:
        a, b = getattr(base, name), getattr(cfg, name)
        if name == "scanmatch":
            a = msgspec.structs.replace(a, worker="inline")
        if a != b:
            return True
    return False


def default_out_dir(source: Path) -> Path:
    """``<flight>-replay`` beside the flight, or ``-replay-2``, ``-3``... if taken."""
    source = source.resolve()  # "." has no name
    base = source.parent / f"{source.name}-replay"
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def _out_dir(source: Path, out_dir: str | Path | None) -> Path:
    """The new flight folder, created (empty); a usage error if that cannot be."""
    out = Path(out_dir) if out_dir is not None else default_out_dir(source)
    if out.exists() and not out.is_dir():
        msg = f"output folder {str(out)!r} is a file"
        raise ConfigError(msg)
    if out.exists() and any(out.iterdir()):
        msg = f"output folder {str(out)!r} is not empty: a flight folder is never overwritten"
        raise ConfigError(msg)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f"output folder {str(out)!r} cannot be created: {err.strerror or err}"
        raise ConfigError(msg) from err
    return out


def is_seed_folder(folder: Path) -> bool:
    """The seed's two tables and no raw recording at all (one of two missing: damaged)."""
    return (
        folder.is_dir()
        and not (folder / "mk.raw").exists()
        and not (folder / "laser.raw").exists()
        and all((folder / name).is_file() for name in TABLES)
    )


def compare_tables(
    original: Path, replayed: Path, warnings: list[str] | None = None
) -> list[TableComparison]:
    """Each table of the replay line by line against the original's.

    A table missing from the original is not compared (a warning says so).
    """
    out = []
    for name in TABLES:
        if not (original / name).is_file():
            if warnings is not None:
                warnings.append(f"{original / name}: missing: the replay's is not compared")
            continue
        a = _lines(original / name)
        b = _lines(replayed / name)
        first = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)
        if first is None and len(a) != len(b):
            first = min(len(a), len(b))
        out.append(
            TableComparison(
                name,
                max(len(a) - 1, 0),
                max(len(b) - 1, 0),
                None if first is None else first + 1,
                a[first] if first is not None and first < len(a) else "",
                b[first] if first is not None and first < len(b) else "",
            )
        )
    return out


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return []


async def _run(app: ReplayApp, feeder: Feeder) -> FlightReport:
    feeder.open_devices()
    try:
        return await app.fly()
    finally:
        feeder.close_devices()


def _run_lockstep(
    app: ReplayApp, feeder: Feeder, clock: VirtualClock, link_dir: Path
) -> FlightReport:
    """Fly ``app`` on a lock-step loop fed by ``feeder``; always clean up.

    SIGINT/SIGTERM stop the replay, not the replayed vehicle (:class:`ReplayApp`): the
    daemon is cancelled - it still closes its ports and its folder - and
    KeyboardInterrupt goes on to the caller.
    """
    loop = LockstepLoop(clock, feeder)
    asyncio.set_event_loop(loop)
    main = loop.create_task(_run(app, feeder))
    try:
        return loop.run_until_complete(main)
    except KeyboardInterrupt:
        main.cancel()
        with contextlib.suppress(BaseException):
            loop.run_until_complete(main)
        raise
    finally:
        with contextlib.suppress(Exception):
            loop.run_until_complete(loop.shutdown_asyncgens())
        asyncio.set_event_loop(None)
        loop.close()
        shutil.rmtree(link_dir, ignore_errors=True)


def replay_flight(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    speed: float | None = None,
    rematch: bool = False,
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
    out = _out_dir(rec.folder, out_dir)

    clock = VirtualClock(rec.start_ns)
    link_dir = Path(tempfile.mkdtemp(prefix="mkflight-replay-"))
    feeder = Feeder(
        rec.inputs,
        clock,
        link_dir,
        speed=speed,
        on_progress=None if on_progress is None else (lambda n: on_progress(n, feeder.total)),
    )
    opts = FlightOptions(
        mk_port=feeder.path("mk"),
        laser_port=feeder.path("laser"),
        log_dir=out,
        durable_logs=False,
    )
    app = ReplayApp(
        cfg,
        opts,
        clock=clock,
        feeder=feeder,
        scans=rec.scans,
        use_recorded_poses=use_recorded,
        ready_ns=rec.ready_ns,
        step_stops=rec.step_stops,
    )
    feeder.set_stop(app.request_stop)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    report = _run_lockstep(app, feeder, clock, link_dir)
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    if on_progress is not None:
        on_progress(feeder.total, feeder.total)

    original = extern_control_frames(rec.recordings["mk"])
    replayed = extern_control_frames(read_raw(out / "mk.raw")) if (out / "mk.raw").exists() else []
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
            f"{rec.folder / 'events.jsonl'}: no scan poses recorded: scans matched again"
        )
    if feeder.stats.dropped or feeder.stats.never_read_bytes:
        warnings.append(
            f"{feeder.stats.dropped} recorded chunks came after the replayed daemon had "
            f"closed the port; {feeder.stats.never_read_bytes} bytes were never read"
        )
    return ReplayReport(
        source=rec.folder,
        out_dir=out,
        flight=report,
        commands=compare_commands(original, replayed, end_ns=None if rec.completed else rec.end_ns),
        tables=compare_tables(rec.folder, out, warnings),
        overrides=overrides,
        rematch=not use_recorded,
        recorded_s=rec.duration_s,
        wall_s=wall_s,
        cpu_s=cpu_s,
        feed=feeder.stats,
        matcher=app.replay_stats(),
        warnings=warnings,
        start_ns=rec.start_ns,
    )


def _seed_comparison(
    seed_dir: Path,
    out: Path,
    imu_seed: np.ndarray,
    laser_seed: np.ndarray,
    rows_played: int,
    first_step: int | None,
    rows_used: dict[int, int],
) -> SeedComparison:
    """Pair the replay's rows with the seed rows they came from; compare the columns."""
    imu_ours = read_table4(out / "imu_50ms.log").rows if (out / "imu_50ms.log").exists() else None
    imu_cmp: list[ColumnComparison] = []
    if imu_ours is not None and first_step is not None:
        ours = imu_ours[imu_ours["index"] >= first_step][:rows_played]
        imu_cmp = compare_columns(ours, imu_seed[: len(ours)], TABLE4_COLUMNS[:9])
    laser_cmp: list[ColumnComparison] = []
    if (out / "laser_100ms.log").exists() and (out / "events.jsonl").exists():
        rows3 = read_table3(out / "laser_100ms.log").rows
        by_index = {int(r["index"]): r for r in rows3}
        pairs = []
        for ev in read_events(out / "events.jsonl").events:
            index = ev.fields.get("index")
            if (
                ev.event == "scan"
                and isinstance(index, int)
                and ev.t_ns in rows_used
                and index in by_index
            ):
                pairs.append((by_index[index], laser_seed[rows_used[ev.t_ns]]))
        if pairs:
            ours3 = np.array([p[0] for p in pairs], dtype=rows3.dtype)
            seed3 = np.array([p[1] for p in pairs], dtype=laser_seed.dtype)
            laser_cmp = compare_columns(ours3, seed3, TABLE3_COLUMNS[:9])
    return SeedComparison(rows_played, len(imu_seed), len(laser_seed), imu_cmp, laser_cmp)


def replay_seed(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    speed: float | None = None,
) -> ReplayReport:
    """Replay a folder of the seed's two tables (:mod:`mkflight.replay.seed`).

    The configuration is the built-in one with ``--set`` on top (the seed's tables do
    not say which was flown).

    Raises:
        ReplayError: a table cannot be read (file and line named) or is empty.
        ConfigError: a bad ``--set``.
    """
    folder = Path(source)
    overrides = list(overrides or [])
    imu_data = read_table4(folder / "imu_50ms.log")
    laser_data = read_table3(folder / "laser_100ms.log")
    warnings = [
        f"{d.path}: last line cut short: dropped" for d in (imu_data, laser_data) if d.truncated
    ]
    imu_seed, laser_seed = imu_data.rows, laser_data.rows
    for d, rows in ((imu_data, imu_seed), (laser_data, laser_seed)):
        if len(rows) == 0:
            msg = f"{d.path}: no rows to replay"
            raise ReplayError(msg)
    cfg = load_config(None, overrides)
    cfg = msgspec.structs.replace(
        cfg, scanmatch=msgspec.structs.replace(cfg.scanmatch, worker="inline")
    )
    out = _out_dir(folder, out_dir)
    clock = VirtualClock(SEED_START_NS)
    seed_clock = SeedClock(len(imu_seed), len(laser_seed))
    link_dir = Path(tempfile.mkdtemp(prefix="mkflight-replay-"))
    app_ref: list[ReplayApp] = []

    def on_end(t_ns: int) -> None:
        if app_ref:
            app_ref[0].request_stop(StopRequest.DURATION, "the seed's TABLE IV ended")

    fc = SeedFc(cfg, imu_seed, seed_clock, t_ns=SEED_START_NS, on_end=on_end)
    urg = seed_urg(cfg, laser_seed, seed_clock, SEED_START_NS)
    feeder = Feeder([], clock, link_dir, speed=speed, models={"mk": fc, "laser": urg})
    opts = FlightOptions(
        mk_port=feeder.path("mk"),
        laser_port=feeder.path("laser"),
        log_dir=out,
        durable_logs=False,
    )
    app = ReplayApp(cfg, opts, clock=clock, feeder=feeder, scans={}, use_recorded_poses=False)
    matcher = SeedMatcher(cfg, laser_seed, seed_clock)
    app.worker = matcher
    app_ref.append(app)
    first_step: list[int] = []

    def on_step(out_: ImuStepOutput) -> None:
        if seed_clock.start_ns is None and out_.phase is Phase.TAKEOFF:
            seed_clock.start_ns = clock.now_ns()
            first_step.append(app.core.counters.imu_steps + 1)

    app.on_step = on_step
    cpu0, wall0 = time.process_time(), time.perf_counter()
    report = _run_lockstep(app, feeder, clock, link_dir)
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    if fc.rows_sent < len(imu_seed):
        warnings.append(
            f"the replayed flight ended after {fc.rows_sent} of {len(imu_seed)} TABLE IV rows"
        )
    replayed = extern_control_frames(read_raw(out / "mk.raw")) if (out / "mk.raw").exists() else []
    return ReplayReport(
        source=folder,
        out_dir=out,
        flight=report,
        commands=compare_commands([], replayed),
        tables=[],
        overrides=overrides,
        rematch=True,
        recorded_s=(clock.now_ns() - SEED_START_NS) / 1e9,
        wall_s=wall_s,
        cpu_s=cpu_s,
        feed=feeder.stats,
        matcher={"seed_poses": len(matcher.rows_used)},
        warnings=warnings,
        start_ns=SEED_START_NS,
        seed=_seed_comparison(
            folder,
            out,
            imu_seed,
            laser_seed,
            fc.rows_sent,
            first_step[0] if first_step else None,
            matcher.rows_used,
        ),
    )
