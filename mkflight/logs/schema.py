"""The flight folder's typed records: one Struct per ``events.jsonl`` kind, and the summary.

Every writer (the daemon, ``sim hover``, a replay) builds these and every reader gets
them back, so a misspelt or missing field is a type error, not a silent ``null``; the
README's schema section is generated from them (``tools/schema.py``).

Events: :class:`FlightEvent` is the base; each kind is a subclass tagged with its
``event`` name (msgspec's tagged union, ``tag_field="event"``), and :data:`KnownEvent`
is their union. On disk a line is ``{"t_ns": ..., "event": "<kind>", <fields in the
order below>}`` (:mod:`mkflight.logs.events` writes it). A line of a kind this version
does not know (a newer writer's), or of a known kind whose fields do not fit its Struct
(a damaged line, an older writer's shape), is read as an :class:`UnknownEvent` holding
its fields as read: typed readers pass over it, :func:`mkflight.logs.load_flight`
counts it in its warnings.

Conventions: units are in the field names (``_m``, ``_mps``, ``_ns``, ``_ms``, ``_v``,
``_counts``; x and y in the world frame W, height up; SPEC §1). ``null`` stands for a
value that is not finite or not known (strict JSON has no NaN). A field typed with
``UnsetType`` may be absent from a line (``UNSET``), which says something else than
``null``.

Summary (``flight.json``'s ``summary``): :class:`FlightSummary` from the daemon,
:class:`HoverSummary` from ``sim hover``; one of another shape is read as an
:class:`UnknownSummary`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Final, TypeVar, get_args

import msgspec
from msgspec import UNSET, Meta, UnsetType

__all__ = [
    "KINDS",
    "UNSET",
    "CpuInHold",
    "Crash",
    "End",
    "Failsafe",
    "FlightEvent",
    "FlightSummary",
    "GcStats",
    "HoverSummary",
    "KnownEvent",
    "LaserLinkStats",
    "LaserLost",
    "LaserReopened",
    "LaserSilent",
    "Learned",
    "MatcherStats",
    "MkLinkStats",
    "PhaseChange",
    "PilotOverride",
    "PrecisionEstimate",
    "Preflight",
    "PreflightFigures",
    "RawCounters",
    "Ready",
    "Scan",
    "Step",
    "Stop",
    "StopDeadline",
    "Timing",
    "UnknownEvent",
    "UnknownSummary",
    "UnsetType",
    "from_plain",
]


_S = TypeVar("_S", bound=msgspec.Struct)


def from_plain(cls: type[_S], values: Mapping[str, Any]) -> _S:
    """``cls`` built from a producer's plain values (``stats.summary()``, ``as_dict()``).

    The values are taken as they are (written as the producer made them); a key the
    Struct lacks, or one it needs and ``values`` lacks, is a TypeError.
    """
    return cls(**values)


def _d(text: str) -> Meta:
    """A field's one-line meaning (the README's schema section shows it)."""
    return Meta(description=text)


# ----- events.jsonl ----------------------------------------------------------------------


class FlightEvent(msgspec.Struct, tag_field="event", kw_only=True, frozen=True, gc=False):
    """One line of ``events.jsonl``: its time, then the kind's own fields.

    Readers match on the subclass; :attr:`event` and :attr:`fields` are the by-name view
    an :class:`UnknownEvent` shares, for what handles any kind alike (a table of columns).
    """

    t_ns: Annotated[int, _d("the flight clock's time of the event, ns")]

    @property
    def event(self) -> str:
        """The kind's name, as in the line's ``event`` key."""
        tag = type(self).__struct_config__.tag
        return tag if isinstance(tag, str) else type(self).__name__

    @property
    def fields(self) -> dict[str, Any]:
        """The fields after ``t_ns`` by name (those absent from the line left out)."""
        return {k: v for k in self.__struct_fields__[1:] if (v := getattr(self, k)) is not UNSET}


class Step(FlightEvent, tag="step", kw_only=True, frozen=True):
    """One flight step (a DebugOut sample): the estimate, the set-point, the command's gas."""

    x_m: Annotated[float | None, _d("estimated position x (W)")] = None
    y_m: Annotated[float | None, _d("estimated position y (W)")] = None
    sp_x_m: Annotated[float | None, _d("set-point x (W); null: no set-point")] = None
    sp_y_m: Annotated[float | None, _d("set-point y (W); null: no set-point")] = None
    sp_height_m: Annotated[float | None, _d("set-point height; null: no set-point")] = None
    height_m: Annotated[float | None, _d("estimated height above the floor")]
    vz_up_mps: Annotated[float | None, _d("estimated vertical velocity, up")]
    gas_counts: Annotated[int, _d("the ExternControl gas sent")]
    battery_v: Annotated[float | None, _d("the FC's battery voltage")]
    phase: Annotated[str, _d("the flight phase after the step (HOLD, LAND...)")]
    action: Annotated[str, _d("the failsafe action in force (NONE, LAND...)")]
    latency_ms: Annotated[
        float | None, _d("DebugOut read to ExternControl written; null: not measured")
    ] = None


