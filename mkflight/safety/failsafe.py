"""The failsafe state machine (SPEC §5; PX4 commander's failsafe framework is the model).

Pure and deterministic: :meth:`Failsafe.update` takes the health of every input at one
step (:class:`FailsafeInputs`, time from the caller) and returns the action to take. Each
check raises a :class:`Cause`; a cause, once raised, is LATCHED until :meth:`Failsafe.landed`
(or :meth:`Failsafe.reset`): its action never goes back down, only escalates along its
timeline. The most severe action of all latched causes wins
(``NONE < WARN < HOLD < LEVEL_HOLD < LAND < RELEASE``), and every raise or escalation of a
cause is returned as a :class:`TransitionEvent` ``(t_ns, action, cause)`` to log.

SPEC §5's table, row by row:

===============================================  ==========================================
condition                                        causes -> action (timeline)
===============================================  ==========================================
NaN/inf in estimate or command (this step)       NONFINITE -> WARN; ``use_last_command``
>= ``nonfinite_land_steps`` consecutive          NONFINITE_REPEATED -> LAND
laser pose older than ``laser_stale_s``          LASER_STALE -> LEVEL_HOLD, LAND after
                                                 ``degenerate_land_s``
scan match degenerate                            SCAN_DEGENERATE -> same as LASER_STALE
                                                 (neither raised in a landing's last
                                                 ``LASER_CAUSE_FLOOR_M``)
no DebugOut for ``mk_stale_s``/``mk_release_s``  none here: the link re-subscribes, then
                                                 releases (see below)
outside ``+-box_m`` of home / above max height   OUT_OF_BOX / ABOVE_MAX_HEIGHT -> HOLD, LAND
                                                 after ``hold_land_s``
filtered battery below warn / land voltage       BATTERY_WARN -> WARN / BATTERY_LOW -> LAND
SIGINT / SIGTERM / --duration / task crash       STOP_* -> LAND (the phases release after
                                                 landing; the app exits 0, or 1 on a crash)
pilot moves sticks / RC switch                   PILOT_OVERRIDE -> RELEASE at once
===============================================  ==========================================

The laser's two causes are not raised while a latched cause already demands LAND or more
and the estimated height is below ``LASER_CAUSE_FLOOR_M``: their whole timeline
(LEVEL_HOLD, then LAND) can never exceed LAND, so they would change nothing the vehicle
does, and near the floor the scan is not a health signal. Higher up they are raised as
ever (a laser that dies in a landing from 1 m is in the record). In a landing's last
0.1-0.2 m the sensor is 0.1-0.25 m above the floor and a tilt of 0.05-0.17 rad
puts the scan plane on the floor 1-2 m out; one attitude per 70 ms sweep, while the
landing's attitude turns at 0.5-2 rad/s, does not level those beams well enough for the
pipeline's floor filter, so such scans fail or go degenerate while the landing goes on as
it should. A cause raised before the landing stays latched and escalates as before; the
scans themselves are in the ``scan`` events.

Timed escalations run on the cause's own clock from the moment it was raised (latched:
a laser that comes back after 0.4 s still lands at 1 s). Ages that are NaN count as stale.
A non-finite position/height skips the box check that step (the NONFINITE row covers
it); a non-finite or non-positive battery sample is ignored by the sag filter.

SPEC §5's MK rows (no DebugOut for ``safety.mk_stale_s``: re-subscribe; for
``safety.mk_release_s``: hand control back) are not checked here. The flight step runs on
a DebugOut's arrival, so it never runs while the MK data is stale: the link enforces them
while the consumer waits for its next sample (:mod:`mkflight.mk.subscription`: the blind
command and the re-subscription after ``mk_stale_s``, Config = 0 after ``mk_release_s``
with control taken, also when a frozen process reads the late sample first).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import msgspec

from mkflight.config import SafetyConfig
from mkflight.conversions import S_PER_NS

HOLD_LAND_S = 1.0
"""Default time from HOLD (box, height) to LAND; SPEC §5 says "hold, then land"."""
LASER_CAUSE_FLOOR_M = 0.25
"""Below this estimated height in a landing the laser's causes are not raised (module
docstring): recorded touchdowns had failed scans at hat heights up to 0.18 m."""


class FailsafeAction(enum.IntEnum):
    """What the vehicle must do; a larger value is more severe and wins."""

    NONE = 0
    WARN = 1
    HOLD = 2
    LEVEL_HOLD = 3
    LAND = 4
    RELEASE = 5


class StopRequest(enum.Enum):
    """Why the operator side asks to stop (SPEC §5 row 6)."""

    SIGINT = "sigint"
    SIGTERM = "sigterm"
    DURATION = "duration"
    CRASH = "crash"


class Cause(enum.Enum):
    """Why a failsafe action is active (one per check, see the module table)."""

    NONFINITE = "nonfinite"
    NONFINITE_REPEATED = "nonfinite_repeated"
    LASER_STALE = "laser_stale"
    SCAN_DEGENERATE = "scan_degenerate"
    OUT_OF_BOX = "out_of_box"
    ABOVE_MAX_HEIGHT = "above_max_height"
    BATTERY_WARN = "battery_warn"
    BATTERY_LOW = "battery_low"
    STOP_SIGINT = "stop_sigint"
    STOP_SIGTERM = "stop_sigterm"
    STOP_DURATION = "stop_duration"
    STOP_CRASH = "stop_crash"
    PILOT_OVERRIDE = "pilot_override"


_STOP_CAUSE = {
    StopRequest.SIGINT: Cause.STOP_SIGINT,
    StopRequest.SIGTERM: Cause.STOP_SIGTERM,
    StopRequest.DURATION: Cause.STOP_DURATION,
    StopRequest.CRASH: Cause.STOP_CRASH,
}


class FailsafeInputs(msgspec.Struct, frozen=True, gc=False):
    """The health of every input at one step (SPEC §5).

    Attributes:
        t_ns: the step's time (the injected clock).
        values_finite: the estimate and the command of this step are free of NaN/inf.
        laser_age_s: seconds since the last laser pose (inf if none yet).
        scan_degenerate: the scan matcher flagged this match as degenerate.
        x_m: estimated position x in W (m); checked against home +- box_m.
        y_m: estimated position y in W (m).
        height_m: estimated height (m, up); checked against max_height_m.
        battery_v: raw battery voltage (V); sag-filtered here.
        stop: a stop request (signal, duration, crash), or None.
        pilot_override: the MK reports the pilot moving the sticks or the RC switch.
    """

    t_ns: int
    values_finite: bool = True
    laser_age_s: float = 0.0
    scan_degenerate: bool = False
    x_m: float = 0.0
    y_m: float = 0.0
    height_m: float = 0.0
    battery_v: float = math.nan
    stop: StopRequest | None = None
    pilot_override: bool = False


@dataclass(frozen=True, slots=True)
class TransitionEvent:
    """A cause raised or escalated: at ``t_ns`` the cause now demands ``action``."""

    t_ns: int
    action: FailsafeAction
    cause: Cause
    overall: FailsafeAction
    detail: str = ""


class FailsafeOutput(msgspec.Struct, frozen=True, gc=False):
    """One step's decision.

    Attributes:
        action: the most severe action of all latched causes.
        causes: every latched cause with its current action, most severe first.
        events: this step's transitions (raise or escalation), in check order.
        use_last_command: this step's values are non-finite: send the last safe command.
        battery_filtered_v: the sag-filtered voltage (NaN until the first valid sample).
        nonfinite_steps: consecutive steps with non-finite values so far.
    """

    action: FailsafeAction
    causes: tuple[tuple[Cause, FailsafeAction], ...]
    events: tuple[TransitionEvent, ...]
    use_last_command: bool
    battery_filtered_v: float
    nonfinite_steps: int


@dataclass(frozen=True, slots=True)
class _Latched:
    since_ns: int
    action: FailsafeAction


def _stale(age_s: float, limit_s: float) -> bool:
    return not (age_s <= limit_s)  # NaN is stale


class Failsafe:
    """The latched, prioritised failsafe (see the module docstring for the table)."""

    def __init__(
        self,
        safety: SafetyConfig,
        *,
        home_x_m: float = 0.0,
        home_y_m: float = 0.0,
        hold_land_s: float = HOLD_LAND_S,
    ) -> None:
        self.safety = safety
        self.home_x_m = home_x_m
        self.home_y_m = home_y_m
        self.hold_land_s = hold_land_s
        self._latched: dict[Cause, _Latched] = {}
        self._nonfinite_steps = 0
        self._battery_v = math.nan
        self._last_t_ns: int | None = None

    # -- state -------------------------------------------------------------------------
    @property
    def action(self) -> FailsafeAction:
        """The current overall action (NONE when nothing is latched)."""
        return max((lat.action for lat in self._latched.values()), default=FailsafeAction.NONE)

    @property
    def causes(self) -> tuple[tuple[Cause, FailsafeAction], ...]:
        """The latched causes with their actions, most severe first."""
        items = sorted(self._latched.items(), key=lambda kv: (-kv[1].action, kv[1].since_ns))
        return tuple((cause, lat.action) for cause, lat in items)

    @property
    def battery_filtered_v(self) -> float:
        """The sag-filtered battery voltage (NaN before the first valid sample)."""
        return self._battery_v

    def set_home(self, x_m: float, y_m: float) -> None:
        """Set the take-off point the box is centred on (W, m)."""
        self.home_x_m, self.home_y_m = x_m, y_m

    def landed(self) -> None:
        """The vehicle is on the ground: clear every latched cause (and the NaN count)."""
        self._latched.clear()
        self._nonfinite_steps = 0

    def reset(self) -> None:
        """Forget everything, including the battery filter (a new flight)."""
        self.landed()
        self._battery_v = math.nan
        self._last_t_ns = None

    # -- step --------------------------------------------------------------------------
    def update(self, inp: FailsafeInputs) -> FailsafeOutput:
        """Evaluate every check at ``inp.t_ns`` and return the action (SPEC §5)."""
        s = self.safety
        t = inp.t_ns
        dt_s = 0.0 if self._last_t_ns is None else (t - self._last_t_ns) * S_PER_NS
        dt_s = dt_s if dt_s > 0.0 else 0.0  # max(0.0, dt_s)
        self._last_t_ns = t
        events: list[TransitionEvent] = []
        active: list[tuple[Cause, str]] = []

        # Row 1: non-finite estimate or command.
        if inp.values_finite:
            self._nonfinite_steps = 0
        else:
            self._nonfinite_steps += 1
            active.append((Cause.NONFINITE, f"{self._nonfinite_steps} step(s)"))
            if self._nonfinite_steps >= s.nonfinite_land_steps:
                active.append((Cause.NONFINITE_REPEATED, f"{self._nonfinite_steps} steps"))
        # Row 2: laser stale or degenerate; not raised near the floor of a landing.
        if self.action < FailsafeAction.LAND or not inp.height_m < LASER_CAUSE_FLOOR_M:
            if _stale(inp.laser_age_s, s.laser_stale_s):
                active.append((Cause.LASER_STALE, f"pose age {inp.laser_age_s:.3f} s"))
            if inp.scan_degenerate:
                active.append((Cause.SCAN_DEGENERATE, "scan match degenerate"))
        # Row 3 (MK data stale) is the link's: see the module docstring.
        # Row 4: geofence.
        dx, dy = inp.x_m - self.home_x_m, inp.y_m - self.home_y_m
        if math.isfinite(dx) and math.isfinite(dy) and (abs(dx) > s.box_m or abs(dy) > s.box_m):
            active.append((Cause.OUT_OF_BOX, f"offset ({dx:.2f}, {dy:.2f}) m"))
        if math.isfinite(inp.height_m) and inp.height_m > s.max_height_m:
            active.append((Cause.ABOVE_MAX_HEIGHT, f"height {inp.height_m:.2f} m"))
        # Row 5: battery (sag-filtered).
        vbat = self._filter_battery(inp.battery_v, dt_s)
        if vbat < s.warn_voltage_v:
            active.append((Cause.BATTERY_WARN, f"filtered {vbat:.2f} V"))
        if vbat < s.land_voltage_v:
            active.append((Cause.BATTERY_LOW, f"filtered {vbat:.2f} V"))
        # Row 6: stop requests.
        if inp.stop is not None:
            active.append((_STOP_CAUSE[inp.stop], inp.stop.value))
        # Row 7: pilot.
        if inp.pilot_override:
            active.append((Cause.PILOT_OVERRIDE, "pilot sticks / RC switch"))

        if not active and not self._latched:  # the usual step: nothing raised, none latched
            return FailsafeOutput(
                FailsafeAction.NONE, (), (), False, self._battery_v, self._nonfinite_steps
            )
        for cause, detail in active:
            if cause not in self._latched:
                self._latched[cause] = _Latched(t, FailsafeAction.NONE)
                self._escalate(cause, t, detail, events)
        for cause in list(self._latched):
            self._escalate(cause, t, "", events)
        overall = self.action
        events = [TransitionEvent(e.t_ns, e.action, e.cause, overall, e.detail) for e in events]
        return FailsafeOutput(
            action=overall,
            causes=self.causes,
            events=tuple(events),
            use_last_command=not inp.values_finite,
            battery_filtered_v=self._battery_v,
            nonfinite_steps=self._nonfinite_steps,
        )

    # -- helpers -----------------------------------------------------------------------
    def _timeline_action(self, cause: Cause, elapsed_s: float) -> FailsafeAction:
        """The action a cause demands ``elapsed_s`` after it was raised."""
        a = FailsafeAction
        if cause in (Cause.LASER_STALE, Cause.SCAN_DEGENERATE):
            return a.LAND if elapsed_s >= self.safety.degenerate_land_s else a.LEVEL_HOLD
        if cause in (Cause.OUT_OF_BOX, Cause.ABOVE_MAX_HEIGHT):
            return a.LAND if elapsed_s >= self.hold_land_s else a.HOLD
        fixed = {
            Cause.NONFINITE: a.WARN,
            Cause.NONFINITE_REPEATED: a.LAND,
            Cause.BATTERY_WARN: a.WARN,
            Cause.BATTERY_LOW: a.LAND,
            Cause.PILOT_OVERRIDE: a.RELEASE,
        }
        return fixed.get(cause, a.LAND)  # the STOP_* causes

    def _escalate(
        self, cause: Cause, t_ns: int, detail: str, events: list[TransitionEvent]
    ) -> None:
        lat = self._latched[cause]
        elapsed_s = max(0.0, (t_ns - lat.since_ns) * S_PER_NS)
        new = self._timeline_action(cause, elapsed_s)
        if new > lat.action:  # latched: never goes back down
            self._latched[cause] = _Latched(lat.since_ns, new)
            why = detail or f"{elapsed_s:.3f} s after it was raised"
            events.append(TransitionEvent(t_ns, new, cause, FailsafeAction.NONE, why))

    def _filter_battery(self, battery_v: float, dt_s: float) -> float:
        """First-order sag filter, time constant ``safety.voltage_filter_s``."""
        if math.isfinite(battery_v) and battery_v > 0.0:
            if math.isnan(self._battery_v):
                self._battery_v = battery_v
            else:
                alpha = 1.0 - math.exp(-dt_s / self.safety.voltage_filter_s)
                self._battery_v += alpha * (battery_v - self._battery_v)
        return self._battery_v
