"""The verdict on one fault flight (issues 10, 17, 18): the same checks for every fault.

Every flight of :mod:`tests.faults.campaign` is judged on:

* **the fault fired, when scheduled**: the simulator's own record (its ``sim fault`` log
  lines, with the fault-clock and host-monotonic times) names every scheduled fault, each
  at its time after the hold began (the daemon's HOLD event, same monotonic clock); an
  injected fault's ``inject: ... armed at T`` line 2 s into the hold and its
  ``fired=True``; each signal sent at its time. A fault that did not fire fails the row
  whatever the daemon did;
* **a clean hover until then**: no failsafe, stop or crash between the hold's start and the
  fault (else the outcome is not the fault's);
* **the daemon's own record of the fault** (:class:`~tests.faults.scenarios.Scenario`):
  failsafe causes, stop request and crashed task logged after the fault, link counters in
  ``flight.json``, a gap in the steps;
* **the outcome against a plain hover**: an absorbed fault leaves the baseline's flight
  (``--duration`` stop on time, no failsafe before it); any other ends the hold within the
  scenario's ``react_s`` of the fault (its first failsafe, stop, crash or phase change, or
  the last step it logged);
* **who flies at the end**: the simulated FC logs each change of "extern control applied"
  and what ended it (our Config = 0 frame, its own hold counter ~5.2 s after the last frame
  when no frame could go, a reboot); after the daemon has gone the last one must say *off*.
  *landed*: on the floor (< 5 cm) when that happened; *released*: in the air, in the
  pilot's hands; *ground*: it never took off. Our landing's touchdown (the simulator's
  truth) is at most 0.5 m/s;
* **every command within the limits the flight was configured with** (its ``flight.json``;
  :mod:`tests.limits_check`), read back from ``mk.raw`` and as the FC took them (the sim's
  summary line, which still sees them when the disk was full);
* **logs readable** with :func:`mkflight.logs.load_flight` and, when the flight was killed,
  rows up to the kill: the last step event within 0.5 s before it;
* **the exit code and the message** (the ``error:`` line, or the JSON summary's reason)
  match the scenario's.

The first four read the flight's records in :mod:`tests.faults.record`.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from mkflight.config import Config
from mkflight.errors import MkflightError
from mkflight.logs import load_flight
from mkflight.logs.flight_json import to_plain
from mkflight.sim.truth import parse_touchdowns
from tests.faults.campaign import Flight
from tests.faults.record import (
    NS,
    WALL_JUMP_S,
    WALL_JUMP_TOL_S,
    after_hold,
    fault_time,
    record_checks,
    wall_clock_jump_s,
)
from tests.faults.scenarios import FAULT_AT_S, Scenario
from tests.limits_check import flown_config, limit_violations

LANDED_M: Final = 0.05
MAX_TOUCHDOWN_MPS: Final = 0.5  # issue 17: every landing, judged on the simulator's truth
RAW_TRACEBACK: Final = re.compile(r"^Traceback \(most recent call last\):", re.M)


@dataclass
class Verdict:
    """One row of the campaign's table, and what was wrong (empty: passed)."""

    name: str
    what: str
    end: str
    code: int | None
    message: str
    commands: int
    max_tilt_counts: float
    max_gas: int
    config0_sent: bool
    released_by: str
    logs: str
    problems: list[str]
    touchdowns_mps: list[float] = field(default_factory=list)  # in our landing
    drops_mps: list[float] = field(default_factory=list)  # touchdowns before it (none: never)
    fired: str = ""  # when the fault fired, after the hold began
    record: str = ""  # the daemon's first reaction after the fault

    known_issue: str | None = None  # the scenario's (tests.faults.scenarios)

    def row(self) -> dict[str, Any]:
        """The verdict as a JSON-able dict, with ``ok``."""
        return self.__dict__ | {"ok": not self.problems}


def _message(flight: Flight) -> str:
    """The ``error:`` line if any, else the JSON summary's reason."""
    for line in reversed(flight.stderr.splitlines()):
        if line.startswith("error:"):
            return line.removeprefix("error:").strip()
    for line in reversed(flight.stdout.splitlines()):
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if isinstance(obj, dict) and isinstance(obj.get("reason"), str):
            return str(obj["reason"])
    return ""


def _extern_end(flight: Flight) -> tuple[bool | None, str, float]:
    """(extern control applied at the end, what ended it, the height then) from the sim."""
    active: bool | None = None
    by = ""
    height_m = math.nan
    for rec in flight.sim_lines:
        if rec.get("event") == "sim fc extern control":
            active = bool(rec.get("active"))
            by = str(rec.get("by", ""))
            height_m = float(rec.get("height_m", math.nan))
    return active, by, height_m


