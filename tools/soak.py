"""Soak: one long real-time simulated hover, gusts and battery drain on.

Run: ``python tools/soak.py`` (30 minutes; ``--minutes M``, ``--json FILE`` for every
figure, ``--log-dir DIR`` to keep the flight folder). Exit 0 only if no step was missed and
the flight ended as planned; 1 otherwise; 2 on a usage or configuration error.

This file runs the flight: the simulator child, the per-step :class:`Recorder`, the battery
plan, :func:`soak` and the command line. The figures, the verdict and the printed table
are pure functions of what it recorded, in ``tools/soak_report.py`` (a sibling module,
imported as ``tools/bench.py`` imports its own).

Set-up. The daemon (:class:`~mkflight.flight.app.FlightApp`, ``--duration`` = the soak)
flies in this process, exactly as ``fly --hover`` does; the simulator
(:class:`~mkflight.sim.live.LiveSim`, gusts and battery as configured) runs in a spawned
child process on real ptys, as ``fly --sim`` runs it, so that this process's CPU time,
memory and timing are the daemon's (plus this tool's small per-step bookkeeping) and not
the vehicle model's. The child also samples the simulated state every
:data:`SIM_SAMPLE_S` (wind, battery, position) for the gust and drain figures.

Battery. The default pack (2.2 Ah at ~7.3 A in hover) reaches ``safety.land_voltage_v``
after about 16 minutes, and a low-battery landing is not what a soak is for. If the
flight would draw more than :data:`MAX_USED_FRACTION` of the configured pack (at
:data:`SOAK_CURRENT_A`, plus :data:`MARGIN_MIN` for pre-flight, take-off and landing), the
pack is enlarged with ``--set sim.vehicle.battery_capacity_ah=C`` so that it ends at about
40 % charge (~3.8 V a cell open-circuit, ~11.0 V under load, above
``safety.warn_voltage_v``): the drain stays visible, the voltage failsafes stay quiet. The
output says which pack flew and why; a ``--set`` of your own wins.

What is measured (per window of ``--window-minutes``, default 5, so drift over time shows):

* **missed steps**: every DebugOut must give one step and one ExternControl. Counted:
  gaps in the step sequence longer than :data:`~soak_report.GAP_FACTOR` median periods
  (the FC's ~53 ms), DebugOuts received but not stepped (the link's ``samples_dropped``:
  newest wins), commands never written (superseded in the outbox), overruns (a step
  busier than 10 ms), and the daemon's own ``flight.json`` counters beside them (its
  timing keeps only the newest 20,000 steps, ~17 minutes). Each gap gets a cause: the
  soak's own snapshot, a garbage collection of >= :data:`~soak_report.GC_NOTE_MS` (a
  ``gc.callbacks`` hook), a DebugOut the daemon dropped, or a DebugOut read late with
  nothing dropped (the simulator sent it late, or the loop was busy elsewhere: the soak
  cannot tell which);
* **latency**: DebugOut arrival -> ExternControl written, and the deviation of the step
  period from its median (re-subscription intervals excluded, as in ``flight.json``);
  p50/p99/max;
* **CPU per step**: ``time.process_time`` of this process over the window / its steps;
* **memory**: :mod:`tracemalloc` starts just before the daemon is built; every
  ``--sample-minutes`` (default 1) the traced size, tracemalloc's own tables and the RSS
  (``/proc/PID/statm``) of the daemon, the matcher and the simulator are read. Reported:
  the first vs the last sample, the growth per 10 minutes (least squares over the samples
  after the baseline, and over the second half: the daemon's bounded deques fill for
  ~17 minutes), and the top :data:`~soak_report.TOP_SITES` growing allocation sites
  (file:line and the source line) between a full snapshot at the second sample
  (2 minutes) and one at the last step (landed, control handed back, before the shutdown
  frees anything).
  Snapshots are taken right after a step's command went out, the longest slack before
  the next DebugOut; their duration is reported, and a gap right after one is the soak's,
  not the daemon's. A site can grow without live objects (CPython keeps freed small
  tuples in free lists, up to 2000 a size, still traced where they were first
  allocated): confirm with ``gc`` before calling a site a leak. tracemalloc slows every
  allocation: on the 2-vCPU development VM it raised the command latency median from
  ~0.7 to ~2.2 ms and the CPU per step from ~2.2 to ~5.5 ms. ``--no-tracemalloc``
  flies the same soak untraced (RSS only) for the timing figures; ``--trace-frames N``
  finds the mkflight caller of a library line (``via``), at a further cost per step;
* **battery** voltage (as the FC reports it, and the simulator's truth) at the start and
  end of the hover; **gusts**: the simulated wind's std per axis.

A flight shorter than four windows gets windows of a quarter of it, and samples of an
eighth (so ``--minutes 0.4`` still has every figure). Nothing in the output is a limit:
the soak reports; only missed steps and an abnormal end fail it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import json
import math
import multiprocessing
import os
import signal
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from soak_report import (  # tools/soak_report.py, beside this file
    GC_NOTE_MS,
    PHASES,
    MemSample,
    figures,
    format_table,
    verdict,
)

from mkflight.config import Config, load_config
from mkflight.control.phases import Phase
from mkflight.conversions import MIN_PER_H, MS_PER_S, NS_PER_MS, NS_PER_S
from mkflight.errors import ConfigError
from mkflight.logs.flight_json import to_plain
from mkflight.sim.pty_server import LATE_NOTE_NS

if TYPE_CHECKING:
    from mkflight.flight.app import FlightApp
    from mkflight.flight.step import ImuStepOutput
    from mkflight.msgs import ImuSample

SOAK_CURRENT_A = 8.0
"""Pack current assumed for sizing: 6.8 A hover at 11.8 V, more as the voltage sags, + avionics."""
MAX_USED_FRACTION = 0.6
"""The soak may draw at most this share of the pack (it ends near 40 % charge)."""
MARGIN_MIN = 2.0
"""Minutes of pack added for the pre-flight, take-off and landing."""
TRACE_FRAMES = 1
"""Frames kept per traced allocation (``--trace-frames``): each one more costs every step."""
SIM_SAMPLE_S = 0.25
"""How often the simulator child samples its state (wind, battery, position)."""
SIM_START_TIMEOUT_S = 30.0
STEPS_PER_S_MAX = 25.0
"""Per-step buffers are sized for this rate (the FC sends ~19 a second)."""
PAGE_B = os.sysconf("SC_PAGE_SIZE")


# ----- the simulator child ---------------------------------------------------------------


def _sim_child(cfg: Config, seed: int, truth: str, conn: Connection) -> None:
    """The simulator process: ptys, then state samples until the soak says stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the daemon lands; the sim stays
    from mkflight.eventlog import configure_events

    configure_events("warning")
    asyncio.run(_serve_sim(cfg, seed, truth, conn))