class Scan(FlightEvent, tag="scan", kw_only=True, frozen=True):
    """A scan matcher result applied to the estimate (``t_ns``: the scan's time).

    ``x_m``, ``y_m`` and ``yaw_rad`` absent (``UNSET``): the pose was not recorded, a
    replay matches the scan again.
    """

    index: Annotated[int | None, _d("its TABLE III row's index; null: no row")]
    step: Annotated[int, _d("the step it entered (the k-th step event is step k)")]
    seq: Annotated[int, _d("the scan's sequence number from the driver")]
    valid: Annotated[bool, _d("the matcher gave a pose")]
    got_ns: Annotated[int | None, _d("when the result came back from the matcher")] = None
    x_m: Annotated[float | UnsetType | None, _d("matched position x (W)")] = UNSET
    y_m: Annotated[float | UnsetType | None, _d("matched position y (W)")] = UNSET
    yaw_rad: Annotated[float | UnsetType | None, _d("matched heading")] = UNSET
    height_m: Annotated[float | None, _d("the hat's height above the floor")]
    degenerate: Annotated[bool, _d("the match was degenerate (a corridor)")]
    match_ms: Annotated[float, _d("time the matcher took (0: no matching ran)")]


class Failsafe(FlightEvent, tag="failsafe", kw_only=True, frozen=True):
    """The failsafe state machine chose an action (SPEC §5)."""

    action: Annotated[str, _d("the action (WARN, LAND, RELEASE...)")]
    cause: Annotated[str, _d("why (laser_stale, battery_low...)")]


class PhaseChange(FlightEvent, tag="phase", kw_only=True, frozen=True):
    """The flight phase changed."""

    to: Annotated[str, _d("the new phase (TAKEOFF, HOLD, LAND...)")]
    reason: Annotated[str, _d("why")]


class PreflightFigures(msgspec.Struct, kw_only=True, frozen=True):
    """What the pre-flight checks measured (SPEC §4, flight phases)."""

    fc_version: Annotated[str, _d("the FlightCtrl's version text")]
    debug_period_ms: Annotated[float | None, _d("DebugOut interval")]
    battery_v: Annotated[float | None, _d("battery voltage")]
    pitch_rad: Annotated[float | None, _d("attitude on the ground")]
    roll_rad: Annotated[float | None, _d("attitude on the ground")]
    laser: Annotated[str, _d("the laser's product name")]
    scan_period_ms: Annotated[float | None, _d("scan interval")]
    ground_height_m: Annotated[float | None, _d("the hat's height on the ground")]


class Preflight(FlightEvent, tag="preflight", kw_only=True, frozen=True):
    """The pre-flight checks passed: the :class:`PreflightFigures` fields."""

    fc_version: Annotated[str, _d("the FlightCtrl's version text")]
    debug_period_ms: Annotated[float | None, _d("DebugOut interval")]
    battery_v: Annotated[float | None, _d("battery voltage")]
    pitch_rad: Annotated[float | None, _d("attitude on the ground")]
    roll_rad: Annotated[float | None, _d("attitude on the ground")]
    laser: Annotated[str, _d("the laser's product name")]
    scan_period_ms: Annotated[float | None, _d("scan interval")]
    ground_height_m: Annotated[float | None, _d("the hat's height on the ground")]

    @classmethod
    def of(cls, t_ns: int, figures: PreflightFigures) -> Preflight:
        """The event of ``figures`` at ``t_ns``."""
        return cls(t_ns=t_ns, **msgspec.structs.asdict(figures))


class Ready(FlightEvent, tag="ready", kw_only=True, frozen=True):
    """READY: the steps use DebugOut from here on (a replay starts its first step here)."""


class Stop(FlightEvent, tag="stop", kw_only=True, frozen=True):
    """A request to land (a signal, ``--duration``, a crash); the first one wins."""

    request: Annotated[str, _d("who asked (sigint, sigterm, duration, crash...)")]
    reason: Annotated[str, _d("why, in words")]
    steps: Annotated[int | None, _d("steps run when it came; null: before READY")] = None


