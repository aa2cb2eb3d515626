"""Landing without the laser's height: a closed-loop descent on what is left (SPEC §5).

When the failsafe lands and the hat height is gone (a stalled or unplugged laser), or the
FC's samples are unusable (NaN), the altitude loop of :mod:`mkflight.control.altitude`
has nothing to hold. An open-loop fraction of a configured gas is not a landing: on an
airframe whose hover gas is 15 % off it either drops (≈ 1.3 m/s at the floor from 0.6 m)
or hovers until someone takes over. :class:`Descent` lands on what the vehicle
still measures, choosing per step among three sources (:class:`DescentMode`):

* ``INERTIAL`` — the FC's samples are good, the height is not: the vertical velocity and
  height are the model-aided dead reckoning of :mod:`mkflight.estimation.vertical` (the
  thrust model with the hover gas learned in HOLD, checked by AccZ), started from what the
  hat gave last. A PI on it (the altitude loop's inner gains, eq 23 of the 2011 QUT CyPhy
  MikroKopter documentation) holds ``descent_mps`` down around the learned hover gas. The
  floor is found two ways: the **stop** — the accelerometer's own integral rises by
  ``stop_fraction`` of the descent speed within ``stop_window_s`` (the landing gear's
  deceleration, which the FC's samples see) while the dead-reckoned height is below
  ``stop_max_height_m`` — and, if no stop was seen, the **descent budget** — the
  dead-reckoned height is ``probe_margin_m`` below the floor. Either starts a **probe**: the
  gas falls at ``probe_rate_per_s`` of the hover gas per second; in the air that makes the
  vehicle fall (the accelerometer's integral drops by ``fall_mps``: back to the descent, the
  budget extended), on the floor nothing moves, and at ``probe_idle_fraction`` of the hover
  gas the floor is confirmed.
* ``LASER`` — the FC's samples are unusable but the hat still gives a height: a PI on
  the hat height's rate, the floor where the height stays below ``floor_height_m`` for
  ``floor_still_s``.
* ``OPEN`` — nothing: the learned hover gas less ``open_accel_mps2`` until the descent
  speed is reached, then the hover gas. The last resort before the pilot.

After ``max_s`` without the floor the descent gives up: control goes to the pilot's
sticks in the air, which the flight logs as such and ends with exit 1. Pure: times come
in as ``t_ns``; no I/O.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, replace

from mkflight.config import ControlConfig
from mkflight.control.limits import gas_to_counts
from mkflight.control.pid import clamp
from mkflight.conversions import NS_PER_S

MAX_ABS_VZ_MPS = 10.0
"""Vertical velocities beyond this are not believed (clamped): the gas stays finite."""
MAX_ABS_HEIGHT_M = 100.0
"""Heights beyond this are clamped likewise."""
MAX_ABS_ACC_MPS2 = 50.0
"""... and accelerations."""
FALL_SIGMAS = 3.5
"""In a probe, a fall is a drop of the accelerometer's integral beyond this many of its
noise's standard deviations (and at least ``fall_mps``)."""


class DescentMode(enum.Enum):
    """What the descent flies on (module docstring)."""

    INERTIAL = "inertial"
    LASER = "laser"
    OPEN = "open"


@dataclass(frozen=True, slots=True, kw_only=True)
class DescentParams:
    """Gains and thresholds of :class:`Descent` (module docstring).

    The fields without a default come from the config (:meth:`from_config`: ``control``
    and ``mk.g_mps2``), their one home; the others are the descent's own constants.
    """

    descent_mps: float
    kp_gas_per_mps: float
    ki_gas_per_m: float
    integral_limit_gas: float
    gas_max: int
    ramp_mps2: float = 0.5
    stop_window_s: float = 0.2
    stop_fraction: float = 0.6
    stop_max_height_m: float = 0.15
    probe_margin_m: float = 0.15
    probe_extend_m: float = 0.2
    probe_rate_per_s: float = 0.2
    probe_idle_fraction: float = 0.5
    fall_mps: float = 0.15
    fall_window_s: float = 0.5
    probe_arrest_fraction: float = 0.05
    probe_fall_limit_mps: float = 0.2
    floor_height_m: float
    floor_still_s: float = 0.5
    open_accel_mps2: float = 0.5
    max_s: float = 12.0
    g_mps2: float

    @classmethod
    def from_config(cls, control: ControlConfig, g_mps2: float) -> DescentParams:
        """The descent speed, the inner loop's gains and the gas limit from ``control``."""
        return cls(
            descent_mps=control.land_mps,
            kp_gas_per_mps=control.kp_vz,
            ki_gas_per_m=control.ki_vz,
            integral_limit_gas=control.integral_limit_gas,
            gas_max=control.gas_max,
            floor_height_m=control.land_detect_height_m,
            g_mps2=g_mps2,
        )