async def _serve_sim(cfg: Config, seed: int, truth: str, conn: Connection) -> None:
    from mkflight.sim.live import LiveSim

    sim = LiveSim(cfg, seed=seed, truth_path=truth, truth_origin_ns=0)
    mk, laser = await sim.start()
    conn.send((mk, laser, os.getpid()))
    rows: list[tuple[float, ...]] = []
    crash = ""
    try:
        while not conn.poll():  # "stop", or EOF: the soak is gone
            s = sim.world.state
            x, y, _ = s.pos_w_m
            rows.append(
                (time.monotonic_ns(), *s.wind_w_mps, s.battery_v, s.used_ah, x, y, s.height_m)
            )
            if (err := sim.crashed()) is not None:
                crash = repr(err)
                break
            await asyncio.sleep(SIM_SAMPLE_S)
    finally:
        with contextlib.suppress(Exception):
            await sim.stop()
    late = {
        name: {
            "count": emu.late_count,
            "wakes": emu.late_wakes,
            "rx_lost_frames": getattr(emu.model, "rx_lost_frames", None),
        }
        for name, emu in (("fc", sim.fc), ("urg", sim.urg))
    }
    with contextlib.suppress(EOFError, OSError):
        conn.send((rows, crash, late))


# ----- per-step recording in the daemon's process ----------------------------------------