class PilotOverride(FlightEvent, tag="pilot_override", kw_only=True, frozen=True):
    """The pilot moved a stick: control is handed back (SPEC §5)."""

    moved: Annotated[dict[int, int], _d("receiver channel -> its value")]


class StopDeadline(FlightEvent, tag="stop_deadline", kw_only=True, frozen=True):
    """The landing did not end in time after a stop request: released."""

    error: Annotated[str, _d("the deadline error")]


class Crash(FlightEvent, tag="crash", kw_only=True, frozen=True):
    """A task ended with an exception: the flight lands."""

    task: Annotated[str, _d("the asyncio task (mk-step, laser, watchdog)")]
    error: Annotated[str, _d("repr() of the exception")]
    exception: Annotated[str | UnsetType, _d("its traceback (a bug's only)")] = UNSET


class LaserSilent(FlightEvent, tag="laser_silent", kw_only=True, frozen=True):
    """No scan in time; the driver restarts the stream."""

    error: Annotated[str, _d("the driver's error")]


class LaserLost(FlightEvent, tag="laser_lost", kw_only=True, frozen=True):
    """The laser's port was lost; it is reopened."""

    error: Annotated[str, _d("the driver's error")]


class LaserReopened(FlightEvent, tag="laser_reopened", kw_only=True, frozen=True):
    """The laser's port is open again."""


class End(FlightEvent, tag="end", kw_only=True, frozen=True):
    """The flight folder is closed (the last line)."""

    exit_reason: Annotated[str | None, _d("the summary's end_reason")]


KnownEvent = (
    Step
    | Scan
    | Failsafe
    | PhaseChange
    | Preflight
    | Ready
    | Stop
    | PilotOverride
    | StopDeadline
    | Crash
    | LaserSilent
    | LaserLost
    | LaserReopened
    | End
)
"""Every event kind this version writes and reads."""

KINDS: Final[dict[str, type[KnownEvent]]] = {
    str(cls.__struct_config__.tag): cls for cls in get_args(KnownEvent)
}
"""Kind name -> its Struct."""


class UnknownEvent(msgspec.Struct, frozen=True):
    """A line read that is not one of :data:`KnownEvent`.

    ``problem``: "" for a kind this version does not know; else why the line does not
    fit its kind's Struct (msgspec's message, naming the field).
    """

    t_ns: int
    event: str
    fields: dict[str, Any]
    problem: str = ""


# ----- flight.json: the summary ---------------------------------------------------------


class Learned(msgspec.Struct, kw_only=True, frozen=True):
    """What the flight learned of its airframe in HOLD, and what it used."""

    bias_level_mps2: Annotated[list[float] | None, _d("accelerometer bias, level frame")]
    hover_gas_counts: Annotated[float | None, _d("hover gas at hover_voltage_v")]
    vibration_mps2: Annotated[list[float] | None, _d("accelerometer noise, std")]
    steady_s: Annotated[float, _d("how long the learning ran")]
    bias_used_mps2: Annotated[list[float], _d("the bias the estimator used")]
    filter: Annotated[str, _d("estimation.filter (kalman, complementary)")]
    acc_noise_used_mps2: Annotated[
        list[float] | UnsetType, _d("the Kalman filter's accelerometer noise")
    ] = UNSET
    filter_gains_per_s: Annotated[
        list[float] | UnsetType, _d("the complementary filter's gains")
    ] = UNSET
    descents: Annotated[list[str], _d("the landing's descent modes, in order")]
    handed_in_air: Annotated[bool, _d("control was handed back in the air")]


class Timing(msgspec.Struct, kw_only=True, frozen=True):
    """Step timing (SPEC §9): latency is DebugOut read to ExternControl written."""

    steps: int
    latency_median_ms: float | None
    latency_p99_ms: float | None
    latency_max_ms: float | None
    period_median_ms: Annotated[float | None, _d("DebugOut interval")]
    jitter_p99_ms: Annotated[float | None, _d("deviation from the median interval")]
    added_jitter_p99_ms: Annotated[float | None, _d("latency change step to step")]
    missed_steps: int
    busy_median_ms: Annotated[float | None, _d("time a step took")]
    busy_p99_ms: float | None
    restarted_periods: int
    overruns: int
    delayed_commands: int


class CpuInHold(msgspec.Struct, kw_only=True, frozen=True):
    """CPU during HOLD, % of one core."""

    daemon: float
    matcher: float
    hold_s: float


class PrecisionEstimate(msgspec.Struct, kw_only=True, frozen=True):
    """Std of the estimate minus the set-point in HOLD (the flight's own view)."""

    std_x_m: float
    std_y_m: float
    std_z_m: float
    samples: int


