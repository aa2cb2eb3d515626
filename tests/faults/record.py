"""A fault flight's records (issue 18): that the fault fired, when, and what the daemon did.

:func:`fault_time` reads the fault's own record (the simulator's ``sim fault`` lines, the
injector's ``armed at`` line, the times the signals went) against the daemon's HOLD event;
:func:`record_checks` reads the daemon's (``events.jsonl``, ``flight.json``) against the
scenario's expectations and a plain hover's; :func:`wall_clock_jump_s`, the daemon's log
stamps. Each adds what is wrong to a list of problems (:mod:`tests.faults.judge`).
"""

from __future__ import annotations

import itertools
import json
import math
import re
import signal
from datetime import datetime
from typing import Any, Final

from mkflight.logs.events import Event
from mkflight.sim.live_faults import parse_faults
from tests.faults.campaign import Flight
from tests.faults.scenarios import FAULT_AT_S, Scenario

NS: Final = 1e9
FIRE_EARLY_S: Final = 0.05  # a record may precede its time by this (the step's sample stamp)
FIRE_LATE_S: Final = 0.5  # SIGUSR1 / the timers go once the hold's stderr line is read
INJECT_LATE_S: Final = 1.0  # the injector counts 40 hold steps: DebugOut at ~53 ms, misses
DURATION_TOL_S: Final = 0.3  # the --duration stop, after READY
WALL_JUMP_S: Final = 3600.0  # tests.faults.inject's wall-clock step
WALL_JUMP_TOL_S: Final = 60.0
GAP_FROM_S: Final = 0.3  # a step gap "at the fault" starts this close to it
DEPARTURES: Final = ("failsafe", "stop", "crash", "phase")


def after_hold(t_s: float, hold_s: float) -> str:
    return f"+{t_s - hold_s:.2f} s"


def fault_time(flight: Flight, hold_s: float, end_s: float, problems: list[str]) -> float | None:
    """When the fault hit (host monotonic s), from its own record; a problem if it did not
    fire, or not at its time after the hold began. None: no fault, or never fired.

    ``end_s``: the daemon's last event; a simulator fault due after it (less the SIGUSR1
    delay) may not have fired: the simulator is stopped once the daemon has gone.
    """
    sc = flight.scenario
    times: list[float] = []
    if sc.sim_faults:
        scheduled = parse_faults(sc.sim_faults)
        fired = [r for r in flight.sim_lines if r.get("event") == "sim fault"]
        names = [str(r.get("fault")) for r in fired]
        due = [str(f) for f in scheduled if hold_s + f.at_s < end_s - FIRE_LATE_S]
        if names != [str(f) for f in scheduled][: len(names)] or len(names) < len(due):
            problems.append(f"the simulator fired {names}, scheduled {sc.sim_faults}")
        for fault, rec in zip(scheduled, fired, strict=False):
            t_s, mono_s = float(rec.get("t_s", math.nan)), float(rec.get("mono_s", math.nan))
            late_clock = t_s - fault.at_s
            late_flight = mono_s - hold_s - fault.at_s
            if not (
                -FIRE_EARLY_S <= late_clock <= FIRE_LATE_S
                and -FIRE_EARLY_S <= late_flight <= FIRE_LATE_S
            ):
                problems.append(
                    f"{fault} fired at {t_s:.2f} s on the fault clock, "
                    f"{mono_s - hold_s:.2f} s after the hold began"
                )
            times.append(mono_s)
    if sc.inject is not None:
        armed = re.search(
            rf"^inject: {re.escape(sc.inject)} armed at ([\d.]+)$", flight.stderr, re.M
        )
        if armed is None:
            problems.append(f"the injector never armed {sc.inject}")
        else:
            t = float(armed.group(1))
            if not -FIRE_EARLY_S <= t - hold_s - FAULT_AT_S <= INJECT_LATE_S:
                problems.append(f"{sc.inject} armed {t - hold_s:.2f} s after the hold began")
            times.append(t)
        if f"inject: {sc.inject} fired=True" not in flight.stderr:
            problems.append(f"{sc.inject} never fired")
    for at_s, sig in sc.send:
        sent = [t for t, s in flight.sent if s == sig]
        name = signal.Signals(sig).name
        if not sent:
            problems.append(f"{name} was never sent (the daemon had gone)")
            continue
        if not -FIRE_EARLY_S <= sent[0] - hold_s - at_s <= FIRE_LATE_S:
            problems.append(f"{name} sent {sent[0] - hold_s:.2f} s after the hold began")
        times.append(sent[0])
    return min(times) if times else None


def wall_clock_jump_s(stderr: str) -> float:
    """The largest step between consecutive timestamps of the daemon's JSON log lines (s)."""
    stamps: list[float] = []
    for line in stderr.splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict) and isinstance(rec.get("timestamp"), str):
            text = rec["timestamp"].replace("Z", "+00:00")
            stamps.append(datetime.fromisoformat(text).timestamp())
    return max((b - a for a, b in itertools.pairwise(stamps)), default=0.0)