def _fc_commands(flight: Flight) -> dict[str, Any] | None:
    """The sim's summary of every ExternControl the FC took."""
    for rec in flight.sim_lines:
        if rec.get("event") == "sim fc commands":
            return rec
    return None


def _truth_text(folder: Path) -> str | None:
    for path in (folder / "truth.txt", folder.parent / "truth.txt"):
        if path.is_file():
            return path.read_text(encoding="utf-8")
    return None


def _truth_heights(text: str | None) -> list[float]:
    if text is None:
        return []
    rows = [r.split() for r in text.splitlines()[1:] if not r.lstrip().startswith("#")]
    return [float(r[3]) for r in rows if len(r) == 4]


def _touchdowns(text: str | None) -> list[tuple[float, float]]:
    """The simulator's touchdowns (host monotonic s, m/s) after it first rose above 0.3 m."""
    if text is None:
        return []
    rows = [r.split() for r in text.splitlines()[1:] if not r.lstrip().startswith("#")]
    up = [float(r[0]) for r in rows if len(r) == 4 and float(r[3]) > 0.3]
    return [(t, v) for t, v in parse_touchdowns(text) if up and t > up[0]]


def _landing_checks(
    sc: Scenario,
    end: str,
    by: str,
    touchdowns: list[tuple[float, float]],
    land_s: float | None,
    problems: list[str],
) -> None:
    """Our landing's touchdowns at most 0.5 m/s; no drop before it where we kept control.

    Ours: from the LAND phase on (``land_s``; None: the daemon never landed). A touchdown
    before it is a drop: the FC flying a stale command while the link was down (a lost
    port, the hold counter after SIGKILL), allowed only where the scenario allows an end
    in the pilot's hands.
    """
    ours = [v for t, v in touchdowns if land_s is not None and t >= land_s]
    drops = [v for t, v in touchdowns if land_s is None or t < land_s]
    if end == "landed" and by != "hold counter" and land_s is not None:
        if not ours:
            problems.append("landed, but the simulator saw no touchdown in our landing")
        elif max(ours) > MAX_TOUCHDOWN_MPS:
            problems.append(f"touchdown at {max(ours):.2f} m/s > {MAX_TOUCHDOWN_MPS} m/s")
    if drops and sc.expect_end == ("landed",):
        problems.append(f"touched down at {max(drops):.2f} m/s before our landing began")