class GcStats(msgspec.Struct, kw_only=True, frozen=True):
    """The garbage collector's runs during the flight."""

    collections: int
    full_collections: int
    max_pause_ms: float


class MatcherStats(msgspec.Struct, kw_only=True, frozen=True):
    """The scan matcher process."""

    scans: int
    cpu_ms_per_scan: float | None


class MkLinkStats(msgspec.Struct, kw_only=True, frozen=True):
    """The MK link's counters (SPEC §2): parser, samples, commands, confirms."""

    bytes_in: int
    frames_in: int
    crc_errors: int
    garbage_bytes: int
    malformed_frames: int
    overflows: int
    samples: int
    samples_dropped: int
    foreign_frames: int
    stale_events: int
    stale_releases: int
    blind_commands: int
    subscriptions: int
    commands_sent: int
    superseded_commands: int
    confirms: int
    confirms_lost: int
    reopens: int
    rtt_median_ms: Annotated[float | None, _d("command to confirm")]


class LaserLinkStats(msgspec.Struct, kw_only=True, frozen=True):
    """The URG driver's counters (SPEC §2): parser, scans, restarts."""

    parser_bytes_in: int
    parser_replies: int
    parser_sum_errors: int
    parser_malformed: int
    parser_garbage_lines: int
    parser_overflows: int
    parser_discarded_bytes: int
    scans: int
    scans_dropped: int
    stale_stream_scans: int
    restarts: int
    stalls: int
    stream_errors: int
    reopens: int


class RawCounters(msgspec.Struct, kw_only=True, frozen=True):
    """One raw port recording (``mk.raw``, ``laser.raw``)."""

    records: int
    bytes_read: int
    bytes_written: int
    dropped: Annotated[int, _d("records not written (a full disk)")]
    error: Annotated[str | None, _d("the write error that stopped it")]


class FlightSummary(msgspec.Struct, kw_only=True, frozen=True):
    """The daemon's end-of-flight summary (``mkflight fly``)."""

    end_reason: Annotated[str, _d("why the flight ended")]
    exit_code: Annotated[int, _d("0: landed and released as asked")]
    duration_s: Annotated[float, _d("wall time of the run")]
    flight_s: Annotated[float, _d("READY to the end, flight clock")]
    final_phase: str
    released: Annotated[bool, _d("Config = 0 went out at the end")]
    failsafes: Annotated[list[str], _d("every failsafe decision, in order")]
    learned: Learned
    timing: Timing
    cpu_percent_of_one_core: float | None
    cpu_percent_in_hold: CpuInHold | None
    precision_estimate: PrecisionEstimate | None
    gc: GcStats
    matcher: MatcherStats
    preflight: PreflightFigures | UnsetType = UNSET
    mk_link: MkLinkStats | UnsetType = UNSET
    laser_link: LaserLinkStats | UnsetType = UNSET
    mk_raw: RawCounters | UnsetType = UNSET
    laser_raw: RawCounters | UnsetType = UNSET
    log_error: Annotated[str | UnsetType | None, _d("the write error that stopped the logs")] = (
        UNSET
    )


class HoverSummary(msgspec.Struct, kw_only=True, frozen=True):
    """``sim hover``'s summary: precision against the truth, the landing, the airframe."""

    std_x_m: Annotated[float | None, _d("HOLD error std (truth), from 3 s into HOLD")]
    std_y_m: float | None
    std_z_m: float | None
    rms_x_m: Annotated[float | None, _d("HOLD error RMS (truth)")]
    rms_y_m: float | None
    rms_z_m: float | None
    realtime_factor: Annotated[float | None, _d("simulated s per wall s")]
    log_dir: str
    sim_s: float
    hold_s: float
    end: Annotated[str, _d("landed, released in the air, ground or flying")]
    landed: bool
    released: Annotated[bool, _d("control is the pilot's at the end (Config = 0)")]
    touchdowns_mps: Annotated[list[float], _d("every touchdown's downward speed (truth)")]
    touchdown_mps: Annotated[float | None, _d("the hardest one")]
    failsafes: list[str]
    cpu_us_per_step: float
    max_height_m: float
    final_height_m: float
    scans: Annotated[bool, _d("ray-cast scans through the real laser pipeline")]
    airframe_kind: Annotated[str, _d("sim.airframe")]
    airframe_seed: Annotated[int, _d("sim.seed")]
    airframe: Annotated[
        dict[str, float | int | bool | list[float] | None], _d("the airframe's constants")
    ]
    learned: Learned


class UnknownSummary(msgspec.Struct, frozen=True):
    """A summary that fits neither Struct (another version's): its fields as read, and why."""

    fields: dict[str, Any]
    problem: str = ""
