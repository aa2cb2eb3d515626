"""Replaying a folder of the original system's two tables alone: the run.

A folder with TABLE III and TABLE IV of the 2011 QUT CyPhy MikroKopter documentation's
format and no raw recording is played through the device models of
:mod:`mkflight.replay.seed`: this module puts the run together and sets the replay's own
tables beside the original ones.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import numpy.typing as npt

from mkflight.config import Config, load_config
from mkflight.control.phases import Phase
from mkflight.conversions import NS_PER_S
from mkflight.errors import ReplayError
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
from mkflight.replay.daemon import ReplayApp, replay_options
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

SEED_START_NS = 1_000 * NS_PER_S  # the lock-step clock of such a replay starts here (any)
#: The tables start at take-off; a daemon still on the ground this long after the start
#: never takes off (e.g. TABLE III's first pose is NaN or far outside the room: no valid
#: fix), and the replay, which would otherwise run on forever, ends (one normally takes
#: off about 2.5 s in).
TAKEOFF_TIMEOUT_NS = 30 * NS_PER_S


def is_seed_folder(folder: Path) -> bool:
    """The two tables and no raw recording at all (one of two missing: damaged)."""
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
    """Pair the replay's rows with the original rows they came from; compare the columns."""
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


class _TakeoffWatch:
    """Starts the tables' clock at the replayed daemon's take-off and stops the replay.

    It stops a daemon still on the ground :data:`TAKEOFF_TIMEOUT_NS` after the start, and
    one whose TABLE IV ran out (:class:`~mkflight.replay.seed.SeedFc`'s ``on_end``).
    """

    def __init__(self, clock: VirtualClock, tables: SeedClock) -> None:
        self.clock = clock
        self.tables = tables
        self.app: ReplayApp | None = None
        self.first_step: int | None = None  # the daemon's first step at take-off (1-based)

    def watch(self, app: ReplayApp) -> None:
        """Watch ``app``'s steps from now on."""
        self.app = app

    def on_end(self, t_ns: int) -> None:
        """TABLE IV ran out: land and release, as ``--duration`` would."""
        if self.app is not None:
            self.app.request_stop(StopRequest.DURATION, "the original system's TABLE IV ended")

    def on_step(self, out: ImuStepOutput) -> None:
        """After each step: start the tables' clock at take-off, or give up waiting for it."""
        app = self.app
        if app is None:
            return
        if self.tables.start_ns is None and out.phase is Phase.TAKEOFF:
            self.tables.start_ns = self.clock.now_ns()
            self.first_step = app.flight.core.counters.imu_steps + 1
        elif (
            self.tables.start_ns is None
            and app.flight.stop.request is None
            and self.clock.now_ns() > SEED_START_NS + TAKEOFF_TIMEOUT_NS
        ):
            app.request_stop(
                StopRequest.DURATION, f"no take-off in {TAKEOFF_TIMEOUT_NS // NS_PER_S} s"
            )


def _read_tables(folder: Path) -> tuple[npt.NDArray[np.void], npt.NDArray[np.void], list[str]]:
    """TABLE IV and TABLE III rows of ``folder`` and the warnings reading them.

    Raises:
        ReplayError: a table cannot be read (file and line named) or is empty.
    """
    imu_data = read_table4(folder / "imu_50ms.log")
    laser_data = read_table3(folder / "laser_100ms.log")
    warnings = [
        f"{d.path}: last line cut short: dropped" for d in (imu_data, laser_data) if d.truncated
    ]
    for d in (imu_data, laser_data):
        if len(d.rows) == 0:
            msg = f"{d.path}: no rows to replay"
            raise ReplayError(msg)
    return imu_data.rows, laser_data.rows, warnings


def _seed_app(
    cfg: Config,
    feeder: Feeder,
    clock: VirtualClock,
    out: Path,
    matcher: SeedMatcher,
    on_step: Callable[[ImuStepOutput], None],
) -> ReplayApp:
    """The daemon on the feeder's model ports, with TABLE III's poses as its matcher."""
    opts = replay_options(feeder, out)
    return ReplayApp(
        cfg,
        opts,
        clock=clock,
        feeder=feeder,
        scans={},
        use_recorded_poses=False,
        matcher=matcher,
        on_step=on_step,
    )


def replay_seed(
    source: str | Path,
    out_dir: str | Path | None = None,
    *,
    overrides: list[str] | None = None,
    speed: float | None = None,
) -> ReplayReport:
    """Replay a folder of the original system's two tables (:mod:`mkflight.replay.seed`).

    The configuration is the built-in one with ``--set`` on top (the tables do not say
    which was flown).

    Raises:
        ReplayError: a table cannot be read (file and line named) or is empty.
        ConfigError: a bad ``--set``.
    """
    folder = Path(source)
    overrides = list(overrides or [])
    imu_seed, laser_seed, warnings = _read_tables(folder)
    cfg = load_config(None, overrides)
    cfg = msgspec.structs.replace(
        cfg, scanmatch=msgspec.structs.replace(cfg.scanmatch, worker="inline")
    )
    out = out_dir_for(folder, out_dir)
    clock = VirtualClock(SEED_START_NS)
    seed_clock = SeedClock(len(imu_seed), len(laser_seed))
    link_dir = Path(tempfile.mkdtemp(prefix="mkflight-replay-"))
    watch = _TakeoffWatch(clock, seed_clock)
    fc = SeedFc(cfg, imu_seed, seed_clock, t_ns=SEED_START_NS, on_end=watch.on_end)
    urg = seed_urg(cfg, laser_seed, seed_clock, SEED_START_NS)
    feeder = Feeder(
        [], clock, link_dir, speed=speed, models={"mk": fc, "laser": urg}, memory=speed is None
    )
    matcher = SeedMatcher(cfg, laser_seed, seed_clock)
    app = _seed_app(cfg, feeder, clock, out, matcher, watch.on_step)
    watch.watch(app)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    report = run_lockstep(app, feeder, clock, link_dir)
    wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    if seed_clock.start_ns is None:
        warnings.append(
            f"the replayed daemon did not take off within {TAKEOFF_TIMEOUT_NS / NS_PER_S:.0f} s: "
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
        recorded_s=(clock.now_ns() - SEED_START_NS) / NS_PER_S,
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
            watch.first_step,
            matcher.rows_used,
        ),
    )
