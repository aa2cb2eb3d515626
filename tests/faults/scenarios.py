"""The fault campaign's scenarios (issues 10, 18): each fault, and what must follow it.

A :class:`Scenario` says how the fault goes in (the simulator's schedule, a
:mod:`tests.faults.inject` fault inside the daemon, signals, a read-only mount) and what
proves it was handled, beyond the checks every flight gets (:mod:`tests.faults.judge`):

* the **exit code and the message**, as specific as the fault allows (the ``error:`` line
  or the JSON summary's reason: ``failsafe: t+5.35s LEVEL_HOLD laser_stale``, not ``.``);
* the **daemon's own record** of the fault: the failsafe causes it raised after the fault
  (``events.jsonl``), the stop request and the crashed task it logged, its link counters
  in ``flight.json`` (garbage bytes, CRC and checksum errors, reopens), a gap in its
  steps as long as the FC's silence;
* **how the outcome differs from a plain hover**: a fault the daemon must absorb
  (``hover_like``) leaves the flight as the baseline's, ended by ``--duration`` on time
  with no failsafe before it; any other ends the hold within ``react_s`` of the fault.

Fault times count from the hold's first line (:data:`FAULT_AT_S` after it).
"""

from __future__ import annotations

import signal
from dataclasses import dataclass
from typing import Final

FAULT_AT_S: Final = 2.0  # faults and signals: seconds after the hold began


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
    config0: bool | None = True  # we must have sent Config = 0 last (None: cannot)
    by_fc: bool = False  # no frame can go: the FC's own hold counter must end extern control
    in_air: bool = True  # the fault must hit a vehicle in HOLD
    # --- the daemon's record of the fault (issue 18)
    causes: tuple[str, ...] = ()  # failsafe causes it must raise after the fault
    stop: str | None = None  # the stop request it must log after the fault
    crash_task: str | None = None  # the task whose crash it must log after the fault
    counters: tuple[tuple[str, str, int], ...] = ()  # flight.json: (section, key, at least)
    summary: tuple[tuple[str, str], ...] = ()  # flight.json summary: (key, regex of its value)
    step_gap_s: float | None = None  # no step for at least this long, from the fault on
    # --- how the outcome differs from a plain hover
    hover_like: bool = False  # absorbed: ends by --duration on time, no failsafe before
    react_s: float = 2.0  # else: the hold ends (failsafe, stop, crash, logs) this soon
    # a daemon defect this row exposes, not yet fixed: the row is judged as strictly, its
    # failure shown in the table and as an expected failure (xfail) in pytest
    known_issue: str | None = None
    sets: tuple[str, ...] = ()  # --set KEY=VALUE for the flight (e.g. the matcher's worker)

    @property
    def needs_namespace(self) -> bool:
        """The flight runs in a mount namespace (``unshare -rm``)."""
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
FC_FLOOD_BYTES: Final = 40 * 180
LASER_FLOOD_BYTES: Final = 20 * 1152

DURATION_END: Final = r"^--duration \d+ s$"
# the port gone: the reader (EIO) or a command's write sees it first
FC_VANISHED: Final = (
    r"^FlightCtrl lost: \S+: (device vanished or failed \(EIO|write failed, port closed)"
)
# no DebugOut for mk_release_s: the link handed control back; the MK task says so when it
# times out ("FlightCtrl lost: no DebugOut ..."), the step when a late DebugOut still came
FC_SILENT: Final = (
    r"^(FlightCtrl lost: no DebugOut from \S+ for [\d.]+ s; it hands control to the pilot's"
    r" sticks|control was handed back to the pilot \(no DebugOut for [\d.]+ s\))$"
)
LASER_STALE: Final = r"^failsafe: t\+[\d.]+s LEVEL_HOLD laser_stale$"
NONFINITE: Final = r"^failsafe: t\+[\d.]+s WARN nonfinite$"
LASER_LANDING: Final = ("laser_stale",)  # level hold, then land after degenerate_land_s
NONFINITE_LANDING: Final = ("nonfinite", "nonfinite_repeated")
FC_LOSS_S: Final = 2.0  # mk_release_s (1.0) + the MK task's 0.3 s + the FC's last frames