def _rss_b(pid: int | str = "self") -> int | None:
    """Resident set size of a process (``/proc/PID/statm``), None if it is gone."""
    try:
        return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE_B
    except (OSError, IndexError, ValueError):
        return None


def _children() -> list[dict[str, Any]]:
    """This process's children: pid, command line, RSS."""
    out: list[dict[str, Any]] = []
    me = os.getpid()
    for task in Path(f"/proc/{me}/task").iterdir():
        with contextlib.suppress(OSError):
            for pid in (task / "children").read_text().split():
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
                out.append({"pid": int(pid), "cmd": cmd.decode()[:120], "rss_b": _rss_b(pid)})
    return out


COUNTERS = ("debugouts", "dropped", "commands", "superseded")


@dataclass(slots=True)
class Recorder:
    """The soak's view of each step, in buffers sized before the flight (no growth)."""

    duration_s: float
    sample_s: float
    sim_pid: int
    app: FlightApp | None = None
    bar: Any = None
    n: int = 0
    overflow: int = 0
    steps: dict[str, np.ndarray] = field(default_factory=dict)
    stop_step: int | None = None
    samples: list[MemSample] = field(default_factory=list)
    snapshots: list[tuple[float, float, tracemalloc.Snapshot]] = field(default_factory=list)
    snap_steps: list[int] = field(default_factory=list)
    gc_pauses: list[tuple[int, float, int]] = field(default_factory=list)
    matcher_pid: int | None = None
    children: list[dict[str, Any]] = field(default_factory=list)
    _sample_t_ns: int = 0
    _sample_v: float = math.nan
    _restarts: int = 0
    _delayed: int = 0
    _next_k: int = 1
    _bar_s: int = 0
    _gc_t0_ns: int = 0

    def __post_init__(self) -> None:
        cap = math.ceil((self.duration_s + 120.0) * STEPS_PER_S_MAX)
        self.steps = {"arrival_ns": np.zeros(cap, np.int64), "phase": np.zeros(cap, np.int8)}
        for name in ("latency_ns", "busy_ns", "cpu_s", "battery_v"):
            self.steps[name] = np.full(cap, np.nan)
        for name in COUNTERS:
            self.steps[name] = np.zeros(cap, np.int64)
        self.steps["restart"] = np.zeros(cap, np.bool_)

    def on_sample(self, sample: ImuSample) -> ImuSample:
        """The daemon's ``sample_filter`` seam, used only to read: arrival time, battery."""
        self._sample_t_ns, self._sample_v = sample.t_ns, sample.battery_v
        return sample

    def on_gc(self, phase: str, info: dict[str, int]) -> None:
        """A ``gc.callbacks`` hook: note collections that pause the loop >= GC_NOTE_MS."""
        now = time.monotonic_ns()
        if phase == "start":
            self._gc_t0_ns = now
        elif (ms := (now - self._gc_t0_ns) / NS_PER_MS) >= GC_NOTE_MS and len(
            self.gc_pauses
        ) < 1000:
            self.gc_pauses.append((now, ms, info.get("generation", -1)))

    def on_step(self, out: ImuStepOutput) -> None:
        """After each step (its command is written): record it; sample memory when due."""
        app = self.app
        assert app is not None
        assert app.ports.link is not None
        i, s, stats, link = self.n, self.steps, app.stats, app.ports.link.stats
        if i >= len(s["arrival_ns"]):
            self.overflow += 1
            return
        s["arrival_ns"][i] = self._sample_t_ns
        delayed = stats.delayed_commands != self._delayed
        self._delayed = stats.delayed_commands
        s["latency_ns"][i] = math.nan if delayed else stats.latency_ns.last()
        s["busy_ns"][i] = stats.busy_ns.last()
        s["restart"][i] = stats.restarted_periods != self._restarts
        self._restarts = stats.restarted_periods
        s["cpu_s"][i] = time.process_time()
        s["battery_v"][i] = self._sample_v
        s["phase"][i] = PHASES.index(out.phase.value)
        s["debugouts"][i] = link.samples
        s["dropped"][i] = link.samples_dropped
        s["commands"][i] = link.commands_sent
        s["superseded"][i] = link.superseded_commands
        self.n = i + 1
        elapsed_s = (self._sample_t_ns - app.start_ns) / NS_PER_S
        if i == 0:
            self.matcher_pid = app.worker.worker_pid
            self.children = _children()
            self._memory("start", elapsed_s)
        if self.stop_step is None and app.stop.request is not None:
            self.stop_step = i
        due_s = self._next_k * self.sample_s
        if elapsed_s >= due_s and due_s <= self.duration_s + 1e-6:
            self._next_k += 1
            self._memory("sample", elapsed_s, snapshot=self._next_k == 3)  # the baseline
        if out.phase is Phase.RELEASED:  # the last step: landed, control handed back
            self._memory("end", elapsed_s, snapshot=True)
        if self.bar is not None and (shown := min(int(elapsed_s), int(self.duration_s))) > (
            self._bar_s
        ):
            self.bar.update(shown - self._bar_s)
            self._bar_s = shown

    def _memory(self, kind: str, t_s: float, *, snapshot: bool = False) -> None:
        traced, peak = tracemalloc.get_traced_memory()
        matcher = _rss_b(self.matcher_pid) if self.matcher_pid else None
        self.samples.append(
            MemSample(
                kind,
                t_s,
                traced,
                peak,
                tracemalloc.get_tracemalloc_memory(),
                _rss_b(),
                matcher,
                _rss_b(self.sim_pid),
            )
        )
        if snapshot and tracemalloc.is_tracing():
            t0 = time.perf_counter()
            snap = tracemalloc.take_snapshot()
            self.snapshots.append((t_s, (time.perf_counter() - t0) * MS_PER_S, snap))
            self.snap_steps.append(self.n - 1)


