"""The soak's figures and report (``tools/soak.py``): pure, no flight, no I/O.

What each figure means is in ``tools/soak.py``'s docstring. This module turns what the
soak recorded (a :class:`Recording`: the per-step buffers, the :class:`MemSample` readings,
the tracemalloc snapshots and gc pauses; the simulator child's state samples) into the
figures (:func:`figures`), the pass/fail decision (:func:`verdict`) and the table printed
for a human (:func:`format_table`). The constants that define a figure (a gap, an
overrun, a noted gc pause, the phases) live here and are imported by ``tools/soak.py``.
"""

from __future__ import annotations

import itertools
import linecache
import math
import os
import tracemalloc
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from mkflight.conversions import MS_PER_S, NS_PER_MS, NS_PER_S, S_PER_MIN

GAP_FACTOR = 1.5
"""A step interval longer than this many median periods is a missed step."""
TOP_SITES = 5
OVERRUN_MS = 10.0
"""A step busier than this (arrival to done, logs included) is an overrun (as flight.json)."""
GC_NOTE_MS = 5.0
"""Garbage collections that hold the loop this long are noted (a gap may be theirs)."""
PHASES = ("preflight", "handshake", "takeoff", "hold", "land", "landed", "released")


# ----- what the soak recorded ------------------------------------------------------------


@dataclass(slots=True)
class MemSample:
    """One memory reading: traced (current, peak), RSS of the daemon, matcher, simulator."""

    kind: str  # "start" (first step), "sample" (every --sample-minutes), "end" (last step)
    t_s: float
    traced_b: int
    peak_b: int
    tracemalloc_b: int  # tracemalloc's own tables: in the RSS, not in the traced size
    rss_b: int | None
    matcher_rss_b: int | None
    sim_rss_b: int | None


class Recording(Protocol):
    """What the figures read from the soak's recorder (``tools/soak.py``'s ``Recorder``)."""

    duration_s: float
    n: int
    overflow: int
    steps: dict[str, np.ndarray]
    stop_step: int | None
    samples: list[MemSample]
    snapshots: list[tuple[float, float, tracemalloc.Snapshot]]
    snap_steps: list[int]
    gc_pauses: list[tuple[int, float, int]]


# ----- figures ---------------------------------------------------------------------------


def _pct(values: np.ndarray, q: float) -> float:
    v = values[np.isfinite(values)]
    return float(np.percentile(v, q, method="inverted_cdf")) if v.size else math.nan


def _triple(values_ms: np.ndarray) -> dict[str, float]:
    return {
        "p50": round(_pct(values_ms, 50), 4),
        "p99": round(_pct(values_ms, 99), 4),
        "max": round(_pct(values_ms, 100), 4),
    }


def _slope_per_10min(samples: Sequence[MemSample], attr: str, since_s: float = 0.0) -> float | None:
    """Least-squares growth per 10 min over the regular samples after the baseline snapshot.

    The baseline (the second sample) is skipped too: the snapshot it takes then is held
    until the end, in the RSS (tracemalloc does not trace its own objects).
    """
    regular = [s for s in samples if s.kind == "sample"][2:]
    regular = [s for s in regular if s.t_s >= since_s]
    pts = [(s.t_s, getattr(s, attr)) for s in regular if getattr(s, attr) is not None]
    if len(pts) < 2:
        return None
    t, v = np.array(pts, dtype=np.float64).T
    return float(np.polyfit(t, v, 1)[0] * 600.0)


def _site(frame: tracemalloc.Frame) -> str:
    text = linecache.getline(frame.filename, frame.lineno).strip()
    return f"{frame.filename}:{frame.lineno}" + (f"  [{text[:60]}]" if text else "")


