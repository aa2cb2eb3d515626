"""The fault campaign (issue 10): each fault is a real flight on ptys, judged the same way.

A scenario is ``mkflight sim`` in its own process (the FC and the URG on ptys, with its
scheduled faults) and ``mkflight fly --hover`` flying it, in real time, as on hardware.
Faults inside the daemon go in through :mod:`tests.faults.inject` (the real CLI with a
fault armed after two seconds of hold); signals and pauses are sent from here. Flights run
:data:`MAX_AT_ONCE` at a time.

Every flight is judged by :func:`judge`, whatever its fault:

* **who flies at the end**: the simulated FC logs each change of "extern control applied"
  and what ended it (our Config = 0 frame, its own hold counter ~5.2 s after the last frame
  when no frame could go, a reboot); after the daemon has gone the last one must say *off*.
  *landed*: on the floor (< 5 cm) when that happened; *released*: in the air, in the
  pilot's hands (the sim's pilot keeps the gas stick down, so it sinks to the floor);
  *ground*: it never took off;
* **every command within limits**, read back from ``mk.raw`` and as the FC took them (the
  sim's summary line, which still sees them when the disk was full): tilt ≤ ``max_tilt_rad`` in
  counts (+1 for rounding), |yaw| ≤ ``yaw_max_counts``, 0 ≤ gas ≤ ``gas_max``;
* **logs readable** with :func:`mkflight.logs.load_flight` (a killed flight's torn last
  raw record is a warning, not a failure) and, when the flight was killed, rows up to the
  kill: the last step event within 0.5 s before it;
* **the exit code and the message** (the ``error:`` line, or the JSON summary's reason)
  match the scenario's expectation.
"""

from __future__ import annotations

import json
import math
import os
import queue
import re
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from mkflight.config import Config
from mkflight.errors import MkflightError
from mkflight.logs import load_flight
from mkflight.sim.truth import parse_touchdowns

REPO: Final = Path(__file__).resolve().parents[2]
PY: Final = sys.executable
MAX_AT_ONCE: Final = 4
FLIGHT_TIMEOUT_S: Final = 120.0
FC_RELEASE_WAIT_S: Final = 12.0  # the FC's hold counter runs out ~5.2 s after a frame
LANDED_M: Final = 0.05
MAX_TOUCHDOWN_MPS: Final = 0.5  # issue 17: every landing, judged on the simulator's truth
FAULT_AT_S: Final = 2.0  # faults and signals: seconds after the hold began
CFG: Final = Config()


@dataclass(frozen=True)
class Scenario:
    """One fault and what must follow (see the module docstring)."""

    name: str
    what: str  # the fault, as the README's table says it
    expect_code: int
    expect_message: str  # a regex searched in the message
    expect_end: tuple[str, ...]  # allowed ends: landed, released, ground
    sim_faults: tuple[str, ...] = ()
    inject: str | None = None  # a tests.faults.inject fault
    send: tuple[tuple[float, int], ...] = ()  # (seconds after the hold began, signal)
    duration_s: float = 16.0
    namespace: str | None = None  # "ro-start": log dir's mount read-only before start
    ci: bool = False  # in the fast subset CI runs (the rest: tools/faults.py)
    config0: bool | None = True  # we must have sent Config = 0 last (None: cannot)
    by_fc: bool = False  # no frame can go: the FC's own hold counter must end extern control
    in_air: bool = True  # the fault must hit a vehicle in HOLD

    @property
    def needs_namespace(self) -> bool:
        return self.namespace is not None


def _flood(kind: str, start_s: float, dur_s: float, period_s: float, nbytes: int) -> list[str]:
    """``kind`` faults of ``nbytes`` every ``period_s`` for ``dur_s``: a line at full baud."""
    n = round(dur_s / period_s)
    return [f"{kind}@{start_s + i * period_s:.2f}:{nbytes}" for i in range(n)]


# 57 600 baud 8N1 = 5 760 bytes/s = 288 bytes per 50 ms. The FC's own frames (a DebugOut
# every 50 ms, the confirms and 'p' answers) take about a third: 180 bytes of garbage every
# 50 ms fill the rest (the simulated wire is shared, so the line is full); 288 bytes every
# 50 ms is more than the line carries, and the FC's frames fall behind. The URG's
# USB CDC port has no baud; 115 200 (its RS-232 rate) = 1 152 bytes every 100 ms.
FC_FLOOD: Final = tuple(_flood("fc-garbage", FAULT_AT_S, 2.0, 0.05, 180))
FC_SATURATE: Final = tuple(_flood("fc-garbage", FAULT_AT_S, 3.0, 0.05, 288))
LASER_FLOOD: Final = tuple(_flood("laser-garbage", FAULT_AT_S, 2.0, 0.1, 1152))