# ----- the soak --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Plan:
    """What the soak flies: its length, windows, samples, seed and the config it changed."""

    minutes: float
    window_s: float
    sample_s: float
    seed: int
    overrides: list[str]
    battery_note: str
    capacity_ah: float
    trace: bool = True
    trace_frames: int = TRACE_FRAMES

    @property
    def duration_s(self) -> float:
        return self.minutes * 60.0


def battery_overrides(cfg: Config, minutes: float) -> tuple[list[str], str]:
    """The ``--set`` that sizes the pack for the soak (none if it suffices) and why."""
    v = cfg.sim.vehicle
    need_ah = SOAK_CURRENT_A * (minutes + MARGIN_MIN) / MIN_PER_H
    if need_ah <= MAX_USED_FRACTION * (v.battery_capacity_ah - v.battery_used_ah):
        return [], (
            f"configured pack {v.battery_capacity_ah:g} Ah kept: the soak draws about "
            f"{need_ah:.2f} Ah at {SOAK_CURRENT_A:g} A"
        )
    cap = math.ceil(10.0 * (need_ah / MAX_USED_FRACTION + v.battery_used_ah)) / 10.0
    return [f"sim.vehicle.battery_capacity_ah={cap:g}"], (
        f"pack enlarged {v.battery_capacity_ah:g} -> {cap:g} Ah "
        f"(sim.vehicle.battery_capacity_ah): {minutes:g} min + {MARGIN_MIN:g} min at "
        f"{SOAK_CURRENT_A:g} A draw {need_ah:.2f} Ah, more than {MAX_USED_FRACTION:.0%} of "
        f"the configured pack (a low-battery landing would end the soak early); the larger "
        f"pack ends near {1 - MAX_USED_FRACTION:.0%} charge, above safety.warn_voltage_v"
    )


def _recv(conn: Connection, timeout_s: float) -> Any:
    if not conn.poll(timeout_s):
        msg = f"no answer from the simulator process within {timeout_s:g} s"
        raise TimeoutError(msg)
    return conn.recv()


