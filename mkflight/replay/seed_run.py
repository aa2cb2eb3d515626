"""Replaying a folder of the seed's two tables: the run (its models: ``replay.seed``)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import msgspec
import numpy as np

from mkflight.config import load_config
from mkflight.control.phases import Phase
from mkflight.errors import ReplayError
from mkflight.flight.app import FlightOptions
from mkflight.flight.step import ImuStepOutput
from mkflight.logs.events import read_events
from mkflight.logs.flight import extern_control_frames
from mkflight.logs.raw import read_raw
from mkflight.logs.schema import Scan
from mkflight.logs.table3 import COLUMNS as TABLE3_COLUMNS
from mkflight.logs.table3 import read_table3
from mkflight.logs.table4 import COLUMNS as TABLE4_COLUMNS
from mkflight.logs.table4 import read_table4
from mkflight.replay.compare import compare_commands
from mkflight.replay.daemon import ReplayApp
from mkflight.replay.feeder import Feeder
from mkflight.replay.report import TABLES, ReplayReport, SeedComparison
from mkflight.replay.seed import (
    ColumnComparison,
    SeedClock,
    SeedFc,
    SeedMatcher,
    compare_columns,
    seed_urg,
)
from mkflight.replay.session import out_dir_for, run_lockstep
from mkflight.replay.vloop import VirtualClock
from mkflight.safety.failsafe import StopRequest

SEED_START_NS = 1_000 * 1_000_000_000  # a seed replay's lock-step clock starts here (any)
#: The tables start at take-off; a daemon still on the ground this long after the start
#: never takes off (e.g. TABLE III's first pose is NaN or far outside the room: no valid
#: fix), and the replay, which would otherwise run on forever, ends (one normally takes
#: off about 2.5 s in).
TAKEOFF_TIMEOUT_NS = 30 * 1_000_000_000


def is_seed_folder(folder: Path) -> bool:
    """The seed's two tables and no raw recording at all (one of two missing: damaged)."""
    return (
        folder.is_dir()
        and not (folder / "mk.raw").exists()
        and not (folder / "laser.raw").exists()
        and all((folder / name).is_file() for name in TABLES)
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
            index = ev.index if isinstance(ev, Scan) else None
            if index is not None and ev.t_ns in rows_used and index in by_index:
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
    out = out_dir_for(folder, out_dir)
    clock = VirtualClock(SEED_START_NS)
    seed_clock = SeedClock(len(imu_seed), len(laser_seed))
    link_dir = Path(tempfile.mkdtemp(prefix="mkflight-replay-"))
    app_ref: list[ReplayApp] = []

    def on_end(t_ns: int) -> None:
        if app_ref:
            app_ref[0].request_stop(StopRequest.DURATION, "the seed's TABLE IV ended")

    fc = SeedFc(cfg, imu_seed, seed_clock, t_ns=SEED_START_NS, on_end=on_end)
    urg = seed_urg(cfg, laser_seed, seed_clock, SEED_START_NS)
    feeder = Feeder(
        [], clock, link_dir, speed=speed, models={"mk": fc, "laser": urg}, memory=speed is None
    )
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
        elif (
            seed_clock.start_ns is None
            and app.stop_request is None
            and clock.now_ns() > SEED_START_NS + TAKEOFF_TIMEOUT_NS
        ):
            app.request_stop(
                StopRequest.DURATION, f"no take-off in {TAKEOFF_TIMEOUT_NS // 1_000_000_000} s"
            )

    app.on_step = on_step
    cpu0, wall0 = time.process_time(), time.perf_counter()
    report = run_lockstep(app, feeder, clock, link_dir)
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    if seed_clock.start_ns is None:
        warnings.append(
            f"the replayed daemon did not take off within {TAKEOFF_TIMEOUT_NS / 1e9:.0f} s: "
            f"no TABLE IV row was played (is {folder / 'laser_100ms.log'}'s first pose valid?)"
        )
    elif fc.rows_sent < len(imu_seed):
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
