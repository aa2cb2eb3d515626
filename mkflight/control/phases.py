"""Flight phases (SPEC §4): a pure state machine that owns the set-point.

``PREFLIGHT -> HANDSHAKE -> TAKEOFF -> HOLD -> LAND -> LANDED -> RELEASED``

* PREFLIGHT: nothing sent but neutral frames; a ``takeoff`` request (after the caller's
  pre-flight checks) starts the HANDSHAKE.
* HANDSHAKE: neutral frames with Config = 0 for ``handshake_s``; then, if the confirms
  arrived (``handshake_ok``) and the estimate is finite, TAKEOFF at the current x, y, psi.
* TAKEOFF: the height set-point ramps from the current height to ``takeoff_height_m`` at
  ``climb_mps`` (with that rate as climb feed-forward); reaching it -> HOLD.
* HOLD: constant set-point.
* LAND: the height set-point descends at ``land_mps`` (down to ``land_floor_m`` below the
  floor, so the loop keeps pushing down); the land detector -> LANDED.
* LANDED: take control with gas 0 (``gas_cut``) for ``landed_idle_s``, then RELEASED.
* RELEASED: Config = 0, terminal.

Set-points never step: x, y, psi are fixed at take-off and the height moves at most
``max(climb_mps, land_mps) * min(dt, max_step_dt_s)`` per step (``dt`` from ``t_ns``;
a clock that goes back counts as 0). The failsafe's action acts on the phases:
HOLD freezes the ramp (the set-point stays where it is; a vehicle outside the box is
pulled back to it), LEVEL_HOLD freezes it too and asks for ``ControlMode.LEVEL``, LAND
goes to LAND (from PREFLIGHT/HANDSHAKE straight to RELEASED: nothing to land), RELEASE
goes to RELEASED at once. A ``land`` request lands, a ``release`` request releases now.

Land detector: the estimated height below ``land_detect_height_m``, or the gas at or below
``land_gas_counts`` with ``|vz_up| <= land_still_mps`` (gas at minimum and no descent),
continuously for ``land_detect_s``; only on a valid hat height (without one,
:mod:`mkflight.control.descent` finds the floor and the flight step says LANDED).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import msgspec

from mkflight.config import ControlConfig
from mkflight.control.controller import ControlMode, Setpoint
from mkflight.conversions import S_PER_NS
from mkflight.msgs import Estimate
from mkflight.safety.failsafe import FailsafeAction


class Phase(enum.Enum):
    """Where in the flight we are."""

    PREFLIGHT = "preflight"
    HANDSHAKE = "handshake"
    TAKEOFF = "takeoff"
    HOLD = "hold"
    LAND = "land"
    LANDED = "landed"
    RELEASED = "released"


FLYING_PHASES = (Phase.TAKEOFF, Phase.HOLD, Phase.LAND)
"""The phases in the air: the controllers run and a set-point exists."""


@dataclass(frozen=True, slots=True)
class PhaseParams:
    """Timing and ramp parameters (config keys where they exist, defaults otherwise)."""

    climb_mps: float = 0.3
    land_mps: float = 0.3
    takeoff_height_m: float = 0.6
    land_detect_height_m: float = 0.05
    land_detect_s: float = 1.0
    handshake_s: float = 1.0
    landed_idle_s: float = 1.0
    land_floor_m: float = -0.2
    land_gas_counts: int = 60
    land_still_mps: float = 0.1
    max_step_dt_s: float = 0.2

    @classmethod
    def from_config(
        cls, control: ControlConfig, handshake_s: float, **overrides: float
    ) -> PhaseParams:
        """Take every key config has (``control.*``, ``mk.handshake_s``).

        ``overrides`` set the rest (e.g. ``takeoff_height_m`` from ``--height``); the
        low-gas threshold of the land detector defaults to 0.6 x ``control.hover_gas``.
        """
        params = cls(
            climb_mps=control.climb_mps,
            land_mps=control.land_mps,
            takeoff_height_m=control.takeoff_height_m,
            land_detect_height_m=control.land_detect_height_m,
            land_detect_s=control.land_detect_s,
            handshake_s=handshake_s,
            land_gas_counts=round(0.6 * control.hover_gas),
        )
        return replace(params, **overrides)  # type: ignore[arg-type]


class PhaseRequests(msgspec.Struct, frozen=True, gc=False):
    """Operator requests and link facts at one step."""

    takeoff: bool = False
    land: bool = False
    release: bool = False
    handshake_ok: bool = False


@dataclass(frozen=True, slots=True)
class PhaseEvent:
    """A phase change at ``t_ns`` with its reason."""

    t_ns: int
    from_phase: Phase
    to_phase: Phase
    reason: str


class PhaseState(msgspec.Struct, frozen=True, gc=False):
    """The phase machine's memory."""

    phase: Phase = Phase.PREFLIGHT
    t_ns: int | None = None
    phase_start_ns: int = 0
    setpoint: Setpoint | None = None
    land_since_ns: int | None = None