async def soak(cfg: Config, plan: Plan, folder: Path) -> dict[str, Any]:
    """Fly the soak (simulator in a child, daemon here, traced) and return every figure."""
    from mkflight.commands.progress import tty_bar
    from mkflight.flight.app import FlightApp, FlightOptions

    ctx = multiprocessing.get_context("spawn")
    ours, theirs = ctx.Pipe()
    child = ctx.Process(
        target=_sim_child,
        args=(cfg, plan.seed, str(folder / "truth.txt"), theirs),
        name="mkflight-soak-sim",
        daemon=True,
    )
    child.start()
    theirs.close()
    rows: list[tuple[float, ...]] = []
    sim_crash = ""
    sim_late: dict[str, dict[str, Any]] = {}
    try:
        mk, laser, sim_pid = await asyncio.to_thread(_recv, ours, SIM_START_TIMEOUT_S)
        rec = Recorder(plan.duration_s, plan.sample_s, sim_pid)
        if plan.trace:
            tracemalloc.start(
                TRACE_FRAMES
            )  # before the daemon exists: all of its allocations are traced
        app = FlightApp(
            cfg,
            FlightOptions(mk_port=mk, laser_port=laser, log_dir=folder, duration_s=plan.duration_s),
            on_step=rec.on_step,
            sample_filter=rec.on_sample,
        )
        rec.app = app
        gc.callbacks.append(rec.on_gc)
        try:
            with tty_bar(int(plan.duration_s), "s") as bar:
                rec.bar = bar
                report = await app.fly()
        finally:
            gc.callbacks.remove(rec.on_gc)
        if plan.trace and len(rec.snapshots) == 1:  # no last step: the end, after the shutdown
            rec.snapshots.append((math.inf, math.nan, tracemalloc.take_snapshot()))
        tracemalloc.stop()
    finally:
        with contextlib.suppress(OSError, ValueError):
            ours.send("stop")
        try:
            rows, sim_crash, sim_late = await asyncio.to_thread(_recv, ours, 10.0)
        except (TimeoutError, EOFError, OSError) as err:
            sim_crash = sim_crash or f"no samples from the simulator: {err!r}"
        await asyncio.to_thread(child.join, 10.0)
        if child.is_alive():
            child.kill()
    if rec.n < 2:
        msg = f"the flight made {rec.n} steps: {report.reason}"
        raise RuntimeError(msg)
    fc_late = sim_late.get("fc", {}).get("wakes", [])
    out = figures(
        rec,
        rows,
        start_ns=app.start_ns,
        window_s=plan.window_s,
        tool_file=__file__,
        sim_late_ns=[t for t, _ in fc_late],
    )
    out["simulator_late"] = {
        name: {
            "wakeups_late_over_ms": LATE_NOTE_NS / NS_PER_MS,
            "count": v["count"],
            "max_ms": round(max((ms for _, ms in v["wakes"]), default=0.0), 2),
            "at_s": [round((t - app.start_ns) / NS_PER_S, 3) for t, _ in v["wakes"][:20]],
            # frames the emulated device dropped because they arrived too soon after the
            # previous one (mk-serial.md §3): host bytes are stamped when the simulator
            # reads them, so a late read packs frames the daemon had spaced
            "rx_lost_frames": v.get("rx_lost_frames"),
        }
        for name, v in sim_late.items()
    }
    s = to_plain(report.summary)  # the summary's keys, as in flight.json
    first, last = rec.samples[0], rec.samples[-1]
    out["flight"] = {
        "exit_code": report.exit_code,
        "reason": report.reason,
        "final_phase": s.get("final_phase"),
        "released": s.get("released"),
        "failsafes": s.get("failsafes"),
        "log_dir": str(folder),
        "sim_crash": sim_crash or None,
    }
    keys = ("timing", "cpu_percent_of_one_core", "cpu_percent_in_hold", "gc", "matcher")
    out["daemon"] = {k: s.get(k) for k in (*keys, "precision_estimate")}
    out["daemon"]["mk_link"] = {
        k: v
        for k, v in (s.get("mk_link") or {}).items()
        if k in ("samples", "samples_dropped", "commands_sent", "stale_events", "crc_errors")
    }
    out["processes"] = {
        "at": [first.t_s, last.t_s],
        "daemon": {"pid": os.getpid(), "rss_start_b": first.rss_b, "rss_end_b": last.rss_b},
        "matcher": {
            "pid": rec.matcher_pid,
            "rss_start_b": first.matcher_rss_b,
            "rss_end_b": last.matcher_rss_b,
        },
        "simulator": {
            "pid": rec.sim_pid,
            "rss_start_b": first.sim_rss_b,
            "rss_end_b": last.sim_rss_b,
        },
        "children_at_start": rec.children,
    }
    out["plan"] = {
        "minutes": plan.minutes,
        "duration_s": plan.duration_s,
        "window_s": plan.window_s,
        "sample_s": plan.sample_s,
        "seed": plan.seed,
        "tracemalloc": plan.trace,
        "trace_frames": plan.trace_frames,
        "overrides": plan.overrides,
        "battery": plan.battery_note,
        "capacity_ah": plan.capacity_ah,
        "gusts": cfg.sim.vehicle.gusts,
        "wind_std_mps": cfg.sim.vehicle.wind_std_mps,
    }
    out["verdict"] = verdict(out)
    return out


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="hover this long (default 30)")
    ap.add_argument("--json", metavar="FILE", help="write every figure to FILE")
    ap.add_argument("--log-dir", help="keep the flight folder there (new or empty)")
    ap.add_argument("--seed", type=int, help="simulator seed (default sim.seed)")
    ap.add_argument("--config", help="config file (default: the built-in defaults)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--window-minutes", type=float, default=5.0)
    ap.add_argument("--sample-minutes", type=float, default=1.0)
    ap.add_argument(
        "--no-tracemalloc",
        dest="trace",
        action="store_false",
        help="no tracemalloc (RSS only): to see what tracing costs the latency",
    )
    ap.add_argument(
        "--trace-frames",
        type=int,
        default=TRACE_FRAMES,
        help="frames per traced allocation (default 1; more find a leak's caller, but slow "
        "every step)",
    )
    args = ap.parse_args(argv)
    if not 1 <= args.trace_frames <= 100:
        ap.error("--trace-frames must be 1..100")
    for name in ("minutes", "window_minutes", "sample_minutes"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            ap.error(f"--{name.replace('_', '-')} must be a positive number")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    from mkflight.eventlog import configure_events
    from mkflight.flight.flight_logs import folder_in_use
    from mkflight.logs.flight_json import json_safe

    configure_events("warning")
    duration_s = args.minutes * 60.0
    try:
        cfg = load_config(args.config, args.set)
        extra, note = battery_overrides(cfg, args.minutes)
        cfg = load_config(args.config, [*extra, *args.set])  # your --set wins
        if args.log_dir and folder_in_use(Path(args.log_dir)):
            msg = f"--log-dir {args.log_dir!r} is not empty"
            raise ConfigError(msg)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    plan = Plan(
        minutes=args.minutes,
        window_s=min(args.window_minutes * 60.0, duration_s / 4.0),
        sample_s=min(args.sample_minutes * 60.0, duration_s / 8.0),
        seed=cfg.sim.seed if args.seed is None else args.seed,
        overrides=[*extra, *args.set],
        battery_note=note,
        capacity_ah=cfg.sim.vehicle.battery_capacity_ah,
        trace=args.trace,
        trace_frames=args.trace_frames,
    )
    with tempfile.TemporaryDirectory(prefix="mkflight-soak-") as tmp:
        folder = Path(args.log_dir) if args.log_dir else Path(tmp) / "flight"
        folder.mkdir(parents=True, exist_ok=True)
        result = asyncio.run(soak(cfg, plan, folder))
    if not args.log_dir:
        result["flight"]["log_dir"] += " (deleted; --log-dir keeps it)"
    print(format_table(result))
    if args.json:
        text = json.dumps(json_safe(result), indent=2, allow_nan=False)
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    return 0 if result["verdict"]["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