@dataclass(frozen=True, slots=True)
class DescentOutput:
    """One step of the descent.

    Attributes:
        gas_counts: the gas to send (level, no yaw), within ``[0, gas_max]``.
        on_floor: the floor is found: cut the gas (the flight phases go LANDED).
        give_up: no floor within ``max_s``: hand control to the pilot (in the air).
        note: what changed this step ("" if nothing), for the event log.
        stopped: the landing gear's stop was felt: the vehicle rests (the dead reckoning
            may take height 0 and speed 0).
        vz_reset_mps: a probe found the vehicle falling: its vertical speed is at least
            this (the dead reckoning may take it), else None.
    """

    gas_counts: int
    on_floor: bool = False
    give_up: bool = False
    note: str = ""
    stopped: bool = False
    vz_reset_mps: float | None = None


class Descent:
    """A landing without the hat height (see the module docstring)."""

    def __init__(
        self,
        params: DescentParams,
        *,
        t_ns: int,
        vz_up_mps: float,
        hover_gas_counts: float,
        integral_gas: float = 0.0,
        noise_mps2: float | None = None,
    ) -> None:
        """Start at ``t_ns`` from the vertical velocity now.

        Args:
            params: gains and thresholds.
            t_ns: the start.
            vz_up_mps: the vertical velocity now (NaN: 0).
            hover_gas_counts: the gas that holds the weight at the hover voltage, level
                (learned in flight, else configured).
            integral_gas: the altitude loop's inner integral (carried over, bumpless).
            noise_mps2: the accelerometer's noise (AccZ, one sample's std; None: 0.3): how
                much its integral wanders on the floor, which a fall must exceed.
        """
        self.p = params
        noise = noise_mps2 if noise_mps2 is not None and math.isfinite(noise_mps2) else 0.3
        self._noise = min(max(noise, 0.0), 2.0)
        self._t0_ns = self._t_ns = t_ns
        self._floor_m = -params.probe_margin_m  # the dead-reckoned height of the floor budget
        hover_ok = math.isfinite(hover_gas_counts) and hover_gas_counts > 0
        self._hover = (
            clamp(hover_gas_counts, 1.0, params.gas_max) if hover_ok else 0.75 * params.gas_max
        )
        lim = params.integral_limit_gas
        self._integral = clamp(integral_gas, -lim, lim) if math.isfinite(integral_gas) else 0.0
        self._vz_sp = min(vz_up_mps, 0.0) if math.isfinite(vz_up_mps) else 0.0
        self._history: deque[tuple[int, float, float]] = deque()  # (t_ns, vz, Σ a·dt)
        self._dv_mps = 0.0  # the accelerometer's integral since the start (raw, bias removed)
        self._fall_history: deque[tuple[int, float]] = deque()  # (t_ns, Σ a·dt before it)
        self._probe: tuple[int, float, float] | None = None  # (start t_ns, gas, Σ a·dt then)
        self._on_floor = False
        self._laser: tuple[int, float] | None = None  # the last hat height used (t, h)
        self._laser_vz = 0.0
        self._low_since_ns: int | None = None
        self.mode = DescentMode.INERTIAL
        self.last_gas = self._hover

    @property
    def elapsed_s(self) -> float:
        """Seconds since the descent began."""
        return (self._t_ns - self._t0_ns) / NS_PER_S

    def step(
        self,
        t_ns: int,
        *,
        gas_factor: float,
        vz_up_mps: float | None = None,
        height_m: float | None = None,
        acc_up_mps2: float | None = None,
        hat: tuple[int, float] | None = None,
    ) -> DescentOutput:
        """One step: the gas to send and whether the floor is found.

        Args:
            t_ns: this step's time.
            gas_factor: the feed-forward's factor now, ``(V_hover / V) / (cos θ cos φ)``
                (1 when unknown): the hover gas now is ``hover_gas_counts * gas_factor``.
            vz_up_mps: the vertical velocity without the hat (the model-aided dead
                reckoning of :mod:`mkflight.estimation.vertical`; with the FC's samples
                unusable, corrected by the hat heights instead), or None.
            height_m: the dead-reckoned height (m, up), or None.
            acc_up_mps2: the level-frame vertical acceleration measured now (bias
                removed), or None when the FC's samples are unusable.
            hat: the newest hat height ``(scan t_ns, m)`` when the hat still gives one.
        """
        dt_s = max(0.0, (t_ns - self._t_ns) / NS_PER_S)
        self._t_ns = t_ns
        p = self.p
        if self._on_floor:
            return DescentOutput(0, on_floor=True)
        if self.elapsed_s > p.max_s:
            return DescentOutput(0, give_up=True, note=f"no floor found in {p.max_s:g} s")
        factor = gas_factor if math.isfinite(gas_factor) and 0.0 < gas_factor < 10.0 else 1.0
        hover_now = self._hover * factor
        inertial = (
            vz_up_mps is not None
            and math.isfinite(vz_up_mps)
            and acc_up_mps2 is not None
            and math.isfinite(acc_up_mps2)
        )
        if hat is not None and math.isfinite(hat[1]) and not inertial:
            self.mode = DescentMode.LASER
            h = (hat[0], clamp(hat[1], -MAX_ABS_HEIGHT_M, MAX_ABS_HEIGHT_M))
            vz_model = (
                clamp(vz_up_mps, -MAX_ABS_VZ_MPS, MAX_ABS_VZ_MPS)
                if vz_up_mps is not None and math.isfinite(vz_up_mps)
                else None
            )
            return self._laser_step(t_ns, dt_s, h, hover_now, vz_model)
        if inertial and vz_up_mps is not None and acc_up_mps2 is not None:
            self.mode = DescentMode.INERTIAL
            vz = clamp(vz_up_mps, -MAX_ABS_VZ_MPS, MAX_ABS_VZ_MPS)
            acc = clamp(acc_up_mps2, -MAX_ABS_ACC_MPS2, MAX_ABS_ACC_MPS2)
            h_est = height_m if height_m is not None and math.isfinite(height_m) else math.inf
            return self._inertial_step(t_ns, dt_s, vz, acc, h_est, hover_now)
        self.mode = DescentMode.OPEN
        return self._open_step(dt_s, hover_now)

    # ---------------------------------------------------------------- the modes
    def _pi(self, vz_up_mps: float, dt_s: float, hover_now: float) -> float:
        """The descent-speed PI around the hover gas (eq 23's form), anti-windup."""
        p = self.p
        self._vz_sp = max(-p.descent_mps, self._vz_sp - p.ramp_mps2 * dt_s)
        error = self._vz_sp - vz_up_mps
        raw = hover_now + p.kp_gas_per_mps * error + self._integral
        step = p.ki_gas_per_m * error * dt_s
        if not ((raw >= p.gas_max and step > 0) or (raw <= 0 and step < 0)):
            lim = p.integral_limit_gas
            self._integral = clamp(self._integral + step, -lim, lim)
        return hover_now + p.kp_gas_per_mps * error + self._integral

    def _out(self, gas: float, note: str = "") -> DescentOutput:
        if not math.isfinite(gas):  # absurd inputs (they are clamped): hold the last gas
            gas = self.last_gas
        self.last_gas = gas
        return DescentOutput(gas_to_counts(gas, self.p.gas_max), self._on_floor, False, note)

    def _inertial_step(
        self,
        t_ns: int,
        dt_s: float,
        vz_up_mps: float,
        acc_up_mps2: float,
        height_m: float,
        hover_now: float,
    ) -> DescentOutput:
        p = self.p
        self._fall_history.append((t_ns, self._dv_mps))
        self._dv_mps += acc_up_mps2 * dt_s
        hist = self._history
        hist.append((t_ns, vz_up_mps, self._dv_mps))
        window_ns = round(p.stop_window_s * NS_PER_S)
        while len(hist) > 1 and hist[1][0] <= t_ns - window_ns:
            hist.popleft()
        if self._probe is not None:
            return self._probe_step(t_ns, dt_s, vz_up_mps, height_m, hover_now)
        old_ns, old_vz, old_dv = hist[0]
        stopped = (
            height_m < p.stop_max_height_m  # higher up, a jolt is not the floor
            and t_ns - old_ns >= window_ns // 2
            and old_vz < -0.5 * p.descent_mps
            and self._dv_mps - old_dv >= p.stop_fraction * p.descent_mps
        )
        if stopped or height_m <= self._floor_m:
            gas0 = min(self.last_gas, hover_now)
            self._probe = (t_ns, gas0, self._dv_mps)
            why = "a stop" if stopped else f"dead-reckoned height {height_m:.2f} m"
            out = self._out(gas0, f"probe: {why}")
            return replace(out, stopped=stopped)
        return self._out(self._pi(vz_up_mps, dt_s, hover_now))

    def _probe_step(
        self, t_ns: int, dt_s: float, vz_up_mps: float, height_m: float, hover_now: float
    ) -> DescentOutput:
        """The gas falls in steps; a short fall is arrested, a long one ends the probe."""
        p = self.p
        assert self._probe is not None
        start_ns, gas, dv0 = self._probe
        gas -= p.probe_rate_per_s * self._hover * dt_s
        # the accelerometer's integral wanders by noise·√(T·t) on the floor too
        wander = self._noise * math.sqrt(max(dt_s, 1e-3) * (t_ns - start_ns) / NS_PER_S)
        limit = max(p.probe_fall_limit_mps, FALL_SIGMAS * wander)
        if self._dv_mps - dv0 < -limit:  # really falling: descend again
            self._probe = None
            self._floor_m = min(self._floor_m, height_m) - p.probe_extend_m
            self._vz_sp = -p.descent_mps
            # the dead reckoning is off (it put the floor too high, and a model that
            # disagrees with a resting vehicle drifts): the probe began near rest, so the
            # speed is what the accelerometer gained since
            vz = self._dv_mps - dv0
            out = self._out(self._pi(vz, dt_s, hover_now), "probe: falling, descend")
            return replace(out, vz_reset_mps=vz)
        note = ""
        if self._fall_mps(t_ns, dt_s) is not None:  # a short fall: hold a little more gas
            gas += p.probe_arrest_fraction * self._hover
            self._fall_history.clear()  # a new window from here
            note = "probe: a fall, arrested"
        self._probe = (start_ns, gas, dv0)
        if gas <= p.probe_idle_fraction * hover_now:
            self._on_floor = True
            return DescentOutput(0, on_floor=True, note="floor: the probe found it")
        return self._out(gas, note)

    def _fall_mps(self, t_ns: int, dt_s: float) -> float | None:
        """The accelerometer's speed change over the last ``fall_window_s`` if a fall.

        A fall is a drop beyond ``fall_mps`` and beyond :data:`FALL_SIGMAS` times the
        noise's spread over the window (``noise·√(T·window)``); the window starts no
        earlier than the probe.
        """
        p, probe = self.p, self._probe
        if probe is None:
            return None
        since_ns = max(probe[0], t_ns - round(p.fall_window_s * NS_PER_S))
        hist = self._fall_history
        while len(hist) > 1 and hist[1][0] <= since_ns:
            hist.popleft()
        if not hist or hist[0][0] > since_ns:
            return None
        drop = self._dv_mps - hist[0][1]
        span_s = (t_ns - hist[0][0]) / NS_PER_S
        wander = self._noise * math.sqrt(max(dt_s, 1e-3) * span_s)
        return drop if drop < -max(p.fall_mps, FALL_SIGMAS * wander) else None

    def _laser_step(
        self,
        t_ns: int,
        dt_s: float,
        hat: tuple[int, float],
        hover_now: float,
        vz_model: float | None,
    ) -> DescentOutput:
        """On the hat: the PI flies ``vz_model`` if given, else the heights' own rate.

        ``vz_model`` is the thrust model corrected by the hat heights (no delay); the
        heights' rate is ~0.1 s old.
        """
        p = self.p
        h_t_ns, h_m = hat
        if self._laser is None or h_t_ns > self._laser[0]:
            if self._laser is not None:
                span_s = (h_t_ns - self._laser[0]) / NS_PER_S
                if 0.0 < span_s <= 0.5:
                    vz = (h_m - self._laser[1]) / span_s
                    self._laser_vz = clamp(vz, -MAX_ABS_VZ_MPS, MAX_ABS_VZ_MPS)
            self._laser = (h_t_ns, h_m)
        if h_m < p.floor_height_m:
            self._low_since_ns = self._low_since_ns if self._low_since_ns is not None else t_ns
            if (t_ns - self._low_since_ns) / NS_PER_S >= p.floor_still_s:
                self._on_floor = True
                return DescentOutput(0, on_floor=True, note="floor: the hat height")
        else:
            self._low_since_ns = None
        vz = self._laser_vz if vz_model is None else vz_model
        return self._out(self._pi(vz, dt_s, hover_now))

    def _open_step(self, dt_s: float, hover_now: float) -> DescentOutput:
        p = self.p
        accel = p.open_accel_mps2 if self._vz_sp > -p.descent_mps else 0.0
        self._vz_sp = max(-p.descent_mps, self._vz_sp - accel * dt_s)
        return self._out(hover_now * (1.0 - accel / p.g_mps2) + self._integral)
