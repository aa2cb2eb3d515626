"""Identify the airframe from a recorded flight: attitude response, hover gas, vibration, biases.

What a flight folder (:func:`mkflight.logs.load_flight`) tells of the vehicle it flew, for
``mkflight tune`` (:mod:`mkflight.analysis.tune`). Everything is read from the HOLD phase
of the ``step`` events and the TABLE IV rows of the same steps (row ``index`` k is the
k-th step), with the flight's own configuration (``flight.json``'s ``config``; the
defaults when the folder has none). § and TABLE: the 2011 QUT CyPhy MikroKopter
documentation.

* **Attitude response** per axis (§F): the commanded angle is
  ``counts / (mk.signs.<axis> * mk.counts_per_rad)`` (``ControlPitch`` for pitch,
  ``ControlRoll`` for roll), held from its step's time until the next step (zero-order
  hold: the FC takes the command a few ms after each DebugOut; that small latency ends up
  in the delay). The model is a pure delay ``d`` and a first-order lag ``tau`` with a gain
  ``K`` and a constant offset ``b`` (the FC's horizon bias)::

      tau * x'(t) + x(t) = u(t - d),      angle(t) = K * x(t) + b

  simulated exactly between the steps' real (jittered) times from the first row of the
  flight, at rest, and fitted on the HOLD rows: for every ``(d, tau)`` of a grid (d 0 to
  0.3 s by 5 ms, tau 0.02 to 0.4 s by 5 ms) ``K`` and ``b`` come from linear least squares,
  and the grid point with the smallest residual wins. ``K`` is the FC's angle per angle the
  flight believed it commanded: an FC that answers 100 counts per radian flown with
  ``mk.counts_per_rad`` 120 has ``K`` = 1.2, and its own counts per radian are
  ``mk.counts_per_rad / K``. Pitch and roll are fitted each on its own and together
  (one ``d``, ``tau`` and ``K``, an offset each).
* **Hover gas**: the gas that holds the weight at ``control.hover_voltage_v`` and level
  attitude, in the flight's own feed-forward model (``gas_ff = hover_gas *
  (hover_voltage_v / battery_v) / (cos θ cos φ)``, §K, §M): the median over the
  steady HOLD steps (``|vz_up_mps|`` ≤ 0.1 m/s) of ``gas * (battery_v / hover_voltage_v) *
  cos θ cos φ``.
* **Vibration** per accelerometer axis: the standard deviation of successive differences
  over √2 (white noise survives differencing, the slow flight accelerations do not), in
  m/s² and in the MK's counts with the flight's calibration (``mk.acc_*``). On AccZ the
  thrust's answer to the gas commands (the altitude loop's own doing) is taken out first
  by least squares on the previous two steps' gas; without that, a flight whose gas
  jitters would read as a vibrating one.
* **Accelerometer biases in the level frame**: the mean of ``a = R_y(θ) R_x(φ) f + (0, 0,
  g)`` (SPEC §3) over HOLD, which averages 0 for a vehicle that holds its position; it
  includes the FC's horizon error (a tilt the FC does not report turns gravity into a
  horizontal acceleration).

A fit is marked poor, not trusted, when the data cannot carry it: fewer than
:data:`MIN_FIT_SAMPLES` HOLD rows, a commanded angle that barely moves
(:data:`MIN_EXCITATION_RAD`: a calm hover), an R² below :data:`MIN_R2`, a gain outside
:data:`GAIN_LIMITS` or a best point on the far edge of the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from mkflight.analysis.attitude_fit import AttitudeFit, fit_attitude
from mkflight.config import Config, config_from_dict
from mkflight.errors import ConfigError, MkflightError
from mkflight.frames import level_acceleration
from mkflight.logs.flight import FlightData, load_flight
from mkflight.logs.flight_json import json_safe

__all__ = [
    "MIN_HOLD_STEPS",
    "AttitudeFit",
    "Identification",
    "IdentificationError",
    "identify",
    "identify_flight",
]

FloatArray = npt.NDArray[np.float64]

MIN_HOLD_STEPS: Final = 40
"""Fewer HOLD steps than this (2 s) is too little data for anything: an error."""
STEADY_VZ_MPS: Final = 0.1
"""Steps climbing or sinking faster than this do not count for the hover gas."""
MIN_GAS_STEPS: Final = 20
"""The hover gas needs this many steady HOLD steps."""
_HOLD: Final = "HOLD"
_AXES: Final = (("pitch", "ControlPitch", "AnglePitch"), ("roll", "ControlRoll", "AngleRoll"))


class IdentificationError(MkflightError):
    """A flight folder cannot be identified: no HOLD phase, or too little of it (exit 1)."""


@dataclass(frozen=True, slots=True)
class Identification:
    """What one flight tells of its airframe (module docstring: the methods).

    Attributes:
        log_dir: the flight folder.
        hold_s: the HOLD phase's duration.
        hold_steps: its steps.
        pitch: the pitch axis's attitude fit.
        roll: the roll axis's.
        attitude: both axes together (the one the tuning uses).
        flight_counts_per_rad: ``mk.counts_per_rad`` the flight flew with.
        fc_counts_per_rad: the FC's own counts per radian (flight's / K of ``attitude``;
            NaN when that fit is poor).
        hover_gas_counts: the gas holding the weight at ``hover_voltage_v``, level (NaN:
            too few steady steps).
        hover_voltage_v: the flight's ``control.hover_voltage_v`` it is normalised to.
        hover_gas_steps: the steady HOLD steps it comes from.
        battery_v: the median battery reading over those steps.
        vibration_mps2: accelerometer noise x, y, z (body, m/s²).
        vibration_counts: the same in MK counts (AccNick, AccRoll, AccZ).
        vibration_z_raw_mps2: AccZ's before the gas command's share is taken out.
        acc_bias_level_mps2: the mean level-frame acceleration x, y, z (z down) in HOLD.
        warnings: what was assumed or left out.
    """

    log_dir: str
    hold_s: float
    hold_steps: int
    pitch: AttitudeFit
    roll: AttitudeFit
    attitude: AttitudeFit
    flight_counts_per_rad: float
    fc_counts_per_rad: float
    hover_gas_counts: float
    hover_voltage_v: float
    hover_gas_steps: int
    battery_v: float
    vibration_mps2: tuple[float, float, float]
    vibration_counts: tuple[float, float, float]
    vibration_z_raw_mps2: float
    acc_bias_level_mps2: tuple[float, float, float]
    warnings: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """Plain values (NaN as None) for ``--json`` and reports."""
        out = {
            "log_dir": self.log_dir,
            "hold_s": round(self.hold_s, 3),
            "hold_steps": self.hold_steps,
            "pitch": self.pitch.as_dict(),
            "roll": self.roll.as_dict(),
            "attitude": self.attitude.as_dict(),
            "flight_counts_per_rad": round(self.flight_counts_per_rad, 3),
            "fc_counts_per_rad": round(self.fc_counts_per_rad, 2),
            "hover_gas_counts": round(self.hover_gas_counts, 2),
            "hover_voltage_v": round(self.hover_voltage_v, 3),
            "hover_gas_steps": self.hover_gas_steps,
            "battery_v": round(self.battery_v, 3),
            "vibration_mps2": [round(v, 4) for v in self.vibration_mps2],
            "vibration_counts": [round(v, 2) for v in self.vibration_counts],
            "vibration_z_raw_mps2": round(self.vibration_z_raw_mps2, 4),
            "acc_bias_level_mps2": [round(v, 4) for v in self.acc_bias_level_mps2],
            "warnings": list(self.warnings),
        }
        result: dict[str, Any] = json_safe(out)
        return result


def identify_flight(log_dir: str | Path) -> Identification:
    """Identify the airframe of the flight folder ``log_dir`` (module docstring).

    Raises:
        ReplayError: not a flight folder, or a malformed log (names the file and line).
        IdentificationError: no step events, no HOLD phase or fewer than
            :data:`MIN_HOLD_STEPS` HOLD steps.
    """
    return identify(load_flight(log_dir))


def _flight_config(flight: FlightData, warnings: list[str]) -> Config:
    """The configuration the flight flew with (``flight.json``), else the defaults."""
    if flight.info is None:
        warnings.append("no flight.json: the default configuration assumed")
        return Config()
    source = str(flight.path / "flight.json")
    data = flight.info.config
    try:
        return config_from_dict(data, source)
    except ConfigError as err:
        problem = str(err)
    if isinstance(data, dict):  # another version's config: what this analysis reads
        try:
            cfg = config_from_dict({k: data[k] for k in ("mk", "control") if k in data}, source)
        except ConfigError:
            pass
        else:
            warnings.append(f"flight.json's config: only mk and control read ({problem})")
            return cfg
    warnings.append(f"flight.json's config not usable ({problem}): the defaults assumed")
    return Config()


def identify(flight: FlightData) -> Identification:
    """Identify the airframe from a loaded flight (:func:`identify_flight`)."""
    warnings: list[str] = []
    cfg = _flight_config(flight, warnings)
    imu, steps = flight.imu, flight.steps
    if len(steps) == 0:
        msg = f"{flight.path}: no step events (events.jsonl): cannot find the HOLD phase"
        raise IdentificationError(msg)
    if len(imu) == 0:
        msg = f"{flight.path}: no TABLE IV rows (imu_50ms.log): nothing to identify"
        raise IdentificationError(msg)
    # The k-th step event is the TABLE IV row of index k (load_flight's time base).
    index = imu["index"].astype(np.int64) - 1
    joined = (index >= 0) & (index < len(steps)) & np.isfinite(flight.imu_t_s)
    imu, t_s, index = imu[joined], flight.imu_t_s[joined], index[joined]
    order = np.argsort(t_s, kind="stable")
    imu, t_s, index = imu[order], t_s[order], index[order]
    keep = np.concatenate(([True], np.diff(t_s) > 0))  # strictly increasing times
    imu, t_s, index = imu[keep], t_s[keep], index[keep]
    row_steps = steps[index]
    hold = row_steps["phase"] == _HOLD
    n_hold = int(np.count_nonzero(hold))
    if n_hold == 0:
        msg = f"{flight.path}: no HOLD phase in this flight: nothing to identify"
        raise IdentificationError(msg)
    if n_hold < MIN_HOLD_STEPS:
        msg = (
            f"{flight.path}: only {n_hold} HOLD steps, too little data to identify "
            f"(need at least {MIN_HOLD_STEPS})"
        )
        raise IdentificationError(msg)
    hold_s = float(t_s[hold][-1] - t_s[hold][0])

    cmd = np.empty((2, len(imu)))
    angle = np.empty((2, len(imu)))
    signs = (cfg.mk.signs.nick, cfg.mk.signs.roll)
    for a, (_, control, measured) in enumerate(_AXES):
        cmd[a] = imu[control].astype(np.float64) / (signs[a] * cfg.mk.counts_per_rad)
        angle[a] = imu[measured].astype(np.float64)
    pitch, roll, both = fit_attitude(t_s, cmd, angle, hold)
    fc_cpr = cfg.mk.counts_per_rad / both.gain if both.good else math.nan

    gas, gas_n, battery = _hover_gas(row_steps, imu, hold, cfg.control.hover_voltage_v)
    if gas_n < MIN_GAS_STEPS:
        warnings.append(f"hover gas: only {gas_n} steady HOLD steps (need {MIN_GAS_STEPS})")
        gas = math.nan
    vib, vib_z_raw = _vibration(imu, row_steps["gas_counts"].astype(np.float64), hold, index)
    k = cfg.mk
    scales = (k.acc_nick_counts_per_g / k.g_mps2, k.acc_roll_counts_per_g / k.g_mps2)
    vib_counts = (vib[0] * scales[0], vib[1] * scales[1], vib[2] * k.acc_z_counts_per_mps2)
    return Identification(
        log_dir=str(flight.path),
        hold_s=hold_s,
        hold_steps=n_hold,
        pitch=pitch,
        roll=roll,
        attitude=both,
        flight_counts_per_rad=cfg.mk.counts_per_rad,
        fc_counts_per_rad=fc_cpr,
        hover_gas_counts=gas,
        hover_voltage_v=cfg.control.hover_voltage_v,
        hover_gas_steps=gas_n,
        battery_v=battery,
        vibration_mps2=vib,
        vibration_counts=vib_counts,
        vibration_z_raw_mps2=vib_z_raw,
        acc_bias_level_mps2=_level_bias(imu[hold], k.g_mps2),
        warnings=(*flight.warnings, *warnings),
    )


def _hover_gas(
    steps: Any, imu: Any, hold: npt.NDArray[np.bool_], hover_voltage_v: float
) -> tuple[float, int, float]:
    """(normalised hover gas, steady steps, their median battery voltage)."""
    gas = steps["gas_counts"].astype(np.float64)
    volts = steps["battery_v"].astype(np.float64)
    vz = steps["vz_up_mps"].astype(np.float64)
    tilt = np.cos(imu["AnglePitch"].astype(np.float64)) * np.cos(
        imu["AngleRoll"].astype(np.float64)
    )
    steady = hold & np.isfinite(gas) & (volts > 0) & (np.abs(vz) <= STEADY_VZ_MPS)
    steady &= np.isfinite(tilt)
    n = int(np.count_nonzero(steady))
    if n == 0:
        return math.nan, 0, math.nan
    held = gas[steady] * (volts[steady] / hover_voltage_v) * tilt[steady]
    return float(np.median(held)), n, float(np.median(volts[steady]))


def _vibration(
    imu: Any, gas: FloatArray, hold: npt.NDArray[np.bool_], index: npt.NDArray[np.int64]
) -> tuple[tuple[float, float, float], float]:
    """The accelerometer noise per axis over consecutive HOLD rows (m/s²), and AccZ's raw.

    The std of successive differences / √2: white vibration survives differencing, slow
    flight accelerations do not. AccZ also carries the thrust's answer to each gas
    command (a 5-count step is ~0.5 m/s² within a step): that part, fitted by least
    squares on the gas of the two previous steps, is taken out first. The second value
    is AccZ's figure without that correction.
    """
    after = np.concatenate(([False], np.diff(index) == 1))  # row j follows row j-1
    pairs = hold & after & np.roll(hold, 1)
    triples = pairs & np.roll(pairs, 1)
    out: list[float] = []
    for name in ("AccX", "AccY", "AccZ"):
        d = np.diff(imu[name].astype(np.float64), prepend=math.nan)[pairs]
        out.append(_diff_noise(d))
    acc_z = imu["AccZ"].astype(np.float64)
    rows = np.flatnonzero(triples & np.isfinite(acc_z))
    design = np.column_stack([gas[rows - 1], gas[rows - 2], np.ones(len(rows))])
    usable = np.all(np.isfinite(design), axis=1)
    rows, design = rows[usable], design[usable]
    z = out[2]
    if len(rows) > 10:
        coef, *_ = np.linalg.lstsq(design, acc_z[rows], rcond=None)
        residual = np.full(len(acc_z), math.nan)
        residual[rows] = acc_z[rows] - design @ coef
        z = _diff_noise(np.diff(residual, prepend=math.nan)[pairs])
    return (out[0], out[1], z), out[2]


def _diff_noise(differences: FloatArray) -> float:
    d = differences[np.isfinite(differences)]
    return float(np.std(d) / math.sqrt(2.0)) if len(d) > 1 else math.nan


def _level_bias(rows: Any, g_mps2: float) -> tuple[float, float, float]:
    """The mean level-frame acceleration (SPEC §3) over ``rows``."""
    acc = [
        level_acceleration(fx, fy, fz, p, r, g_mps2)
        for fx, fy, fz, p, r in zip(
            rows["AccX"].tolist(),
            rows["AccY"].tolist(),
            rows["AccZ"].tolist(),
            rows["AnglePitch"].tolist(),
            rows["AngleRoll"].tolist(),
            strict=True,
        )
    ]
    a = np.asarray(acc, dtype=np.float64).reshape(-1, 3)
    a = a[np.all(np.isfinite(a), axis=1)]
    if len(a) == 0:
        return math.nan, math.nan, math.nan
    m = a.mean(axis=0)
    return float(m[0]), float(m[1]), float(m[2])