def _top_growth(rec: Recording, tool_file: str) -> list[dict[str, Any]]:
    """The sites whose traced size grew most between the first and the last snapshot.

    Grouped by the allocating line; ``via``: the innermost mkflight frame of the biggest
    growing stack through that line, when the line itself is not mkflight's (a
    ``dataclasses.replace`` or a deque append says little on its own). The soak's own
    allocations (``tool_file``, ``tools/soak.py``, and this file) are left out.
    """
    if len(rec.snapshots) < 2:
        return []
    ignore = (
        tracemalloc.Filter(False, tracemalloc.__file__),
        tracemalloc.Filter(False, tool_file),
        tracemalloc.Filter(False, __file__),
        tracemalloc.Filter(False, "<unknown>"),
    )
    base = rec.snapshots[0][2].filter_traces(ignore)
    last = rec.snapshots[-1][2].filter_traces(ignore)
    stacks = [s for s in last.compare_to(base, "traceback") if s.size_diff > 0]
    out = []
    for stat in [s for s in last.compare_to(base, "lineno") if s.size_diff > 0][:TOP_SITES]:
        where = stat.traceback[0]
        via = next(
            (
                f
                for st in stacks
                if st.traceback[-1] == where
                for f in reversed(st.traceback)
                if f"{os.sep}mkflight{os.sep}" in f.filename
            ),
            None,
        )
        out.append(
            {
                "site": _site(where),
                "via": _site(via) if via is not None and via != where else None,
                "size_diff_b": stat.size_diff,
                "count_diff": stat.count_diff,
                "size_b": stat.size,
            }
        )
    return out


def _gaps(
    rec: Recording, gap: np.ndarray, dropped: np.ndarray, sim_late_ns: Sequence[int]
) -> np.ndarray:
    """Why each gap or dropped DebugOut happened: an index into :data:`CAUSES` (0: none).

    After one of the soak's snapshots; during a garbage collection of >= GC_NOTE_MS; the
    simulated FC woke late to send (``sim_late_ns``: the emulator's late wake-ups, on the
    same monotonic clock); a DebugOut received but dropped (the daemon fell behind: newest
    wins); else the DebugOut was read late and nothing was dropped (the daemon's loop or
    the host busy).
    """
    arr = rec.steps["arrival_ns"][: rec.n]
    cause = np.zeros(rec.n, np.int8)
    snaps = set(rec.snap_steps)
    for j in np.flatnonzero(gap | (dropped > 0)):
        if j - 1 in snaps:
            cause[j] = 1
        elif any(arr[j - 1] < end <= arr[j] + 5_000_000 for end, _, _ in rec.gc_pauses):
            cause[j] = 2
        elif any(arr[j - 1] < t <= arr[j] for t in sim_late_ns):
            cause[j] = 3
        else:
            cause[j] = 4 if dropped[j] else 5
    return cause


CAUSES = (
    "",
    "soak snapshot",
    "gc pause",
    "simulator sent late",
    "dropped by the daemon",
    "late, none dropped",
)
NOT_THE_DAEMONS = ("soak snapshot", "simulator sent late")
"""Causes that are the measurement's or the test bench's: reported, not counted as missed."""