SCENARIOS: Final[tuple[Scenario, ...]] = (
    Scenario(
        "baseline",
        "none (a 16 s hover)",
        0,
        DURATION_END,
        ("landed",),
        stop="duration",
        causes=("stop_duration",),
        hover_like=True,
    ),
    # --- the FlightCtrl's link
    Scenario(
        "fc-unplug",
        "FC USB adapter pulled, not back",
        1,
        FC_VANISHED,
        # the FC flies our last command for its hold counter (~5.2 s): by then the vehicle
        # may have sunk to the floor or not, as that command had it (we cannot send)
        ("released", "landed"),
        sim_faults=(f"fc-vanish@{FAULT_AT_S}",),
        config0=None,
        by_fc=True,
        crash_task="mk-step",
    ),
    Scenario(
        "fc-unplug-replug",
        "FC adapter pulled, back after 1 s",
        1,
        FC_VANISHED,
        ("released", "landed"),  # as fc-unplug: it may sink while no frame can go
        sim_faults=(f"fc-vanish@{FAULT_AT_S}", f"fc-replug@{FAULT_AT_S + 1}"),
        crash_task="mk-step",
    ),
    Scenario(
        "fc-reboot",
        "FC reboots in flight (brown-out)",
        1,
        FC_SILENT,
        ("released", "landed"),
        sim_faults=(f"fc-reboot@{FAULT_AT_S}",),
        config0=None,
        crash_task="mk-step",
        step_gap_s=1.0,
        react_s=FC_LOSS_S,
    ),
    Scenario(
        "fc-silent-short",
        "FC TX silent 0.5 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=(f"fc-silent@{FAULT_AT_S}:0.5",),
        stop="duration",
        causes=("stop_duration",),
        counters=(("mk_link", "blind_commands", 1),),
        step_gap_s=0.45,
        hover_like=True,
    ),
    Scenario(
        "fc-silent",
        "FC TX silent 3 s",
        1,
        FC_SILENT,
        ("released",),
        sim_faults=(f"fc-silent@{FAULT_AT_S}:3",),
        crash_task="mk-step",
        counters=(("mk_link", "blind_commands", 1),),
        step_gap_s=1.0,
        react_s=FC_LOSS_S,
    ),
    Scenario(
        "fc-crc-burst",
        "CRC error bursts: 5, then 40 frames",
        1,
        FC_SILENT,
        ("released", "landed"),
        sim_faults=(f"fc-corrupt@{FAULT_AT_S}:5", f"fc-corrupt@{FAULT_AT_S + 1.5}:40"),
        crash_task="mk-step",
        counters=(("mk_link", "crc_errors", 45),),
        react_s=1.5 + FC_LOSS_S,
    ),
    Scenario(
        "fc-flood",
        "FC line filled up with garbage (57 600 baud) for 2 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=FC_FLOOD,
        stop="duration",
        causes=("stop_duration",),
        counters=(("mk_link", "garbage_bytes", FC_FLOOD_BYTES),),
        hover_like=True,
    ),
    Scenario(
        "fc-flood-overload",
        "more garbage than the FC line carries, 3 s",
        1,
        FC_SILENT,
        ("released",),
        sim_faults=FC_SATURATE,
        crash_task="mk-step",
        counters=(("mk_link", "garbage_bytes", 5000),),
        react_s=3.0 + FC_LOSS_S,
    ),
    # --- the laser
    Scenario(
        "laser-unplug-replug",
        "URG pulled, back after 1 s",
        0,
        LASER_STALE,
        ("landed",),
        sim_faults=(f"laser-vanish@{FAULT_AT_S}", f"laser-replug@{FAULT_AT_S + 1}"),
        causes=LASER_LANDING,
        counters=(("laser_link", "reopens", 1),),
    ),
    Scenario(
        "laser-stall",
        "URG stops scanning for 30 s",
        0,
        LASER_STALE,
        ("landed",),
        sim_faults=(f"laser-stall@{FAULT_AT_S}:30",),
        causes=LASER_LANDING,
        counters=(("laser_link", "stalls", 1),),
    ),
    Scenario(
        "laser-checksum-storm",
        "30 scans in a row with bad checksums",
        0,
        LASER_STALE,
        ("landed",),
        sim_faults=(f"laser-badsum@{FAULT_AT_S}:30",),
        causes=LASER_LANDING,
        counters=(("laser_link", "parser_sum_errors", 30),),
    ),
    Scenario(
        "laser-flood",
        "URG line flooded with garbage (1 152 bytes / 100 ms) for 2 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=LASER_FLOOD,
        stop="duration",
        causes=("stop_duration",),
        counters=(("laser_link", "parser_discarded_bytes", LASER_FLOOD_BYTES),),
        hover_like=True,
    ),
    Scenario(
        "both-flood",
        "both lines flooded at once for 2 s",
        0,
        DURATION_END,
        ("landed",),
        sim_faults=FC_FLOOD + LASER_FLOOD,
        stop="duration",
        causes=("stop_duration",),
        counters=(
            ("mk_link", "garbage_bytes", FC_FLOOD_BYTES),
            ("laser_link", "parser_discarded_bytes", LASER_FLOOD_BYTES),
        ),
        hover_like=True,
    ),
    # --- values
    Scenario(
        "nan-estimate",
        "NaN in the accelerations and attitude from the FC",
        0,
        NONFINITE,
        ("landed",),
        inject="nan-estimate",
        causes=NONFINITE_LANDING,
    ),
    Scenario(
        "inf-estimate",
        "inf in the accelerations and attitude",
        0,
        NONFINITE,
        ("landed",),
        inject="inf-estimate",
        causes=NONFINITE_LANDING,
    ),
    Scenario(
        "huge-estimate",
        "1e300 in the accelerations and attitude",
        0,
        NONFINITE,
        ("landed",),
        inject="huge-estimate",
        causes=NONFINITE_LANDING,
    ),
    # --- time
    Scenario(
        "wall-clock-jump",
        "wall clock steps 1 h ahead (NTP): time.time, time.time_ns, datetime.now",
        0,
        DURATION_END,
        ("landed",),
        inject="wall-clock-jump",
        stop="duration",
        causes=("stop_duration",),
        hover_like=True,
    ),
    Scenario(
        "process-pause",
        "daemon frozen 1.5 s (SIGSTOP/SIGCONT): its clock jumps",
        1,
        FC_SILENT,
        ("released", "landed"),
        send=((FAULT_AT_S, signal.SIGSTOP), (FAULT_AT_S + 1.5, signal.SIGCONT)),
        crash_task="mk-step",
        step_gap_s=1.4,
    ),
    # --- the disk
    Scenario(
        "disk-full",
        "log files fail with ENOSPC in flight",
        1,
        r"^log write failed: \[Errno 28\] No space left on device",
        ("landed",),
        inject="disk-full",
        # the events can no longer be written: flight.json (a new file) says what happened
        summary=(("log_error", r"No space left on device"), ("final_phase", r"^RELEASED$")),
    ),
    Scenario(
        "read-only-at-start",
        "log dir on a read-only mount",
        1,
        r"^pre-flight check 'log dir' failed: .*(Read-only|read-only|not writable)",
        ("ground",),
        namespace="ro-start",
        config0=None,
        in_air=False,
    ),
    # --- signals
    Scenario(
        "sigterm",
        "SIGTERM (systemctl stop)",
        0,
        r"^SIGTERM$",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGTERM),),
        duration_s=40.0,
        stop="sigterm",
        causes=("stop_sigterm",),
    ),
    Scenario(
        "sigint",
        "SIGINT (Ctrl-C)",
        0,
        r"^SIGINT$",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGINT),),
        duration_s=40.0,
        stop="sigint",
        causes=("stop_sigint",),
    ),
    Scenario(
        "sighup",
        "SIGHUP (the ssh session drops)",
        0,
        r"^SIGHUP$",
        ("landed",),
        send=((FAULT_AT_S, signal.SIGHUP),),
        duration_s=40.0,
        stop="sigterm",  # handled as SIGTERM, logged as SIGHUP
        causes=("stop_sigterm",),
    ),
    Scenario(
        "sigkill",
        "SIGKILL (OOM killer)",
        -9,
        r"^$",
        ("released", "landed"),
        send=((FAULT_AT_S, signal.SIGKILL),),
        duration_s=40.0,
        config0=None,
        by_fc=True,
    ),
    # --- crashes
    Scenario(
        "crash-mk-step",
        "exception in the 50 ms MK task",
        1,
        r"^RuntimeError: injected crash in the mk-step task$",
        ("released",),
        inject="crash-mk-step",
        crash_task="mk-step",
    ),
    Scenario(
        "crash-laser",
        "exception in the laser task",
        1,
        r"^RuntimeError: injected crash in the laser task$",
        ("landed",),
        inject="crash-laser",
        crash_task="laser",
        stop="crash",
        causes=("stop_crash",),
    ),
    Scenario(
        "crash-watchdog",
        "exception in the watchdog task",
        1,
        r"^RuntimeError: injected crash in the watchdog task$",
        ("landed",),
        inject="crash-watchdog",
        crash_task="watchdog",
        stop="crash",
        causes=("stop_crash",),
    ),
    Scenario(
        "crash-mk-reader",
        "exception in the MK link's reader task",
        1,
        r"^FlightCtrl lost: \S+: reader crashed: RuntimeError\('injected crash in the mk-reader",
        ("released", "landed"),
        inject="crash-mk-reader",
        crash_task="mk-step",
    ),
    Scenario(
        "crash-laser-reader",
        "exception in the URG driver's reader task",
        1,
        r"^LinkError: \S+: laser reader crashed: RuntimeError\('injected crash in the laser-re",
        ("landed",),
        inject="crash-laser-reader",
        crash_task="laser",
        stop="crash",
        causes=("stop_crash",),
    ),
    Scenario(
        "kill-matcher",
        "scan-matcher process killed (SIGKILL)",
        1,
        r"^scan matcher failed: scan matcher process died \(exit code -9\)",
        ("landed",),
        inject="kill-matcher",
        sets=("scanmatch.worker=process",),  # the matcher runs inline by default
        crash_task="laser",
        stop="crash",
        causes=("stop_crash",),
    ),
)
BY_NAME: Final = {s.name: s for s in SCENARIOS}