DURATION_END: Final = r"--duration \d+ s"
FC_LOST: Final = r"FlightCtrl lost"

SCENARIOS: Final[tuple[Scenario, ...]] = (
    Scenario("baseline", "none (a 16 s hover)", 0, DURATION_END, ("landed",), ci=True),
    # --- the FlightCtrl's link
    Scenario(
        "fc-unplug",
        "FC USB adapter pulled, not back",
        1,
        FC_LOST,
        # the FC flies our last command for its hold counter (~5.2 s): by then the vehicle
        # may have sunk to the floor or not, as that command had it (we cannot send)
        ("released", "landed"),
        sim_faults=(f"fc-vanish@{FAULT_AT_S}",),
        config0=None,
        by_fc=True,
    ),
    Scenario(
        "fc-unplug-replug",
        "FC adapter pulled, back after 1 s",
        1,
        FC_LOST,
        ("released",),
        sim_faults=(f"fc-vanish@{FAULT_AT_S}", f"fc-replug@{FAULT_AT_S + 1}"),
    ),
    Scenario(
        "fc-reboot",
        "FC reboots in flight (brown-out)",
        1,
        r"DebugOut|FlightCtrl",
        ("released", "landed"),
        sim_faults=(f"fc-reboot@{FAULT_AT_S}",),
        ci=True,
        config0=None,
    ),
    Scenario(
        "fc-silent-short",
        "FC TX silent 0.5 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=(f"fc-silent@{FAULT_AT_S}:0.5",),
    ),
    Scenario(
        "fc-silent",
        "FC TX silent 3 s",
        1,
        r"DebugOut|FlightCtrl",
        ("released",),
        sim_faults=(f"fc-silent@{FAULT_AT_S}:3",),
        ci=True,
    ),
    Scenario(
        "fc-crc-burst",
        "CRC error bursts: 5, then 40 frames",
        1,
        r"DebugOut|FlightCtrl",
        ("released", "landed"),
        sim_faults=(f"fc-corrupt@{FAULT_AT_S}:5", f"fc-corrupt@{FAULT_AT_S + 1.5}:40"),
    ),
    Scenario(
        "fc-flood",
        "FC line filled up with garbage (57 600 baud) for 2 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=FC_FLOOD,
    ),
    Scenario(
        "fc-flood-overload",
        "more garbage than the FC line carries, 3 s",
        1,
        r"no DebugOut",
        ("released",),
        sim_faults=FC_SATURATE,
    ),
    # --- the laser
    Scenario(
        "laser-unplug-replug",
        "URG pulled, back after 1 s",
        0,
        r".",
        ("landed",),
        sim_faults=(f"laser-vanish@{FAULT_AT_S}", f"laser-replug@{FAULT_AT_S + 1}"),
    ),
    Scenario(
        "laser-stall",
        "URG stops scanning for 30 s",
        0,
        r".",
        ("landed",),
        sim_faults=(f"laser-stall@{FAULT_AT_S}:30",),
    ),
    Scenario(
        "laser-checksum-storm",
        "30 scans in a row with bad checksums",
        0,
        r".",
        ("landed",),
        sim_faults=(f"laser-badsum@{FAULT_AT_S}:30",),
        ci=True,
    ),
    Scenario(
        "laser-flood",
        "URG line flooded with garbage (1 152 bytes / 100 ms) for 2 s",
        0,
        r".",
        ("landed",),
        sim_faults=LASER_FLOOD,
    ),
    Scenario(
        "both-flood",
        "both lines flooded at once for 2 s",
        0,
        r".",
        ("landed",),
        sim_faults=FC_FLOOD + LASER_FLOOD,
        ci=True,
    ),
    # --- values
    Scenario(
        "nan-estimate",
        "NaN in the accelerations and attitude from the FC",
        0,
        r"failsafe",
        ("landed",),
        inject="nan-estimate",
    ),
    Scenario(
        "inf-estimate",
        "inf in the accelerations and attitude",
        0,
        r"failsafe",
        ("landed",),
        inject="inf-estimate",
        ci=True,
    ),
    Scenario(
        "huge-estimate",
        "1e300 in the accelerations and attitude",
        0,
        r"failsafe",
        ("landed",),
        inject="huge-estimate",
    ),
    # --- time
    Scenario(
        "wall-clock-jump",
        "wall clock steps 1 h ahead (NTP)",
        0,
        DURATION_END,
        ("landed",),
        inject="wall-clock-jump",
    ),
    Scenario(
        "process-pause",
        "daemon frozen 1.5 s (SIGSTOP/SIGCONT): its clock jumps",
        1,
        r".",
        ("released", "landed"),
        send=((FAULT_AT_S, signal.SIGSTOP), (FAULT_AT_S + 1.5, signal.SIGCONT)),
    ),
    # --- the disk
    Scenario(
        "disk-full",
        "log files fail with ENOSPC in flight",
        1,
        r"log write failed.*No space left",
        ("landed",),
        inject="disk-full",
        ci=True,
    ),
    Scenario(
        "read-only-at-start",
        "log dir on a read-only mount",
        1,
        r"Read-only|read-only|not writable",
        ("ground",),
        namespace="ro-start",
        config0=None,
        in_air=False,
        ci=True,
    ),
    # --- signals
    Scenario(
        "sigterm",
        "SIGTERM (systemctl stop)",
        0,
        r"SIGTERM",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGTERM),),
        duration_s=40.0,
    ),
    Scenario(
        "sigint",
        "SIGINT (Ctrl-C)",
        0,
        r"SIGINT",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGINT),),
        duration_s=40.0,
        ci=True,
    ),
    Scenario(
        "sighup",
        "SIGHUP (the ssh session drops)",
        0,
        r"SIGHUP",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGHUP),),
        duration_s=40.0,
    ),
    Scenario(
        "sigkill",
        "SIGKILL (OOM killer)",
        -9,
        r"^$",
        ("released", "landed"),
        send=((FAULT_AT_S, signal.SIGKILL),),
        duration_s=40.0,
        ci=True,
        config0=None,
        by_fc=True,
    ),
    # --- crashes
    Scenario(
        "crash-mk-step",
        "exception in the 50 ms MK task",
        1,
        r"injected crash in the mk-step",
        ("released",),
        inject="crash-mk-step",
        ci=True,
    ),
    Scenario(
        "crash-laser",
        "exception in the laser task",
        1,
        r"injected crash in the laser",
        ("landed",),
        inject="crash-laser",
        ci=True,
    ),
    Scenario(
        "crash-watchdog",
        "exception in the watchdog task",
        1,
        r"injected crash in the watchdog",
        ("landed",),
        inject="crash-watchdog",
    ),
    Scenario(
        "crash-mk-reader",
        "exception in the MK link's reader task",
        1,
        r"reader crashed",
        ("released", "landed"),
        inject="crash-mk-reader",
    ),
    Scenario(
        "crash-laser-reader",
        "exception in the URG driver's reader task",
        1,
        r"laser reader crashed",
        ("landed",),
        inject="crash-laser-reader",
    ),
    Scenario(
        "kill-matcher",
        "scan-matcher process killed (SIGKILL)",
        1,
        r"scan matcher",
        ("landed",),
        inject="kill-matcher",
        ci=True,
    ),
)
BY_NAME: Final = {s.name: s for s in SCENARIOS}