def figures(
    rec: Recording,
    sim_rows: list[tuple[float, ...]],
    *,
    start_ns: int,
    window_s: float,
    tool_file: str,
    sim_late_ns: Sequence[int] = (),
) -> dict[str, Any]:
    """Every figure of the soak from the recorder and the simulator's samples.

    ``tool_file``: the soak tool's path (its ``__file__``), whose allocations are not
    counted among the growing sites.
    """
    n, s = rec.n, {k: v[: rec.n] for k, v in rec.steps.items()}
    arr = s["arrival_ns"]
    t_s = (arr - start_ns) / NS_PER_S
    period = np.concatenate([[math.nan], np.diff(arr) / NS_PER_MS])  # ms, the interval before i
    median = float(np.nanmedian(period)) if n > 1 else math.nan
    gap = period > GAP_FACTOR * median
    dev = np.abs(period - median)
    dev[s["restart"]] = math.nan
    lat, busy = s["latency_ns"] / NS_PER_MS, s["busy_ns"] / NS_PER_MS
    dropped = np.concatenate([[0], np.diff(s["dropped"])])
    cause = _gaps(rec, gap, dropped, sim_late_ns)
    sim = np.array(sim_rows, dtype=np.float64).reshape(-1, 9)
    sim_t = (sim[:, 0] - start_ns) / NS_PER_S
    bounds = [*np.arange(0.0, rec.duration_s - 1e-6, window_s), rec.duration_s, math.inf]
    windows = []
    for lo, hi in itertools.pairwise(bounds):
        idx = np.flatnonzero((t_s >= lo) & (t_s < hi))
        if idx.size == 0:
            continue
        prev = max(idx[0] - 1, 0)
        steps_cpu = idx[-1] - prev
        wind = sim[(sim_t >= lo) & (sim_t < min(hi, t_s[idx[-1]])), 1:3]
        mem = next((m for m in reversed(rec.samples) if lo < m.t_s <= hi), None)
        windows.append(
            {
                "label": "landing"
                if math.isinf(hi)
                else f"{lo / S_PER_MIN:g}-{hi / S_PER_MIN:g} min",
                "start_s": round(float(lo), 1),
                "steps": int(idx.size),
                "gaps": int(gap[idx].sum()),
                "dropped": int(dropped[idx].sum()),
                "overruns": int((busy[idx] > OVERRUN_MS).sum()),
                "latency_ms": _triple(lat[idx]),
                "period_dev_ms": _triple(dev[idx]),
                "cpu_ms_per_step": round(
                    MS_PER_S * float(s["cpu_s"][idx[-1]] - s["cpu_s"][prev]) / steps_cpu, 4
                )
                if steps_cpu > 0
                else None,
                "battery_v": round(float(np.nanmean(s["battery_v"][idx[-20:]])), 3),
                "wind_std_mps": round(float(np.sqrt(np.mean(np.var(wind, axis=0)))), 4)
                if len(wind) > 1
                else None,
                "traced_b": mem.traced_b if mem else None,
                "rss_b": mem.rss_b if mem else None,
            }
        )
    hold = np.flatnonzero(s["phase"] == PHASES.index("hold"))
    stop = rec.stop_step if rec.stop_step is not None else n
    left_hold = bool(hold.size and (s["phase"][hold[0] : stop] != PHASES.index("hold")).any())
    in_hold = (sim_t >= t_s[hold[0]]) & (sim_t <= t_s[hold[-1]]) if hold.size else sim_t < 0
    hv = s["battery_v"][hold] if hold.size else s["battery_v"]
    truth_v = sim[in_hold, 4] if in_hold.any() else sim[:, 4]
    regular = [m for m in rec.samples if m.kind == "sample"]
    by_cause = {
        c: {"gaps": int((gap & (cause == k)).sum()), "dropped": int(dropped[cause == k].sum())}
        for k, c in enumerate(CAUSES)
        if k
    }
    return {
        "steps": {
            "steps": n,
            "debugouts_received": int(s["debugouts"][-1] - s["debugouts"][0] + 1),
            "externcontrols_sent": int(s["commands"][-1] - s["commands"][0] + 1),
            "samples_dropped": int(dropped.sum()),
            "superseded_commands": int(s["superseded"][-1] - s["superseded"][0]),
            "delayed_commands": int(np.isnan(lat).sum()),
            "period_median_ms": round(median, 3),
            "gaps": int(gap.sum()),
            "by_cause": by_cause,
            "gap_list": [
                {
                    "t_s": round(float(t_s[j]), 3),
                    "period_ms": round(float(period[j]), 2),
                    "dropped": int(dropped[j]),
                    "cause": CAUSES[cause[j]],
                }
                for j in np.flatnonzero(cause)[:100]
            ],
            "gc_pauses_over_ms": GC_NOTE_MS,
            "gc_pauses": [
                {"t_s": round((t - start_ns) / NS_PER_S, 3), "ms": round(ms, 2), "generation": g}
                for t, ms, g in rec.gc_pauses[:100]
            ],
            "overruns": int((busy > OVERRUN_MS).sum()),
            "restarted_periods": int(s["restart"].sum()),
            "flight_s": round(float(t_s[-1]), 2),
            "steps_per_s": round((n - 1) / float(t_s[-1] - t_s[0]), 3),
            "buffer_overflow": rec.overflow,
        },
        "latency_ms": _triple(lat),
        "period_dev_ms": _triple(dev),
        "windows": windows,
        "hold": {
            "hold_s": round(float(t_s[hold[-1]] - t_s[hold[0]]), 2) if hold.size else 0.0,
            "left_hold_before_stop": left_hold,
        },
        "battery": {
            "debugout_v_start": round(float(np.mean(hv[:20])), 3),
            "debugout_v_end": round(float(np.mean(hv[-20:])), 3),
            "truth_v_start": round(float(truth_v[0]), 3) if truth_v.size else None,
            "truth_v_end": round(float(truth_v[-1]), 3) if truth_v.size else None,
            "used_ah_end": round(float(sim[-1, 5]), 4) if len(sim) else None,
        },
        "gusts": {
            "samples": int(in_hold.sum()),
            "wind_std_mps": [round(float(v), 4) for v in np.std(sim[in_hold, 1:4], axis=0)]
            if in_hold.sum() > 1
            else None,
            "wind_max_mps": round(float(np.max(np.linalg.norm(sim[in_hold, 1:4], axis=1))), 4)
            if in_hold.any()
            else None,
        },
        "memory": {
            "tracing": bool(rec.snapshots) or any(m.traced_b for m in rec.samples),
            "samples": [{k: getattr(m, k) for k in MemSample.__slots__} for m in rec.samples],
            "first_traced_b": regular[0].traced_b if regular else None,
            "last_traced_b": regular[-1].traced_b if regular else None,
            "traced_growth_per_10min_b": _slope_per_10min(rec.samples, "traced_b"),
            "traced_growth_last_half_per_10min_b": _slope_per_10min(
                rec.samples, "traced_b", since_s=rec.duration_s / 2
            ),
            "rss_growth_per_10min_b": _slope_per_10min(rec.samples, "rss_b"),
            "snapshots": [
                {"t_s": round(t, 1), "took_ms": round(ms, 1)} for t, ms, _ in rec.snapshots
            ],
            "top_growth": _top_growth(rec, tool_file),
        },
    }