def _describe(e: Event) -> str:
    f = e.fields
    if e.event == "failsafe":
        return f"{f.get('cause')} {f.get('action')}"
    if e.event == "stop":
        return f"stop {f.get('request')}"
    if e.event == "crash":
        return f"crash in {f.get('task')}"
    if e.event == "phase":
        return f"phase {f.get('to')}"
    return e.event


def record_checks(
    sc: Scenario,
    events: list[Event],
    summary: dict[str, Any],
    hold_s: float,
    fault_s: float,
    problems: list[str],
) -> str:
    """The daemon's record of the fault and how its flight differs from a hover (module
    doc); returns its first reaction, for the table."""
    ready = [e.t_ns / NS for e in events if e.event == "ready"]
    after = [e for e in events if e.t_ns / NS >= fault_s - FIRE_EARLY_S]
    reactions = [e for e in after if e.event in DEPARTURES]
    quiet_until = fault_s - FIRE_EARLY_S
    duration_stop = [
        e for e in events if e.event == "stop" and e.fields.get("request") == "duration"
    ]
    if sc.hover_like and duration_stop:
        quiet_until = duration_stop[0].t_ns / NS - FIRE_EARLY_S
    noise = [
        e
        for e in events
        if e.event in ("failsafe", "stop", "crash") and hold_s <= e.t_ns / NS < quiet_until
    ]
    if noise:
        e = noise[0]
        when = "before the fault" if e.t_ns / NS < fault_s else "in a fault that must not end it"
        problems.append(f"{_describe(e)} at {after_hold(e.t_ns / NS, hold_s)} after HOLD, {when}")
    raised = {str(e.fields.get("cause")) for e in after if e.event == "failsafe"}
    for cause in sc.causes:
        if cause not in raised:
            problems.append(f"no {cause} failsafe after the fault (raised: {sorted(raised)})")
    if sc.stop is not None and not any(
        e.event == "stop" and e.fields.get("request") == sc.stop for e in after
    ):
        problems.append(f"no {sc.stop} stop logged after the fault")
    if sc.crash_task is not None and not any(
        e.event == "crash" and e.fields.get("task") == sc.crash_task for e in after
    ):
        problems.append(f"no crash of the {sc.crash_task} task logged after the fault")
    for section, key, least in sc.counters:
        got = summary.get(section, {}).get(key) if isinstance(summary.get(section), dict) else None
        if not isinstance(got, int | float) or got < least:
            problems.append(f"flight.json {section}.{key} = {got}, expected >= {least}")
    for key, pattern in sc.summary:
        if not re.search(pattern, str(summary.get(key))):
            problems.append(f"flight.json summary {key} = {summary.get(key)!r} !~ {pattern!r}")
    steps = [e.t_ns / NS for e in events if e.event == "step"]
    if sc.step_gap_s is not None:
        # after the last step: until the daemon gave up (its crash or end), if it did
        ends = [e.t_ns / NS for e in events if e.event in ("crash", "end")]
        nexts = [*steps[1:], min((t for t in ends if steps and t > steps[-1]), default=math.nan)]
        gaps = [
            b - a
            for a, b in zip(steps, nexts, strict=True)
            if fault_s - GAP_FROM_S <= a <= fault_s + GAP_FROM_S and not math.isnan(b)
        ]
        if max(gaps, default=0.0) < sc.step_gap_s:
            problems.append(
                f"longest gap between steps at the fault {max(gaps, default=0.0):.2f} s"
                f" < {sc.step_gap_s} s: the daemon did not see the FC go silent"
            )
    if sc.hover_like:
        if not duration_stop or not ready:
            problems.append("no --duration stop: the flight did not run as a hover")
            return "no --duration stop"
        t_stop = duration_stop[0].t_ns / NS - ready[0]
        if abs(t_stop - sc.duration_s) > DURATION_TOL_S:
            problems.append(f"--duration stop {t_stop:.2f} s after READY, not {sc.duration_s:g}")
        return f"as a hover: --duration stop at {t_stop:.2f} s"
    if reactions:
        first_s, what = reactions[0].t_ns / NS, _describe(reactions[0])
    elif steps:
        first_s, what = steps[-1], "logs end"
    else:
        problems.append("nothing logged after the fault")
        return "-"
    if first_s - fault_s > sc.react_s:
        problems.append(
            f"the hold went on {first_s - fault_s:.2f} s after the fault (> {sc.react_s} s)"
        )
    if duration_stop:
        problems.append("stopped by --duration, as a plain hover")
    return f"{what} {first_s - fault_s:+.2f} s"