@dataclass
class Flight:
    """What a scenario's flight left behind."""

    scenario: Scenario
    folder: Path
    code: int | None = None
    stdout: str = ""
    stderr: str = ""
    sim_lines: list[dict[str, Any]] = field(default_factory=list)
    sent: list[tuple[float, int]] = field(default_factory=list)  # (monotonic s, signal)
    skipped: str | None = None


def namespace_available() -> str | None:
    """None if ``unshare -rm`` can bind-mount here, else why not."""
    if shutil.which("unshare") is None:
        return "no unshare(1)"
    probe = subprocess.run(
        ["unshare", "-rm", "sh", "-c", "mount --bind /tmp /tmp"],
        capture_output=True,
        text=True,
        check=False,
    )
    return None if probe.returncode == 0 else f"unshare -rm: {probe.stderr.strip()}"


def _sim_reader(
    proc: subprocess.Popen[str], lines: list[dict[str, Any]], q: queue.Queue[str]
) -> None:
    assert proc.stderr is not None
    for line in proc.stderr:
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict):
            lines.append(rec)
            if rec.get("event") == "sim fc extern control":
                q.put("on" if rec.get("active") else "off")


def _fly_command(sc: Scenario, folder: Path, mk: str, laser: str) -> list[str]:
    fly = [
        "--log-level",
        "info",
        "fly",
        "--hover",
        "--log-dir",
        str(folder),
        "--json",
        "--mk-port",
        mk,
        "--laser-port",
        laser,
        "--duration",
        f"{sc.duration_s:g}",
    ]
    if sc.inject is not None:
        cmd = [PY, "-m", "tests.faults.inject", sc.inject, "--", *fly]
    else:
        cmd = [PY, "-m", "mkflight", *fly]
    if sc.namespace == "ro-start":
        mount = f"mount --bind {shlex.quote(str(folder.parent))} {shlex.quote(str(folder.parent))}"
        ro = f"mount -o remount,bind,ro {shlex.quote(str(folder.parent))}"
        return ["unshare", "-rm", "sh", "-c", f"{mount} && {ro} && exec {shlex.join(cmd)}"]
    return cmd