def verdict(out: dict[str, Any]) -> dict[str, Any]:
    """Missed steps and an abnormal end: the reasons the soak fails (exit 1).

    A gap or dropped DebugOut right after one of the soak's own tracemalloc snapshots is
    the measurement's, not the daemon's: reported, not counted.
    """
    st, fl = out["steps"], out["flight"]
    ours = [st["by_cause"][c] for c in NOT_THE_DAEMONS]
    missed = {
        "gaps": st["gaps"] - sum(n["gaps"] for n in ours),
        "dropped_debugouts": st["samples_dropped"] - sum(n["dropped"] for n in ours),
        "debugouts_neither_stepped_nor_dropped": st["debugouts_received"]
        - st["steps"]
        - st["samples_dropped"],
        "steps_without_externcontrol": max(0, st["steps"] - st["externcontrols_sent"]),
        "superseded_commands": st["superseded_commands"],
    }
    abnormal = []
    if fl["exit_code"] != 0:
        abnormal.append(f"exit code {fl['exit_code']}")
    if fl["final_phase"] != "RELEASED":
        abnormal.append(f"final phase {fl['final_phase']}")
    if not str(fl["reason"]).startswith("--duration"):
        abnormal.append(f"ended by {fl['reason']!r}, not by --duration")
    if out["hold"]["hold_s"] <= 0 or out["hold"]["left_hold_before_stop"]:
        abnormal.append("the hover was not held until the stop")
    if fl["sim_crash"]:
        abnormal.append(f"simulator: {fl['sim_crash']}")
    if st["buffer_overflow"]:
        abnormal.append(f"{st['buffer_overflow']} steps beyond the soak's buffers")
    problems = [f"{k.replace('_', ' ')}: {v}" for k, v in missed.items() if v != 0]
    return {
        "missed": missed,
        "missed_total": sum(max(0, v) for v in missed.values()),
        "abnormal": abnormal,
        "problems": problems + abnormal,
        "ok": not problems and not abnormal,
    }


# ----- output ----------------------------------------------------------------------------


def _mb(b: float | None) -> str:
    return "-" if b is None else f"{b / 1e6:.2f}"


def _kb(b: float | None) -> str:
    return "-" if b is None else f"{b / 1e3:+.1f} kB"