class PhaseOutput(msgspec.Struct, frozen=True, gc=False):
    """What the flight step does this step.

    Attributes:
        state: the next state.
        phase: the phase after this step.
        setpoint: the set-point for the controller (None outside TAKEOFF/HOLD/LAND).
        run_controllers: run the controller and send its command.
        take_control: Config bit 0 (False in PREFLIGHT, HANDSHAKE, RELEASED).
        gas_cut: send neutral sticks and gas 0 (LANDED).
        mode: POSITION, or LEVEL under the failsafe's LEVEL_HOLD.
        events: this step's phase changes.
    """

    state: PhaseState
    phase: Phase
    setpoint: Setpoint | None
    run_controllers: bool
    take_control: bool
    gas_cut: bool
    mode: ControlMode
    events: tuple[PhaseEvent, ...]


_Transition = tuple[Phase, str]
"""A phase change: the phase to go to and why."""


def _step_toward(value: float, target: float, max_step: float) -> float:
    if abs(target - value) <= max_step:
        return target
    return value + math.copysign(max_step, target - value)


def _landed_now(p: PhaseParams, est: Estimate, last_gas_counts: int | None) -> bool:
    if not est.height_valid:  # a dead-reckoned height is no floor (the descent finds it)
        return False
    low = math.isfinite(est.height_m) and est.height_m < p.land_detect_height_m
    idle = (
        last_gas_counts is not None
        and last_gas_counts <= p.land_gas_counts
        and math.isfinite(est.vz_up_mps)
        and abs(est.vz_up_mps) <= p.land_still_mps
    )
    return low or idle


def _clamp_dt(dt_s: float, max_dt_s: float) -> float:
    """``min(max(0.0, dt_s), max_dt_s)`` in the builtins' order, without their calls."""
    dt_s = dt_s if dt_s > 0.0 else 0.0
    return max_dt_s if max_dt_s < dt_s else dt_s


def phase_step(
    p: PhaseParams,
    state: PhaseState,
    *,
    t_ns: int,
    est: Estimate,
    requests: PhaseRequests,
    failsafe: FailsafeAction = FailsafeAction.NONE,
    last_gas_counts: int | None = None,
) -> PhaseOutput:
    """Advance the phase machine to ``t_ns`` (see the module docstring).

    Args:
        p: ramp, timing and land-detector parameters.
        state: the previous state (``PhaseState()`` to start).
        t_ns: this step's time (the injected clock).
        est: the current estimate (non-finite fields are tolerated).
        requests: takeoff / land / release requests and the handshake result.
        failsafe: the failsafe's current action.
        last_gas_counts: the gas last sent (for the land detector), None if unknown.

    Returns:
        The next state and what to do with it.
    """
    dt_s = 0.0 if state.t_ns is None else _clamp_dt((t_ns - state.t_ns) * S_PER_NS, p.max_step_dt_s)
    phase, sp, start, land_since = (
        state.phase,
        state.setpoint,
        state.phase_start_ns,
        state.land_since_ns,
    )
    events: list[PhaseEvent] = []
    asked = _asked_transition(p, state, t_ns=t_ns, est=est, requests=requests, fs=failsafe)
    if asked is not None:
        events.append(PhaseEvent(t_ns, phase, *asked))
        phase, start, land_since = asked[0], t_ns, None
        if phase is Phase.TAKEOFF:  # from the handshake: x, y, psi and height of now
            sp = Setpoint(est.x_m, est.y_m, est.yaw_rad, est.height_m)
    ended: _Transition | None = None
    if phase in FLYING_PHASES and sp is not None:
        frozen = failsafe in (FailsafeAction.HOLD, FailsafeAction.LEVEL_HOLD)
        sp, land_since, ended = _fly(
            p,
            phase,
            sp,
            land_since,
            t_ns=t_ns,
            dt_s=dt_s,
            frozen=frozen,
            est=est,
            last_gas_counts=last_gas_counts,
        )
    elif phase is Phase.LANDED and (t_ns - start) * S_PER_NS >= p.landed_idle_s:
        ended = (Phase.RELEASED, "landed idle elapsed")
    if ended is not None:
        events.append(PhaseEvent(t_ns, phase, *ended))
        phase, start, land_since = ended[0], t_ns, None

    flying = phase in FLYING_PHASES
    new_state = PhaseState(phase, t_ns, start, sp, land_since)
    return PhaseOutput(
        state=new_state,
        phase=phase,
        setpoint=sp if flying else None,
        run_controllers=flying,
        take_control=flying or phase is Phase.LANDED,
        gas_cut=phase is Phase.LANDED,
        mode=ControlMode.LEVEL if failsafe is FailsafeAction.LEVEL_HOLD else ControlMode.POSITION,
        events=tuple(events),
    )


