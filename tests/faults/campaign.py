"""The fault campaign (issues 10, 18): each fault is a real flight on ptys.

A scenario (:mod:`tests.faults.scenarios`) is ``mkflight sim`` in its own process (the FC
and the URG on ptys, with its scheduled faults) and ``mkflight fly --hover`` flying it, in
real time, as on hardware. Faults inside the daemon go in through
:mod:`tests.faults.inject` (the real CLI with a fault armed after two seconds of hold);
signals and pauses are sent from here. Each flight is a background job
(:mod:`tests.background`: a few at a time, beside the other tests); CI flies every
scenario. What a flight left (:class:`Flight`: exit code, output, the folder, the
simulator's JSON log lines, the signals sent and when) is judged by
:func:`tests.faults.judge.judge`.
"""

from __future__ import annotations

import json
import queue
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from tests.faults.scenarios import Scenario

REPO: Final = Path(__file__).resolve().parents[2]
PY: Final = sys.executable
FLIGHT_TIMEOUT_S: Final = 120.0
FC_RELEASE_WAIT_S: Final = 12.0  # the FC's hold counter runs out ~5.2 s after a frame


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
    hold_seen_s: float | None = None  # when the hold's first line was read (monotonic s)
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
        *(arg for kv in sc.sets for arg in ("--set", kv)),
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
        flight.hold_seen_s = time.monotonic()
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