def _f(v: float | None, spec: str) -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, spec)


def _row(label: str, w: dict[str, Any], lat: dict[str, float], dev: dict[str, float]) -> str:
    return (
        f"  {label:>14s} {w['steps']:6d} {w['gaps']:4d} {w['dropped']:4d} {w['overruns']:4d} "
        f"{_f(lat['p50'], '7.3f')} {_f(lat['p99'], '6.2f')} {_f(lat['max'], '6.2f')} "
        f"{_f(dev['p50'], '7.2f')} {_f(dev['p99'], '6.2f')} {_f(dev['max'], '6.2f')} "
        f"{_f(w.get('cpu_ms_per_step'), '6.3f'):>6s} {_f(w.get('battery_v'), '6.2f'):>6s} "
        f"{_f(w.get('wind_std_mps'), '5.3f'):>5s} {_mb(w.get('traced_b')):>9s} "
        f"{_mb(w.get('rss_b')):>7s}"
    )


def format_table(r: dict[str, Any]) -> str:
    """The soak's figures for a human."""
    p, fl, st, v = r["plan"], r["flight"], r["steps"], r["verdict"]
    mem, bat, g, pr = r["memory"], r["battery"], r["gusts"], r["processes"]
    t = r["daemon"]["timing"] or {}
    causes = ", ".join(
        f"{c} {n['gaps']}/{n['dropped']}" for c, n in st["by_cause"].items() if any(n.values())
    )
    lines = [
        f"Soak: {p['minutes']:g} min simulated hover, seed {p['seed']}, gusts "
        f"{'on' if p['gusts'] else 'off'} (std {p['wind_std_mps']:g} m/s), windows of "
        f"{p['window_s'] / S_PER_MIN:g} min, memory every {p['sample_s'] / S_PER_MIN:g} min, "
        f"tracemalloc "
        f"{'on' if p['tracemalloc'] else 'OFF'}",
        f"battery: {p['battery']}",
        f"flight: exit {fl['exit_code']}, final phase {fl['final_phase']}, ended by "
        f"{fl['reason']!r}; hover held {r['hold']['hold_s']:.1f} s"
        + (" (LEFT HOLD before the stop)" if r["hold"]["left_hold_before_stop"] else ""),
        f"failsafes: {'; '.join(fl['failsafes'] or []) or 'none'}",
        f"folder: {fl['log_dir']}",
        "",
        f"steps {st['steps']} ({st['steps_per_s']}/s over {st['flight_s']} s); DebugOuts "
        f"received {st['debugouts_received']}, ExternControls sent "
        f"{st['externcontrols_sent']}; period median {st['period_median_ms']:.2f} ms",
        f"gaps > {GAP_FACTOR:g} periods {st['gaps']}, dropped DebugOuts "
        f"{st['samples_dropped']} (gaps/dropped by cause: {causes or 'none'}); superseded "
        f"commands {st['superseded_commands']}, delayed {st['delayed_commands']}, overruns "
        f"> {OVERRUN_MS:g} ms {st['overruns']}, gc pauses >= {GC_NOTE_MS:g} ms "
        f"{len(st['gc_pauses'])}",
        "simulator woke late to send: "
        + (
            ", ".join(
                f"{name.upper()} {v['count']} (max {v['max_ms']:g} ms"
                + (
                    f", frames lost arriving too close: {v['rx_lost_frames']})"
                    if v.get("rx_lost_frames") is not None
                    else ")"
                )
                for name, v in r.get("simulator_late", {}).items()
            )
            or "not known"
        )
        + " (>= 20 ms after a frame was due: the host was busy, not the daemon)",
        f"daemon's counters (flight.json; its timing keeps the newest 20000 steps): steps "
        f"{t.get('steps')}, missed {t.get('missed_steps')}, overruns {t.get('overruns')}, "
        f"delayed {t.get('delayed_commands')}, latency p50/p99 {t.get('latency_median_ms')}/"
        f"{t.get('latency_p99_ms')} ms; CPU {r['daemon']['cpu_percent_of_one_core']} % of a "
        f"core; gc {r['daemon']['gc']}",
        "",
        f"  {'window':>14s} {'steps':>6s} {'gaps':>4s} {'drop':>4s} {'ovr':>4s} "
        f"{'lat p50':>7s} {'p99':>6s} {'max':>6s} {'dev p50':>7s} {'p99':>6s} {'max':>6s} "
        f"{'CPU ms':>6s} {'bat V':>6s} {'wind':>5s} {'traced MB':>9s} {'RSS MB':>7s}",
        *(_row(w["label"], w, w["latency_ms"], w["period_dev_ms"]) for w in r["windows"]),
        _row(
            "all",
            {"steps": st["steps"], "gaps": st["gaps"], "dropped": st["samples_dropped"]}
            | {"overruns": st["overruns"]},
            r["latency_ms"],
            r["period_dev_ms"],
        ),
        "  lat: DebugOut arrival -> ExternControl written (ms); dev: |step period - median| (ms);",
        "  CPU: this process's CPU per step (ms); bat: DebugOut volts; wind: simulated gust "
        "std (m/s)",
        "",
    ]
    if p["tracemalloc"]:
        lines += [
            f"memory (tracemalloc from just before the flight): first sample "
            f"{_mb(mem['first_traced_b'])} MB, last {_mb(mem['last_traced_b'])} MB, growth "
            f"{_kb(mem['traced_growth_per_10min_b'])} per 10 min; RSS growth "
            f"{_kb(mem['rss_growth_per_10min_b'])} per 10 min; traced growth over the second "
            f"half {_kb(mem['traced_growth_last_half_per_10min_b'])} per 10 min",
            "snapshots: "
            + ", ".join(f"at {s['t_s']:g} s took {s['took_ms']:g} ms" for s in mem["snapshots"]),
            f"top {TOP_SITES} growing allocation sites, first snapshot -> last:",
            *(
                [
                    f"  {_kb(s['size_diff_b']):>12s} {s['count_diff']:+7d} blocks  {s['site']}"
                    + (f"\n  {'':>27s}via {s['via']}" if s["via"] else "")
                    for s in mem["top_growth"]
                ]
                or ["  (none)"]
            ),
        ]
    lines += [
        "  kind      time s  traced MB  peak MB  tracemalloc MB  RSS MB  matcher RSS MB  "
        "sim RSS MB",
        *(
            f"  {s['kind']:7s} {s['t_s']:8.1f} {_mb(s['traced_b']):>10s} {_mb(s['peak_b']):>8s} "
            f"{_mb(s['tracemalloc_b']):>15s} {_mb(s['rss_b']):>7s} "
            f"{_mb(s['matcher_rss_b']):>15s} {_mb(s['sim_rss_b']):>11s}"
            for s in mem["samples"]
        ),
        f"RSS first step -> last step: daemon {_mb(pr['daemon']['rss_start_b'])} -> "
        f"{_mb(pr['daemon']['rss_end_b'])} MB, matcher (pid {pr['matcher']['pid']}) "
        f"{_mb(pr['matcher']['rss_start_b'])} -> {_mb(pr['matcher']['rss_end_b'])} MB, "
        f"simulator {_mb(pr['simulator']['rss_start_b'])} -> "
        f"{_mb(pr['simulator']['rss_end_b'])} MB",
        "",
        f"battery in HOLD: DebugOut {bat['debugout_v_start']:.2f} -> "
        f"{bat['debugout_v_end']:.2f} V, truth {_f(bat['truth_v_start'], '.2f')} -> "
        f"{_f(bat['truth_v_end'], '.2f')} V; {_f(bat['used_ah_end'], '.3f')} Ah used of "
        f"{p['capacity_ah']:g} Ah",
        f"gusts in HOLD ({g['samples']} samples): wind std x/y/z "
        + ("/".join(f"{x:.3f}" for x in g["wind_std_mps"]) if g["wind_std_mps"] else "-")
        + f" m/s, max |wind| {_f(g['wind_max_mps'], '.3f')} m/s",
        "",
        "verdict: " + ("OK" if v["ok"] else "FAILED: " + "; ".join(v["problems"])),
    ]
    return "\n".join(lines)