def _asked_transition(
    p: PhaseParams,
    state: PhaseState,
    *,
    t_ns: int,
    est: Estimate,
    requests: PhaseRequests,
    fs: FailsafeAction,
) -> _Transition | None:
    """The change the failsafe or the requests ask for this step (first match wins)."""
    phase = state.phase
    if phase is not Phase.RELEASED and (fs >= FailsafeAction.RELEASE or requests.release):
        return (
            Phase.RELEASED,
            "failsafe release" if fs >= FailsafeAction.RELEASE else "release request",
        )
    if phase in (Phase.PREFLIGHT, Phase.HANDSHAKE) and (fs >= FailsafeAction.LAND or requests.land):
        return Phase.RELEASED, "land before take-off"
    if phase in (Phase.TAKEOFF, Phase.HOLD) and (fs >= FailsafeAction.LAND or requests.land):
        return Phase.LAND, "failsafe land" if fs >= FailsafeAction.LAND else "land request"
    if phase is Phase.PREFLIGHT and requests.takeoff and fs < FailsafeAction.HOLD:
        return Phase.HANDSHAKE, "take-off request"
    if phase is Phase.HANDSHAKE:
        finite = all(math.isfinite(v) for v in (est.x_m, est.y_m, est.yaw_rad, est.height_m))
        elapsed_s = (t_ns - state.phase_start_ns) * S_PER_NS
        if (
            elapsed_s >= p.handshake_s
            and requests.handshake_ok
            and finite
            and fs < FailsafeAction.HOLD
        ):
            return Phase.TAKEOFF, "handshake confirmed"
    return None


def _fly(
    p: PhaseParams,
    phase: Phase,
    sp: Setpoint,
    land_since: int | None,
    *,
    t_ns: int,
    dt_s: float,
    frozen: bool,
    est: Estimate,
    last_gas_counts: int | None,
) -> tuple[Setpoint, int | None, _Transition | None]:
    """A flying phase's set-point ramp: the new set-point, land-detect start and phase end.

    ``frozen``: the failsafe holds, the take-off ramp stops. A failsafe HOLD does not stop
    a landing (LAND outranks it anyway).
    """
    if phase is Phase.TAKEOFF:
        rate = 0.0 if frozen else p.climb_mps
        h = _step_toward(sp.height_m, p.takeoff_height_m, rate * dt_s)
        climb = rate if h != p.takeoff_height_m else 0.0
        sp = msgspec.structs.replace(sp, height_m=h, climb_ff_mps=climb)
        if h == p.takeoff_height_m:
            return sp, land_since, (Phase.HOLD, "take-off height reached")
        return sp, land_since, None
    if phase is Phase.HOLD:
        return msgspec.structs.replace(sp, climb_ff_mps=0.0), land_since, None
    h = _step_toward(sp.height_m, p.land_floor_m, p.land_mps * dt_s)
    sp = msgspec.structs.replace(
        sp, height_m=h, climb_ff_mps=-p.land_mps if h != p.land_floor_m else 0.0
    )
    if not _landed_now(p, est, last_gas_counts):
        return sp, None, None
    land_since = t_ns if land_since is None else land_since
    if (t_ns - land_since) * S_PER_NS >= p.land_detect_s:
        return sp, land_since, (Phase.LANDED, "land detected")
    return sp, land_since, None
