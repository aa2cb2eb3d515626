"""What the flight step knows of its airframe, and how it comes down without the hat.

:class:`FlightAirframe` gathers, for :class:`~mkflight.flight.step.FlightCore`, the three
pieces that make a flight fit the vehicle it is on rather than the configuration:

* the **learner** (:mod:`mkflight.estimation.learner`): accelerometer biases, hover gas
  and vibration from the steady part of HOLD; the biases go into the estimator at once;
* the **vertical channel without the hat** (:mod:`mkflight.estimation.vertical`): from
  the step the hat height is lost, height and vertical speed come from the thrust model
  with the learned hover gas, checked by AccZ;
* the **descent** (:mod:`mkflight.control.descent`): a landing that cannot fly on the hat
  height flies on that channel (or on the hat alone when the FC's samples are unusable),
  finds the floor, and only gives up to the pilot if it finds none.

Pure like the flight step: values and times in, values out.
"""

from __future__ import annotations

import math
from dataclasses import replace

import msgspec

from mkflight.config import Config
from mkflight.control.altitude import hover_feedforward
from mkflight.control.descent import Descent, DescentOutput, DescentParams
from mkflight.control.limits import gas_to_counts
from mkflight.conversions import NS_PER_S
from mkflight.estimation.estimator import Estimator
from mkflight.estimation.learner import (
    UPDATE_EVERY,
    AirframeLearner,
    LearnedAirframe,
    TimeMean,
)
from mkflight.estimation.vertical import VerticalDeadReckoning
from mkflight.msgs import Estimate, ImuSample

LEARN_AFTER_HOLD_S = 2.0
"""The airframe is learned from HOLD steps this long after HOLD began (not the take-off)."""
LEARN_MAX_VZ_MPS = 0.2
"""... and only while the vertical speed is below this."""
BIAS_RATE_MPS3 = 0.02
"""The estimator's bias moves towards the learned one at most this fast (m/s^2 per s)."""
LEARN_STEP_S = 0.0532
"""The nominal step (a DebugOut every 52 FC ticks), for the rate above."""
THRUST_TAU_S = 0.05
"""The motors' lag from gas to thrust the model assumes (an airframe's: 0.03-0.10 s)."""
LASER_HEIGHT_FRESH_S = 0.3
"""A descent without usable FC samples flies on a hat height at most this old."""
RECENT_HOVER_TAU_S = 1.0
"""Before the learner has a hover gas (its first :data:`~mkflight.estimation.learner.MIN_LEARN_S`
of steady HOLD), the thrust model takes the gas flown in HOLD, averaged over this (s)..."""
RECENT_HOVER_MIN_S = 1.0
"""... once it has this much of it (s); before that, the altitude loop's view."""
RECENT_MAX_GAP_S = 0.2
"""A longer gap between samples counts as this long."""
UNLEARNED_DESCENT = 0.7
"""Before the hover gas is learned, a descent without the hat flies this fraction of
``control.land_mps``: the model's error (2-3 % of the hover gas, 0.1-0.2 m/s by the floor
from 0.6 m) then still touches down below 0.5 m/s."""
RECENT_MAX_ACC_G = 0.3
"""A sample accelerating harder than this (a jolt) is left out."""
RECENT_HAT_FRESH_S = 0.15
"""... and only while the hat's last height is this fresh (s; a scan every 0.1 s): once it
stalls the altitude loop flies on a stale height, and its gas is no hover gas."""


def gas_factor(cfg: Config, pitch_rad: float, roll_rad: float, battery_v: float) -> float | None:
    """The altitude feed-forward's factor ``(V_hover / V) / (cos θ cos φ)``, or None."""
    if not (math.isfinite(pitch_rad) and math.isfinite(roll_rad) and math.isfinite(battery_v)):
        return None
    c = cfg.control
    if battery_v <= 0.0 or c.hover_gas <= 0.0:
        return None
    ff = hover_feedforward(c, pitch_rad=pitch_rad, roll_rad=roll_rad, battery_v=battery_v)
    return ff / c.hover_gas


def _finite_imu(imu: ImuSample) -> bool:
    values = (imu.pitch_rad, imu.roll_rad, imu.acc_x_mps2, imu.acc_y_mps2, imu.acc_z_mps2)
    return all(math.isfinite(v) for v in values)


