"""mkflight benchmarks (SPEC §9): medians and ratios against a baseline measured in the same run.

Run: ``pip install -e '.[bench]' && python tools/bench.py`` (``--json`` for every raw figure,
``--only GROUP`` for one group). No remembered figures: every comparison is a ratio between
two things measured here, now, alternated so that the machine's drift hits both alike.

The groups ``scanmatch``, ``flight`` and ``startup`` compare two code trees
(``tools/bench_trees.py``): the baseline, a git revision (``--baseline-rev``, default the code
before the matcher and the daemon's hot path were reworked) extracted into a temporary
folder, against the tree this file is in; each runs in subprocesses on its own code. Both
revisions are printed ("dirty": the current tree has uncommitted changes).

* ``scanmatch``: time per scan and relation error on every set of ``../shared/data/laser/``
  (skipped when absent) and on URG-size scans in unseen random rooms, baseline and current
  alternated ``--repeat`` times: both medians and p95s, their ratio, both accuracies and
  whether current's is no worse; CSM's figures from the data README as a labelled
  reference column (``tools/bench_scanmatch.py``).
* ``flight``: ``--flight-pairs`` pairs of real-time simulated flights of
  ``--flight-duration`` s, the two trees alternated: CPU in HOLD (daemon, matcher), CPU per
  step and per scan, latency median and p99, missed steps, hover precision against the
  truth, start-up (``tools/bench_flight.py``). ``--flight-compare workers`` flies the
  current tree with the matcher in its worker process against inline instead; with
  ``--live``, the live view's cost: flights with ``fly --live`` off and on, a client
  subscribed to every topic.
* ``startup``: import time of the flight path and of the matcher per tree (fresh
  interpreters), and spawn -> READY of ``fly`` (from the ``flight`` group's flights, or
  from ``--flight-pairs`` pairs of 1 s flights when run alone).
* ``codec``: MK frames encoded and decoded per second (ExternControl encode with its range
  checks; DebugOut streams through the incremental parser and the SI conversion).
* ``latency``: DebugOut arrival -> ExternControl on the wire, over a real pty pair. A
  child process poses as the FlightCtrl on the pty's master end: it writes a DebugOut frame and
  timestamps the moment the answering ExternControl frame can be read back. The host side
  is mkflight's link (serialx, eager writes) and, as the baseline, the same loop on
  pyserial-asyncio (whose transport queues every write for the next event-loop turn).
  Both ends use ``time.perf_counter_ns`` (CLOCK_MONOTONIC), one clock for both processes.
* ``step``: CPU per flight step (``FlightCore.imu_step``/``laser_step``) in a lock-step
  hover, current tree only.
* ``replay``: a recorded flight replayed as fast as it goes, with the recorded scan
  poses and, as the baseline, through ptys and with the scan matcher run again
  (``tools/bench_replay.py``), current tree only.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import platform
import pty
import statistics
import subprocess
import sys
import time
import tty
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

from bench_flight import Variant
from bench_scanmatch import DATASETS, RANDOM_ROOMS
from bench_trees import (
    DEFAULT_BASELINE_REV,
    Tree,
    UnknownRevisionError,
    baseline_and_current,
    load_average,
)

from mkflight.conversions import MS_PER_S, NS_PER_MS, NS_PER_US, US_PER_S
from mkflight.mk.codec import FrameParser
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import DebugOut, ExternControl
from mkflight.mk.units import DEFAULT_CALIBRATION, imu_from_debug

DEBUG = DebugOut.from_values({0: -12, 1: 31, 2: -13, 3: 33, 6: -2, 7: 480, 9: 118, 11: 271})
# Samples not counted at the start of each run: first calls, and the link's 3 ms gap after
# its initial 'd' (a real FC answers 'd' with a 16 ms DebugOut, so that gap never binds).
WARMUP = 3
COMMAND = ExternControl(nick=-20, roll=15, yaw=3, gas=100, frame=7, config=1)


def percentile(values: list[float], q: float) -> float:
    """The q-th percentile (0..100) by nearest rank."""
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))
    return ordered[index]


# ----- codec throughput ------------------------------------------------------------------


def bench_codec(seconds: float = 1.0) -> dict[str, float]:
    """Frames per second for the pure codec paths (median of 5 timed batches)."""

    def rate(fn: Callable[[], int]) -> float:
        rates = []
        for _ in range(5):
            t0 = time.perf_counter()
            n = fn()
            rates.append(n / (time.perf_counter() - t0))
        return statistics.median(rates)

    batch = max(1000, int(20000 * seconds))

    def encode_commands() -> int:
        for _ in range(batch):
            COMMAND.encode()
        return batch

    stream = DEBUG.encode() * 200

    def decode_debug() -> int:
        parser = FrameParser()
        n = 0
        for _ in range(max(1, batch // 200)):
            for frame in parser.feed(stream):
                imu_from_debug(DebugOut.decode(frame), 0, DEFAULT_CALIBRATION)
                n += 1
        return n

    return {
        "extern_control_encode_per_s": rate(encode_commands),
        "debugout_decode_to_si_per_s": rate(decode_debug),
    }


# ----- the flight step -----------------------------------------------------------------


def bench_step(duration_s: float = 60.0) -> dict[str, float]:
    """CPU time of FlightCore.imu_step / laser_step along a simulated hover (median, p99).

    The onboard computer is a ~1 GHz ARM: these are the figures to scale, not the
    simulator's wall time (which includes the vehicle model).
    """
    import tempfile

    from mkflight.config import Config
    from mkflight.flight import step as flight_step
    from mkflight.sim.hover import run_hover

    imu_us: list[float] = []
    laser_us: list[float] = []
    core_cls = flight_step.FlightCore
    imu_step, laser_step = core_cls.imu_step, core_cls.laser_step

    def timed_imu(self: Any, *a: Any, **k: Any) -> Any:
        t0 = time.process_time_ns()
        out = imu_step(self, *a, **k)
        imu_us.append((time.process_time_ns() - t0) / NS_PER_US)
        return out

    def timed_laser(self: Any, *a: Any, **k: Any) -> Any:
        t0 = time.process_time_ns()
        out = laser_step(self, *a, **k)
        laser_us.append((time.process_time_ns() - t0) / NS_PER_US)
        return out

    core_cls.imu_step = timed_imu  # type: ignore[method-assign]
    core_cls.laser_step = timed_laser  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as folder:
            run_hover(Config(), duration_s=duration_s, seed=1, log_dir=Path(folder) / "f")
    finally:
        core_cls.imu_step = imu_step  # type: ignore[method-assign]
        core_cls.laser_step = laser_step  # type: ignore[method-assign]
    return {
        "imu_step_median_us": statistics.median(imu_us),
        "imu_step_p99_us": percentile(imu_us, 99),
        "laser_step_median_us": statistics.median(laser_us),
        "laser_step_p99_us": percentile(laser_us, 99),
        "steps": float(len(imu_us)),
    }


# ----- latency over a pty ------------------------------------------------------------------


def fc_process(master: int, samples: int, period_s: float, ready: Any, out: Any) -> None:
    """Poses as the FC on a pty master: DebugOut out, time until the ExternControl is back.

    It runs in its own process so that the host's interpreter lock cannot delay the
    moment it sees the reply (a thread would measure the GIL's 5 ms switch interval).
    """
    frame = DEBUG.encode()
    parser = FrameParser()
    latencies_ms: list[float] = []
    ready.wait()
    for _ in range(samples):
        t0 = time.perf_counter_ns()
        os.write(master, frame)
        got = False
        t1 = t0
        while not got:
            data = os.read(master, 4096)
            t1 = time.perf_counter_ns()
            got = any(f.cmd == "b" for f in parser.feed(data))
        latencies_ms.append((t1 - t0) / NS_PER_MS)
        time.sleep(period_s)
    out.send(latencies_ms)


Host = Callable[[str, Any, int], Coroutine[Any, Any, float]]


async def busy_task(chunk_ms: float, every_ms: float) -> None:
    """Other work on the same event loop (a scan match, log formatting): CPU in chunks."""
    while True:
        t_end = time.perf_counter() + chunk_ms / MS_PER_S
        while time.perf_counter() < t_end:
            pass
        await asyncio.sleep(every_ms / MS_PER_S)


def with_load(host: Host, chunk_ms: float = 2.0, every_ms: float = 5.0) -> Host:
    """Run ``host`` with :func:`busy_task` beside it on the loop."""

    async def loaded(path: str, ready: Any, samples: int) -> float:
        busy = asyncio.create_task(busy_task(chunk_ms, every_ms))
        try:
            return await host(path, ready, samples)
        finally:
            busy.cancel()

    return loaded


async def host_mkflight(path: str, ready: Any, samples: int) -> float:
    """mkflight's path: serialx stream, MkLink, eager ExternControl write per sample.

    Returns the process CPU time per sample after the warm-up, in microseconds.
    """
    from mkflight.config import Config
    from mkflight.io.serial import open_serial

    stream = await open_serial(path, 57600)
    link = MkLink(stream, LinkSettings.from_config(Config()), DEFAULT_CALIBRATION)
    link.start()
    ready.set()
    cpu0 = 0.0
    for i in range(samples):
        if i == WARMUP:
            cpu0 = time.process_time()
        await link.next_sample(timeout_s=5.0)
        link.send_extern_control(COMMAND)
    cpu_us = (time.process_time() - cpu0) / max(1, samples - WARMUP) * US_PER_S
    await link.close(release=False)
    return cpu_us


async def host_pyserial_asyncio(path: str, ready: Any, samples: int) -> float:
    """The baseline: pyserial-asyncio streams, same parser, writer.write per sample."""
    import serial_asyncio

    reader, writer = await serial_asyncio.open_serial_connection(url=path, baudrate=57600)
    parser = FrameParser()
    data = COMMAND.encode()
    ready.set()
    answered = 0
    cpu0 = 0.0
    while answered < samples:
        chunk = await reader.read(4096)
        for frame in parser.feed(chunk):
            if frame.cmd == "D":
                imu_from_debug(DebugOut.decode(frame), 0, DEFAULT_CALIBRATION)
                writer.write(data)
                answered += 1
                if answered == WARMUP:
                    cpu0 = time.process_time()
    cpu_us = (time.process_time() - cpu0) / max(1, samples - WARMUP) * US_PER_S
    writer.close()
    return cpu_us


def bench_latency(host: Host, samples: int, period_s: float) -> tuple[list[float], float]:
    """Run one host against the FC process: latencies in ms, host CPU us per sample.

    The CPU figure is the host process's user+system time per sample in steady state
    (event loop, parsing, conversion, encoding, the write), warm-up excluded.
    """
    ctx = multiprocessing.get_context("fork")
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    ready = ctx.Event()
    receive, send = ctx.Pipe(duplex=False)
    fc = ctx.Process(target=fc_process, args=(master, samples + WARMUP, period_s, ready, send))
    fc.start()
    try:
        cpu_us_per_sample = asyncio.run(host(path, ready, samples + WARMUP))
        latencies: list[float] = receive.recv()[WARMUP:]
        fc.join(timeout=10)
    finally:
        os.close(master)
        os.close(slave)
    return latencies, cpu_us_per_sample


def summarize(values: list[float]) -> dict[str, float]:
    """Median, p99 and max."""
    return {
        "median": statistics.median(values),
        "p99": percentile(values, 99),
        "max": max(values),
        "n": float(len(values)),
    }


GROUPS = ("codec", "latency", "scanmatch", "step", "flight", "startup", "replay")
TREE_GROUPS = ("scanmatch", "flight", "startup")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--only", nargs="+", choices=GROUPS, metavar="GROUP", help=f"run these: {', '.join(GROUPS)}"
    )
    parser.add_argument(
        "--baseline-rev",
        default=DEFAULT_BASELINE_REV,
        metavar="REV",
        help=f"the baseline code tree, a git revision (default {DEFAULT_BASELINE_REV})",
    )
    parser.add_argument(
        "--repeat", type=int, default=3, help="scanmatch: alternated runs per tree and dataset"
    )
    parser.add_argument(
        "--datasets",
        nargs="+",
        choices=[*DATASETS, RANDOM_ROOMS],
        metavar="NAME",
        help=f"scanmatch: these only ({', '.join([*DATASETS, RANDOM_ROOMS])})",
    )
    parser.add_argument(
        "--flight-duration",
        type=float,
        default=60.0,
        metavar="S",
        help="flight: each simulated flight (real time)",
    )
    parser.add_argument("--flight-pairs", type=int, default=3, help="flight: pairs of flights")
    parser.add_argument(
        "--worker",
        choices=("default", "process", "inline"),
        default="default",
        help="flight: scanmatch.worker for both trees (default: each tree's own default)",
    )
    parser.add_argument(
        "--flight-compare",
        choices=("trees", "workers"),
        default="trees",
        help="flight: baseline tree against this one, or this tree's matcher in its "
        "worker process against inline",
    )
    parser.add_argument(
        "--live",
        action="store_true",
        help="the 'flight' group measures fly --live instead: off and on alternated in pairs "
        "of --flight-duration with a client subscribed to every topic",
    )
    parser.add_argument("--live-pairs", type=int, default=3, help="--live: pairs of flights")
    parser.add_argument(
        "--import-repeat", type=int, default=5, help="startup: fresh interpreters per import"
    )
    parser.add_argument(
        "--replay-source", type=Path, metavar="DIR", help="the 'replay' group's flight folder"
    )
    parser.add_argument(
        "--replay-duration",
        type=float,
        default=600.0,
        metavar="S",
        help="without --replay-source: fly (and keep) a simulated flight this long to replay",
    )
    parser.add_argument("--replay-runs", type=int, default=3, help="replays per variant")
    parser.add_argument("--samples", type=int, default=400, help="latency samples per variant")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds per variant")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    return parser.parse_args(argv)


def wanted(args: argparse.Namespace, group: str) -> bool:
    return args.only is None or group in args.only


def run_latency(samples: int, rounds: int) -> dict[str, Any]:
    """mkflight's link against pyserial-asyncio, idle and loaded, alternated in rounds."""
    variants: dict[str, Host] = {
        "mkflight_serialx": host_mkflight,
        "pyserial_asyncio": host_pyserial_asyncio,
        "mkflight_serialx+load": with_load(host_mkflight),
        "pyserial_asyncio+load": with_load(host_pyserial_asyncio),
    }
    runs: dict[str, list[float]] = {name: [] for name in variants}
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    per_round = max(1, samples // rounds)
    for _ in range(rounds):  # alternate A B A B: drift hits both alike
        for name, host in variants.items():
            latencies, cpu_us = bench_latency(host, per_round, period_s=0.01)
            runs[name] += latencies
            cpu[name].append(cpu_us)
    stats = {name: summarize(v) for name, v in runs.items()}
    for name in variants:
        stats[name]["cpu_us_per_sample"] = statistics.median(cpu[name])
    return {
        "latency_ms": stats,
        "latency_ratio_ours_over_baseline": {
            suffix or "idle": {
                q: stats["mkflight_serialx" + suffix][q] / stats["pyserial_asyncio" + suffix][q]
                for q in ("median", "p99")
            }
            for suffix in ("", "+load")
        },
    }


def flight_variants(trees: tuple[Tree, Tree], compare: str, worker: str) -> tuple[Variant, Variant]:
    """The two sides of a flight comparison (``--flight-compare``, ``--worker``)."""
    import bench_flight

    base, cur = trees
    if compare == "workers":
        return (
            bench_flight.Variant("process", cur, ("scanmatch.worker=process",)),
            bench_flight.Variant("inline", cur, ("scanmatch.worker=inline",)),
        )
    settings = () if worker == "default" else (f"scanmatch.worker={worker}",)
    return (
        bench_flight.Variant(base.label, base, settings),
        bench_flight.Variant(cur.label, cur, settings),
    )


def run_tree_groups(args: argparse.Namespace, result: dict[str, Any]) -> None:
    """The groups that compare the baseline revision with this tree (module docstring)."""
    import bench_flight
    import bench_scanmatch

    with baseline_and_current(args.baseline_rev) as trees:
        result["trees"] = {t.label: t.revision for t in trees}
        if wanted(args, "scanmatch"):
            result["scanmatch"] = bench_scanmatch.compare(trees, args.datasets, args.repeat)
        variants = flight_variants(trees, args.flight_compare, args.worker)
        flown = None
        if wanted(args, "flight") and args.live:
            result["flight_live"] = bench_flight.run_live(args.flight_duration, args.live_pairs)
        elif wanted(args, "flight"):
            flown = bench_flight.run_pairs(variants, args.flight_pairs, args.flight_duration)
            result["flight"] = flown
        if wanted(args, "startup"):
            if args.flight_compare != "trees" or args.live:  # start-up compares the trees
                variants, flown = flight_variants(trees, "trees", args.worker), None
            result["startup"] = bench_flight.startup(
                variants, args.flight_pairs, args.import_repeat, flown
            )


def run_groups(args: argparse.Namespace) -> dict[str, Any]:
    """Every group asked for, as one dict of raw figures."""
    result: dict[str, Any] = {
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus",
        "python": platform.python_version(),
        "load_before": load_average(),
    }
    if wanted(args, "codec"):
        result["codec"] = bench_codec()
    if wanted(args, "latency"):
        result.update(run_latency(args.samples, args.rounds))
    if wanted(args, "step"):
        result["flight_step_us"] = bench_step()
    if any(wanted(args, g) for g in TREE_GROUPS):
        run_tree_groups(args, result)
    if wanted(args, "replay"):
        import bench_replay  # tools/bench_replay.py, beside this file

        result["replay"] = bench_replay.run(
            args.replay_source, args.replay_duration, args.replay_runs
        )
    result["load_after"] = load_average()
    return result


def print_latency(result: dict[str, Any]) -> None:
    print("DebugOut arrival -> ExternControl on the wire, ms (pty pair):")
    head = f"  {'variant':24s} {'median':>8s} {'p99':>8s} {'max':>8s} {'n':>6s}"
    print(head + f" {'host CPU us/sample':>19s}")
    for name, s in result["latency_ms"].items():
        print(
            f"  {name:24s} {s['median']:8.3f} {s['p99']:8.3f} {s['max']:8.3f} {s['n']:6.0f}"
            f" {s['cpu_us_per_sample']:19.0f}"
        )
    print("  (+load: another task on the loop burns 2 ms of CPU every 5 ms)")
    for case, r in result["latency_ratio_ours_over_baseline"].items():
        print(
            f"  ratio mkflight/pyserial-asyncio ({case}): "
            f"median {r['median']:.2f}, p99 {r['p99']:.2f}"
        )


def print_replay(r: dict[str, Any]) -> None:
    print(f"replay of {r['source']} ({r['fast']['recorded_s']:.0f} s recorded):")
    print(f"  {'variant':26s} {'wall s':>8s} {'x real time':>12s} {'CPU ms/step':>12s} ok")
    for name, v in r.items():
        if isinstance(v, dict):
            print(
                f"  {name:26s} {v['wall_s_median']:8.2f} {v['speedup_median']:12.0f}"
                f" {v['cpu_ms_per_step']:12.3f} {v['deterministic']}"
            )
    print(f"  ratio fast/baseline (wall): {r['ratio_fast_over_baseline']:.2f}")


def print_text(result: dict[str, Any]) -> None:
    """The human tables."""
    import bench_flight
    import bench_scanmatch

    print(f"machine: {result['machine']}, Python {result['python']}")
    print(
        f"load average (1/5/15 min): before {result['load_before']}, after {result['load_after']}"
    )
    if "trees" in result:
        for label, revision in result["trees"].items():
            print(f"{label:8s} tree: {revision}")
    labels = ("baseline", "current")
    for key, value in result.get("codec", {}).items():
        print(f"  {key:34s} {value:12,.0f}")
    if "latency_ms" in result:
        print_latency(result)
    if "flight_step_us" in result:
        f = result["flight_step_us"]
        print(
            "Flight step CPU (a simulated hover, current tree): imu_step median "
            f"{f['imu_step_median_us']:.0f} us, p99 {f['imu_step_p99_us']:.0f} us; "
            f"laser_step median {f['laser_step_median_us']:.0f} us, "
            f"p99 {f['laser_step_p99_us']:.0f} us"
        )
    if "scanmatch" in result:
        print(bench_scanmatch.format_compare_table(result["scanmatch"], labels))
    if "flight" in result:
        print(bench_flight.format_table(result["flight"]))
    if "flight_live" in result:
        print(bench_flight.format_live_table(result["flight_live"]))
    if "startup" in result:
        print(bench_flight.format_startup(result["startup"], labels))
    if "replay" in result:
        print_replay(result["replay"])


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        result = run_groups(args)
    except UnknownRevisionError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except (RuntimeError, subprocess.CalledProcessError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_text(result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