def fly(sc: Scenario, base: Path) -> Flight:
    """Fly one scenario in real time; return what it left (see the module docstring).

    The daemon logs its phases on stderr (``--log-level info``), read here line by line:
    the hold's first line arms the faults, the simulator's with SIGUSR1 (its fault times
    count from it) and the signals with timers, so a fault always meets a hovering vehicle
    however slowly the machine started the flight.
    """
    parent = base / sc.name
    parent.mkdir(parents=True)
    folder = parent / "flight"
    flight = Flight(sc, folder)
    if sc.needs_namespace and (why := namespace_available()) is not None:
        flight.skipped = why
        return flight
    if sc.namespace != "ro-start":
        folder.mkdir()
    truth = parent / "truth.txt" if sc.namespace == "ro-start" else folder / "truth.txt"
    sim_cmd = [PY, "-m", "mkflight", "--log-json", "--log-level", "info", "sim"]
    sim_cmd += ["--truth", str(truth), "--seed", "7", "--faults-on-sigusr1"]
    for f in sc.sim_faults:
        sim_cmd += ["--fault", f]
    sim = subprocess.Popen(
        sim_cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    extern: queue.Queue[str] = queue.Queue()
    assert sim.stdout is not None
    paths = dict(sim.stdout.readline().split(maxsplit=1) for _ in range(2))
    sim_reader = threading.Thread(target=_sim_reader, args=(sim, flight.sim_lines, extern))
    sim_reader.start()
    proc = subprocess.Popen(
        _fly_command(sc, folder, paths["mk"].strip(), paths["laser"].strip()),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    timers: list[threading.Timer] = []

    def send(sig: int) -> None:
        if proc.poll() is None:
            flight.sent.append((time.monotonic(), sig))
            proc.send_signal(sig)

    def on_hold() -> None:
        sim.send_signal(signal.SIGUSR1)
        for at_s, sig in sc.send:
            timer = threading.Timer(at_s, send, args=(sig,))
            timer.start()
            timers.append(timer)

    err_lines: list[str] = []
    out_chunks: list[str] = []

    def read_stderr() -> None:
        assert proc.stderr is not None
        holding = False
        for line in proc.stderr:
            err_lines.append(line)
            if not holding and '"phase"' in line and '"HOLD"' in line:
                holding = True
                on_hold()

    def read_stdout() -> None:
        assert proc.stdout is not None
        out_chunks.append(proc.stdout.read())

    readers = [threading.Thread(target=read_stderr), threading.Thread(target=read_stdout)]
    for r in readers:
        r.start()
    try:
        proc.wait(timeout=FLIGHT_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    for r in readers:
        r.join()
    for timer in timers:
        timer.cancel()
    flight.code = proc.returncode
    flight.stdout, flight.stderr = "".join(out_chunks), "".join(err_lines)
    _await_fc_released(flight, extern)
    sim.send_signal(signal.SIGTERM)
    try:
        sim.wait(timeout=10)
    except subprocess.TimeoutExpired:
        sim.kill()
        sim.wait()
    sim_reader.join()
    return flight


def _await_fc_released(flight: Flight, extern: queue.Queue[str]) -> None:
    """Wait (on the sim's own log lines, no polling) until the FC no longer applies extern
    control, or FC_RELEASE_WAIT_S: after a kill or a lost port it is the FC's hold
    counter that hands the vehicle back."""
    state = "off"
    for rec in flight.sim_lines:
        if rec.get("event") == "sim fc extern control":
            state = "on" if rec.get("active") else "off"
    deadline = time.monotonic() + FC_RELEASE_WAIT_S
    while state == "on":
        try:
            state = extern.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return


def fly_all(scenarios: Iterable[Scenario], base: Path) -> dict[str, Flight]:
    """Fly the scenarios, at most :data:`MAX_AT_ONCE` at a time."""
    todo = list(scenarios)
    with ThreadPoolExecutor(MAX_AT_ONCE) as pool:
        flights = list(pool.map(lambda s: fly(s, base), todo))
    return {f.scenario.name: f for f in flights}


# --------------------------------------------------------------------------- judging


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
    touchdowns_mps: list[float] = field(default_factory=list)

    def row(self) -> dict[str, Any]:
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


def _truth_heights(folder: Path) -> list[float]:
    for path in (folder / "truth.txt", folder.parent / "truth.txt"):
        if path.is_file():
            rows = path.read_text(encoding="utf-8").splitlines()[1:]
            rows = [r for r in rows if not r.lstrip().startswith("#")]  # touchdown, airframe
            return [float(r.split()[3]) for r in rows if len(r.split()) == 4]
    return []


def _touchdowns(folder: Path) -> list[float]:
    """The simulator's touchdown speeds (m/s) after the vehicle first rose above 0.3 m."""
    for path in (folder / "truth.txt", folder.parent / "truth.txt"):
        if path.is_file():
            text = path.read_text(encoding="utf-8")
            rows = [r.split() for r in text.splitlines()[1:] if not r.lstrip().startswith("#")]
            up = [float(r[0]) for r in rows if len(r) == 4 and float(r[3]) > 0.3]
            return [v for t, v in parse_touchdowns(text) if up and t > up[0]]
    return []


def judge(flight: Flight) -> Verdict:
    """The verdict on one flight (module docstring)."""
    sc = flight.scenario
    problems: list[str] = []
    message = _message(flight)
    if flight.code != sc.expect_code:
        problems.append(f"exit code {flight.code}, expected {sc.expect_code}")
    if not re.search(sc.expect_message, message):
        problems.append(f"message {message!r} does not match {sc.expect_message!r}")
    if "Traceback" in flight.stderr and sc.inject is None:
        problems.append("a traceback on stderr")
    heights = _truth_heights(flight.folder)
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
    touchdowns = _touchdowns(flight.folder)
    # our landing (released: the simulated pilot's gas is down, it drops; the hold counter:
    # the FC flew our last command alone, the port gone)
    if end == "landed" and by != "hold counter":
        if not touchdowns:
            problems.append("landed, but the simulator saw no touchdown after the take-off")
        elif max(touchdowns) > MAX_TOUCHDOWN_MPS:
            problems.append(f"touchdown at {max(touchdowns):.2f} m/s > {MAX_TOUCHDOWN_MPS} m/s")
    fc_view = _fc_commands(flight)
    if fc_view is None:
        problems.append("the sim did not say which commands the FC took")
    elif fc_view.get("frames", 0):
        tilt_limit = CFG.control.max_tilt_rad * CFG.mk.counts_per_rad + 1.0
        if (
            float(fc_view["max_tilt_counts"]) > tilt_limit
            or int(fc_view["max_yaw_counts"]) > CFG.control.yaw_max_counts
            or not 0 <= int(fc_view["min_gas_counts"]) <= int(fc_view["max_gas_counts"])
            or int(fc_view["max_gas_counts"]) > CFG.control.gas_max
        ):
            problems.append(f"the FC took a command out of limits: {fc_view}")
    commands = 0
    max_tilt = 0.0
    max_gas = 0
    config0 = False
    logs = "none"
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
                tilt = [math.hypot(float(n), float(r)) for n, r in pairs]
                max_tilt = max(tilt)
                max_gas = int(cmds["gas"].max())
                config0 = int(cmds["config"][-1]) == 0
                tilt_limit = CFG.control.max_tilt_rad * CFG.mk.counts_per_rad + 1.0
                bad = sum(
                    1
                    for t, y, g in zip(tilt, cmds["yaw"], cmds["gas"], strict=True)
                    if t > tilt_limit
                    or abs(int(y)) > CFG.control.yaw_max_counts
                    or not 0 <= int(g) <= CFG.control.gas_max
                )
                if bad:
                    problems.append(f"{bad} commands out of limits")
            phases = [e.fields.get("to") for e in data.events if e.event == "phase"]
            if sc.in_air and "HOLD" not in phases:
                problems.append("never reached HOLD: the fault did not hit a hovering vehicle")
            kills = [t for t, s in flight.sent if s == signal.SIGKILL]
            if kills:
                steps = [e.t_ns for e in data.events if e.event == "step"]
                gap_s = kills[0] - steps[-1] / 1e9 if steps else math.inf
                if not 0 <= gap_s < 0.5:
                    problems.append(f"last logged step {gap_s:.2f} s before the kill")
                logs += f", last step {gap_s * 1000:.0f} ms before the kill"
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
        touchdowns_mps=[round(v, 2) for v in touchdowns],
    )


def report_row(verdict: Verdict) -> None:
    """Append the verdict to ``$MKFLIGHT_FAULTS_REPORT`` (JSON lines) if it is set."""
    path = os.environ.get("MKFLIGHT_FAULTS_REPORT")
    if path:
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps(verdict.row()) + "\n")