class FlightAirframe:
    """The learner, the vertical channel without the hat and the descent (module docstring)."""

    def __init__(self, cfg: Config, estimator: Estimator) -> None:
        """Learn for ``estimator`` (it gets the biases) with ``cfg``'s hover voltage and gains."""
        self.cfg = cfg
        self.estimator = estimator
        self.learner = AirframeLearner(cfg.control.hover_voltage_v)
        self.vertical: VerticalDeadReckoning | None = None
        """The model-aided vertical channel while the hat gives no height (else None)."""
        self.descent: Descent | None = None
        self.log: list[str] = []
        """What the descents without a hat height did, for ``flight.json``."""
        self._laser_height: tuple[int, int, float] | None = None  # (arrival, scan t_ns, m)
        self._gas_lagged: tuple[int, float] | None = None  # the motors' view of the gas
        self._hat_used_ns: int | None = None  # the last hat height the model took
        self._hat_model: VerticalDeadReckoning | None = None  # no FC samples: model + hat
        self._applied: LearnedAirframe | None = None  # the figures last given the estimator
        self._lag: tuple[float, float] = (0.0, 0.0)  # (dt, the motors' lag factor)
        self._recent_hover = TimeMean(RECENT_HOVER_TAU_S)  # the gas flown in HOLD
        self._recent_t_ns: int | None = None  # its last sample's time
        self._factor_of: tuple[ImuSample, float | None] | None = None  # the step's gas factor

    def _gas_factor(self, imu: ImuSample) -> float | None:
        """:func:`gas_factor` of ``imu``'s attitude and battery, once per sample.

        The thrust model and the learner both ask for it on every step.
        """
        memo = self._factor_of
        if memo is None or memo[0] is not imu:  # a sample is immutable: its identity will do
            memo = self._factor_of = (
                imu,
                gas_factor(self.cfg, imu.pitch_rad, imu.roll_rad, imu.battery_v),
            )
        return memo[1]

    # ----------------------------------------------------------------- thrust model
    def thrust_up(
        self, imu: ImuSample, *, flying: bool, gas_counts: int, integral_gas: float
    ) -> float | None:
        """The thrust model's vertical acceleration for this sample (m/s^2, up), or None.

        ``g·(gas_lagged / hover_now - 1)`` with the gas flown (the last command) through the
        motors' lag and the hover gas now (learned, else the altitude loop's view, scaled
        like the feed-forward). None unless flying with control and a gas the model can
        describe (above a third of the hover gas): then the accelerometer alone.
        """
        t_ns = imu.t_ns
        prev = self._gas_lagged
        if prev is None or not flying or gas_counts <= 0:
            self._gas_lagged = (t_ns, float(gas_counts))
            if not flying or gas_counts <= 0:
                return None
        else:
            dt_s = (t_ns - prev[0]) / NS_PER_S
            dt_s = dt_s if dt_s > 0.0 else 0.0  # max(0.0, dt_s)
            if self._lag[0] != dt_s:  # one exp per new interval
                self._lag = (dt_s, 1.0 - math.exp(-dt_s / THRUST_TAU_S))
            self._gas_lagged = (t_ns, prev[1] + (gas_counts - prev[1]) * self._lag[1])
        factor = self._gas_factor(imu)
        if factor is None:
            return None
        hover_now = self.hover_gas(factor, integral_gas) * factor
        gas = self._gas_lagged[1]
        if not (hover_now > 0.0 and gas > hover_now / 3.0):
            return None
        return self.cfg.mk.g_mps2 * (gas / hover_now - 1.0)

    # ----------------------------------------------------------------- learning
    def observe(
        self,
        imu: ImuSample,
        est: Estimate,
        *,
        hold_s: float | None,
        quiet: bool,
        gas_counts: int,
        on_floor: bool = False,
    ) -> None:
        """Learn from this (finite, fresh) sample if the flight is steady or at rest.

        Args:
            imu: the sample the estimator just took.
            est: the estimate after it.
            hold_s: seconds since HOLD began (None: not in HOLD).
            quiet: no failsafe beyond a warning, and we have control.
            gas_counts: the gas the FC flew during this sample (the last command).
            on_floor: before take-off, motors off: the biases are learned at rest.
        """
        acc_l = self.estimator.last_acc_level
        factor = self._gas_factor(imu)
        if acc_l is None or factor is None:
            return
        at_rest = on_floor and gas_counts == 0 and est.height_valid
        if hold_s is not None:
            self._observe_hold_gas(imu, factor, quiet=quiet, gas_counts=gas_counts)
        steady = (
            hold_s is not None
            and hold_s >= LEARN_AFTER_HOLD_S
            and est.pose_valid
            and est.height_valid
            and quiet
            and abs(est.vz_up_mps) < LEARN_MAX_VZ_MPS
        )
        f_body = (imu.acc_x_mps2, imu.acc_y_mps2, imu.acc_z_mps2)
        residual = self.estimator.last_acc_residual
        noise_source = None
        if residual is not None and residual[2] is not None:
            noise_source = (residual[0], residual[1], residual[2])
        self.learner.observe(
            imu.t_ns,
            acc_level_mps2=acc_l,
            f_body_mps2=f_body,
            gas_factor=factor,
            gas_counts=float(gas_counts),
            steady=steady,
            at_rest=at_rest,
            noise_source_mps2=noise_source,
        )
        self._apply_learned(steady=steady, at_rest=at_rest)

    def _observe_hold_gas(
        self, imu: ImuSample, factor: float, *, quiet: bool, gas_counts: int
    ) -> None:
        """In HOLD, before the hover gas is learned: track the gas flown as a hover gas.

        Only while quiet, with gas, and on a fresh hat height (:data:`RECENT_HAT_FRESH_S`),
        and leaving out jolts (:data:`RECENT_MAX_ACC_G`).
        """
        lh = self._laser_height
        if (
            self.learner.learned().hover_gas_counts is None  # once learned: not needed
            and quiet
            and gas_counts > 0
            and lh is not None
            and (imu.t_ns - lh[0]) / NS_PER_S <= RECENT_HAT_FRESH_S
        ):
            a_up = self.acc_up(imu, True)
            gas = self._gas_lagged[1] if self._gas_lagged is not None else float(gas_counts)
            if a_up is not None and abs(a_up) < RECENT_MAX_ACC_G * self.cfg.mk.g_mps2:
                # gas = hover·factor·(1 + a/g): the loop's gas is the hover gas only on average
                # over a level flight; this holds while it climbs or sinks too
                self._track_recent_hover(
                    imu.t_ns, gas / (factor * (1.0 + a_up / self.cfg.mk.g_mps2))
                )

    def _apply_learned(self, *, steady: bool, at_rest: bool) -> None:
        """Give the estimator what the learner has new: vibration and accelerometer biases."""
        learned = self.learner.learned()
        if learned is self._applied:
            return  # nothing new (the learner refreshes every few samples)
        self._applied = learned
        if steady and learned.vibration_mps2 is not None:
            self.estimator.set_acc_noise(learned.vibration_mps2)
        if at_rest and learned.bias_level_mps2 is not None:  # on the floor: take it at once
            self.estimator.set_acc_bias(learned.bias_level_mps2)
        elif steady and learned.bias_level_mps2 is not None:
            # towards the learned value at a bounded rate: a step in the bias would be a
            # step in the filter's velocity (eq 15-17), i.e. a kick to the loops
            step = BIAS_RATE_MPS3 * LEARN_STEP_S * UPDATE_EVERY
            now = self.estimator.acc_bias_level
            self.estimator.set_acc_bias(
                tuple(  # type: ignore[arg-type]
                    b + max(-step, min(step, target - b))
                    for b, target in zip(now, learned.bias_level_mps2, strict=True)
                )
            )

    def _track_recent_hover(self, t_ns: int, hover_counts: float) -> None:
        """The gas flown in HOLD, normalised like the feed-forward, averaged over ~1 s."""
        last, self._recent_t_ns = self._recent_t_ns, t_ns
        if last is None or not math.isfinite(hover_counts):
            return
        dt_s = min(max(0.0, (t_ns - last) / NS_PER_S), RECENT_MAX_GAP_S)
        if dt_s > 0.0:
            self._recent_hover.add(hover_counts, dt_s)

    def hat_height(self, arrival_ns: int, scan_t_ns: int, height_m: float | None) -> None:
        """A hat height arrived (None or NaN: none): the descent may fly on it."""
        if height_m is not None and math.isfinite(height_m):
            self._laser_height = (arrival_ns, scan_t_ns, height_m)

    def learned(self) -> dict[str, object]:
        """What the flight learned of its airframe and how it used it (``flight.json``)."""
        out: dict[str, object] = self.learner.learned().as_dict()
        out["bias_used_mps2"] = [round(v, 4) for v in self.estimator.acc_bias_level]
        out["filter"] = self.cfg.estimation.filter
        if self.cfg.estimation.filter == "kalman":  # its trust in the accelerometers
            out["acc_noise_used_mps2"] = [round(v, 4) for v in self.estimator.acc_noise_used]
        else:
            out["filter_gains_per_s"] = [round(v, 3) for v in self.estimator.filter_gains]
        out["descents"] = list(self.log)
        return out

    # ----------------------------------------------------------------- without the hat
    def acc_up(self, imu: ImuSample, fresh: bool) -> float | None:
        """This sample's level-frame vertical acceleration, bias removed (m/s^2, up).

        The accelerometers' own (not the model-aided one the estimator integrates): the
        descent detects the floor by what the thrust model cannot know.
        """
        acc_l = self.estimator.last_raw_acc_level
        if not fresh or acc_l is None or not _finite_imu(imu):
            return None
        a_up = self.estimator.acc_bias_level[2] - acc_l[2]
        return a_up if math.isfinite(a_up) else None

    def hover_gas(self, factor: float | None, integral_gas: float) -> float:
        """The gas holding the weight at the hover voltage.

        Learned (:mod:`~mkflight.estimation.learner`, after 5 s of steady HOLD); before
        that the gas flown in HOLD over the last second (a stall early in HOLD); before
        that the altitude loop's view: the configured feed-forward plus ``integral_gas``,
        the loop's inner integral (which takes seconds to find an airframe's 82-115).
        """
        learned = self.learner.learned().hover_gas_counts
        if learned is not None:
            return learned
        recent = self._recent_hover
        if recent.span_s >= RECENT_HOVER_MIN_S:
            return recent.value
        return self.cfg.control.hover_gas + integral_gas / (factor or 1.0)

    def blind_gas(self, battery_v: float, integral_gas: float) -> int:
        """The gas to hold level without data: the hover gas now (counts, within limits)."""
        factor = gas_factor(self.cfg, 0.0, 0.0, battery_v) or 1.0
        gas = self.hover_gas(factor, integral_gas) * factor
        return gas_to_counts(gas if math.isfinite(gas) else 0.0, self.cfg.control.gas_max)

    def _factor(self, imu: ImuSample) -> float | None:
        """The feed-forward factor of a level descent (None: no battery reading).

        The tilt it corrects for is at most the tilt the controllers may command: a wrong
        attitude must not become gas.
        """
        lim = self.cfg.control.max_tilt_rad
        pitch, roll = imu.pitch_rad, imu.roll_rad  # NaN stays NaN (then: level)
        if abs(pitch) > lim:
            pitch = math.copysign(lim, pitch)
        if abs(roll) > lim:
            roll = math.copysign(lim, roll)
        factor = gas_factor(self.cfg, pitch, roll, imu.battery_v)
        if factor is None:  # no attitude (NaN): level, as commanded
            factor = gas_factor(self.cfg, 0.0, 0.0, imu.battery_v)
        return factor

    def without_hat(
        self,
        imu: ImuSample,
        est: Estimate,
        *,
        fresh: bool,
        flying: bool,
        gas_counts: int,
        integral_gas: float,
    ) -> Estimate:
        """``est``, with height and vz from the model-aided channel while the hat is gone."""
        if est.height_valid or not flying:
            self.vertical = None
            return est
        factor = self._factor(imu)
        if self.vertical is None:
            vib = self.learner.learned().vibration_mps2
            self.vertical = VerticalDeadReckoning(
                t_ns=imu.t_ns,
                height_m=est.height_m,
                vz_up_mps=est.vz_up_mps,
                hover_gas_counts=self.hover_gas(factor, integral_gas),
                gas_counts=float(gas_counts),
                noise_mps2=None if vib is None else vib[2],
                g_mps2=self.cfg.mk.g_mps2,
            )
        v = self.vertical.step(
            imu.t_ns,
            gas_counts=float(gas_counts),
            gas_factor=1.0 if factor is None else factor,
            acc_up_mps2=self.acc_up(imu, fresh),
        )
        return msgspec.structs.replace(est, height_m=v.height_m, vz_up_mps=v.vz_up_mps)

    def _hat_model_vz(
        self,
        t_ns: int,
        imu: ImuSample,
        est: Estimate,
        hat: tuple[int, float] | None,
        gas_counts: int,
    ) -> float | None:
        """Without usable FC samples: the thrust model's speed, corrected by each hat height.

        The hat's own rate is ~0.1 s old: too late for the descent's PI.
        """
        if hat is None:
            return None
        factor = self._factor(imu)
        gas = float(gas_counts)
        if self._hat_model is None:
            self._hat_model = VerticalDeadReckoning(
                t_ns=t_ns,
                height_m=hat[1],
                vz_up_mps=est.vz_up_mps,
                hover_gas_counts=self.hover_gas(factor, 0.0),
                gas_counts=gas,
                noise_mps2=None,
                g_mps2=self.cfg.mk.g_mps2,
            )
        v = self._hat_model
        v.step(t_ns, gas_counts=gas, gas_factor=factor or 1.0, acc_up_mps2=None)
        if self._hat_used_ns != hat[0]:
            self._hat_used_ns = hat[0]
            v.correct_height(hat[1], age_s=(t_ns - hat[0]) / NS_PER_S)
        return v.state.vz_up_mps

    def descend(
        self,
        t_ns: int,
        imu: ImuSample,
        est: Estimate,
        *,
        inertial: bool,
        integral_gas: float,
        gas_counts: int,
        since: str,
    ) -> DescentOutput:
        """One step of a landing without the hat height (:mod:`mkflight.control.descent`).

        Args:
            t_ns: this step's time.
            imu: this step's sample.
            est: the estimate (height and vz from :meth:`without_hat` when the hat is gone).
            inertial: the FC's samples are good; otherwise the hat alone, else nothing.
            integral_gas: the altitude loop's inner integral (the hover gas if not learned).
            gas_counts: the gas the FC flew during this sample (the last command).
            since: the flight time now, for the log (``t+12.35s``).
        """
        factor = self._factor(imu)
        if self.descent is None:
            vib = self.learner.learned().vibration_mps2
            params = DescentParams.from_config(self.cfg.control, self.cfg.mk.g_mps2)
            if self.learner.learned().hover_gas_counts is None:
                # the thrust model's hover gas is a guess (module docstring): a slower
                # descent leaves room for its error in the touchdown
                params = replace(params, descent_mps=params.descent_mps * UNLEARNED_DESCENT)
            self.descent = Descent(
                params,
                t_ns=t_ns,
                vz_up_mps=est.vz_up_mps if inertial else math.nan,
                hover_gas_counts=self.hover_gas(factor, integral_gas),
                noise_mps2=None if vib is None else vib[2],
            )
            self.log.append(f"{since} start")
        d = self.descent
        hat: tuple[int, float] | None = None
        lh = self._laser_height
        if lh is not None and (t_ns - lh[0]) / NS_PER_S <= LASER_HEIGHT_FRESH_S:
            hat = (lh[1], lh[2])
        vz = est.vz_up_mps if inertial else self._hat_model_vz(t_ns, imu, est, hat, gas_counts)
        mode_before = d.mode
        out = d.step(
            t_ns,
            gas_factor=1.0 if factor is None else factor,
            vz_up_mps=vz,
            height_m=est.height_m if inertial else None,
            acc_up_mps2=self.acc_up(imu, inertial),
            hat=hat,
        )
        if self.vertical is not None:
            if out.stopped:
                self.vertical.rest()
            if out.vz_reset_mps is not None:
                self.vertical.set_velocity(out.vz_reset_mps)
        if d.mode is not mode_before or out.note:
            self.log.append(f"{since} {d.mode.value}: {out.note or 'mode'}")
        return out