def judge(flight: Flight) -> Verdict:
    """The verdict on one flight (module docstring)."""
    sc = flight.scenario
    problems: list[str] = []
    message = _message(flight)
    if flight.code != sc.expect_code:
        problems.append(f"exit code {flight.code}, expected {sc.expect_code}")
    if not re.search(sc.expect_message, message):
        problems.append(f"message {message!r} does not match {sc.expect_message!r}")
    # a raw traceback (an exception nobody caught); the JSON event lines carry a crash's
    # traceback inside a string, on the same line
    if RAW_TRACEBACK.search(flight.stderr) and sc.inject is None:
        problems.append("a traceback on stderr")
    truth = _truth_text(flight.folder)
    heights = _truth_heights(truth)
    active, by, off_height_m = _extern_end(flight)
    final_h = heights[-1] if heights else math.nan
    if not heights or max(heights) < LANDED_M:
        end = "ground"
    elif active:
        end = "EXTERN STILL ON"
    else:  # on the floor when the FC stopped taking our commands, or in the air
        end = "landed" if off_height_m < LANDED_M else "released"
    if end not in sc.expect_end:
        problems.append(f"ended {end} (height {final_h:.2f} m), expected {'/'.join(sc.expect_end)}")
    touchdowns = _touchdowns(truth)
    land_s: float | None = None  # when our landing began (None: we never landed)
    cfg = Config()
    if (flight.folder / "flight.json").is_file():
        try:
            cfg = flown_config(flight.folder)
        except (MkflightError, OSError, ValueError) as err:
            problems.append(f"flight.json: {err}")
    fc_view = _fc_commands(flight)
    if fc_view is None:
        problems.append("the sim did not say which commands the FC took")
    elif fc_view.get("frames", 0):
        # the FC's extremes: the largest tilt with zero yaw, the gas range's two ends
        tilt, yaw = float(fc_view["max_tilt_counts"]), int(fc_view["max_yaw_counts"])
        extremes = [
            (tilt, 0.0, yaw, int(fc_view["min_gas_counts"])),
            (0.0, 0.0, 0, int(fc_view["max_gas_counts"])),
        ]
        if bad := limit_violations(extremes, cfg):
            problems.append(f"the FC took a command out of limits: {bad[0]}")
    commands = 0
    max_tilt = 0.0
    max_gas = 0
    config0 = False
    logs = "none"
    fired = record = "-"
    if flight.folder.is_dir() and any(flight.folder.iterdir()):
        try:
            data = load_flight(flight.folder)
        except (MkflightError, OSError, ValueError) as err:
            logs = f"UNREADABLE: {err}"
            problems.append(logs)
        else:
            logs = f"{len(data.imu)} + {len(data.laser)} rows"
            if data.warnings:
                logs += f", {len(data.warnings)} warning(s)"
            cmds = data.commands
            commands = len(cmds)
            if commands:
                pairs = zip(cmds["nick"], cmds["roll"], strict=True)
                max_tilt = max(math.hypot(float(n), float(r)) for n, r in pairs)
                max_gas = int(cmds["gas"].max())
                config0 = int(cmds["config"][-1]) == 0
                counts = zip(cmds["nick"], cmds["roll"], cmds["yaw"], cmds["gas"], strict=True)
                if bad := limit_violations(counts, cfg):
                    problems.append(f"{len(bad)} commands out of limits, e.g. {bad[0]}")
            events = list(data.events)
            summary = to_plain(data.info.summary) if data.info and data.info.summary else {}
            lands = [
                e.t_ns / NS
                for e in events
                if e.event == "phase" and e.fields.get("to") in ("LAND", "LANDED")
            ]
            if lands:
                land_s = lands[0]
            elif summary.get("final_phase") in ("LAND", "LANDED", "RELEASED") and events:
                land_s = events[-1].t_ns / NS  # its events stopped (a full disk): it landed
            holds = [
                e.t_ns / NS for e in events if e.event == "phase" and e.fields.get("to") == "HOLD"
            ]
            if sc.in_air and not holds:
                problems.append("never reached HOLD: the fault did not hit a hovering vehicle")
            if holds:
                hold_s = holds[0]
                end_s = max(e.t_ns / NS for e in events)
                fault_s = fault_time(flight, hold_s, end_s, problems)
                if fault_s is None and not (sc.sim_faults or sc.inject or sc.send):
                    fault_s = hold_s + FAULT_AT_S  # the baseline: a hover all along
                if fault_s is not None:
                    fired = after_hold(fault_s, hold_s) if sc.name != "baseline" else "-"
                    record = record_checks(sc, events, summary, hold_s, fault_s, problems)
            if sc.inject == "wall-clock-jump":
                jump_s = wall_clock_jump_s(flight.stderr)
                if abs(jump_s - WALL_JUMP_S) > WALL_JUMP_TOL_S:
                    problems.append(
                        f"the daemon's log timestamps jumped {jump_s:.0f} s, not {WALL_JUMP_S:g}:"
                        " the wall clock was not shifted"
                    )
                record += f"; its log stamps jumped {jump_s:+.0f} s"
            kills = [t for t, s in flight.sent if s == signal.SIGKILL]
            if kills:
                steps = [e.t_ns for e in data.events if e.event == "step"]
                gap_s = kills[0] - steps[-1] / NS if steps else math.inf
                if not 0 <= gap_s < 0.5:
                    problems.append(f"last logged step {gap_s:.2f} s before the kill")
                logs += f", last step {gap_s * 1000:.0f} ms before the kill"
    _landing_checks(sc, end, by, touchdowns, land_s, problems)
    if sc.by_fc and by != "hold counter":
        problems.append(f"extern control was not ended by the FC's hold counter (by {by or '?'})")
    if sc.config0 is True and by != "command":
        problems.append(f"extern control was not ended by our Config = 0 (by {by or '?'})")
    if sc.in_air and end == "ground":
        problems.append("never took off")
    return Verdict(
        name=sc.name,
        what=sc.what,
        end=end,
        code=flight.code,
        message=message,
        commands=commands,
        max_tilt_counts=round(max_tilt, 1),
        max_gas=max_gas,
        config0_sent=config0,
        released_by=by,
        logs=logs,
        problems=problems,
        touchdowns_mps=[round(v, 2) for t, v in touchdowns if land_s is not None and t >= land_s],
        drops_mps=[round(v, 2) for t, v in touchdowns if land_s is None or t < land_s],
        fired=fired,
        record=record,
        known_issue=sc.known_issue,
    )


def report_row(verdict: Verdict) -> None:
    """Append the verdict to ``$MKFLIGHT_FAULTS_REPORT`` (JSON lines) if it is set."""
    path = os.environ.get("MKFLIGHT_FAULTS_REPORT")
    if path:
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps(verdict.row()) + "\n")
