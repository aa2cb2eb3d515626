"""A configuration for the identified airframe: the tuning rule, and writing the config file.

:func:`tuned_overrides` turns an :class:`~mkflight.analysis.identify.Identification` into
``section.key=value`` items (the ``--set`` syntax of :func:`mkflight.config.load_config`)
by this rule; each item only when the data carry it (a poor attitude fit, a missing hover
gas or vibration leaves its keys as they are):

* ``mk.counts_per_rad`` = the FC's own counts per radian, ``flight's counts_per_rad / K``
  (K: the attitude fit's gain). The position loop's angle is then the angle flown, and the
  gains below mean what they meant on the airframe they were tuned on.
* ``control.hover_gas`` = the identified hover gas, moved from the flight's
  ``hover_voltage_v`` to the config's (the feed-forward is ``hover_gas * hover_voltage_v /
  battery_v``: the product is what matters). The altitude loop's integral no longer has to
  carry the difference, and a blind descent that uses the hover gas starts from the truth.
* **Position and velocity gains by time scaling.** The default gains were tuned on the
  nominal airframe, whose attitude answers in ``T0`` = :data:`NOMINAL_RESPONSE_S` (0.1 s
  delay + 0.1 s lag). An airframe that answers in ``T = d + tau`` is, for the horizontal
  loops, the nominal one with time stretched by ``T / T0`` (the attitude response is the
  only fast dynamics in the loop besides the integrations; drag is slow). A loop keeps its
  damping under a stretch ``s`` when each gain scales with its units: a gain in 1/s by
  ``1/s`` (``kp_xy``, ``kp_vxy``), in 1/s² by ``1/s²`` (``ki_xy``, ``ki_vxy``),
  dimensionless unchanged (``kd_vxy``, ``kd_xy``: not written). But damping is not all:
  gusts want the highest gains the loop's margin allows, and the defaults keep enough
  margin up to ``T_slow`` = :data:`SLOW_RESPONSE_S` (0.3 s). So the stretch applied is

  ========================  =================  ===========================================
  response T                s                  why
  ========================  =================  ===========================================
  T < T0                    T / T0  (< 1)      a faster airframe takes higher gains
  T0 <= T <= T_slow         1                  the defaults' margin suffices; lower gains
                                               would only let the gusts push it further
  T > T_slow                T / T_slow (> 1)   the defaults would ring: scale from T_slow
  ========================  =================  ===========================================

  Measured in ``sim hover`` (60 s, three seeds each, std of x and y, truth) on drawn
  airframes: at T 0.13-0.16 s full scaling cut the std by 15-35 % against the defaults;
  at T 0.25-0.29 s any scaling down made it worse (by 5-50 %), the defaults were best;
  at T 0.32-0.38 s scaling from T_slow cut it by 15-65 % (0.137 -> 0.047 m at 0.375 s),
  better than scaling from T0 would.
  The scaled values are the DEFAULTS' (:data:`REFERENCE`, the gains tuned for ``T0``),
  not the base config's: tuning again from a config this wrote gives the same gains
  instead of scaling twice. Each is then kept within a factor :data:`MAX_GAIN_FACTOR`
  (2.5) of the base config's value (a gain set to 0 stays 0) and within its config range.
* ``estimation.filter_gain_z_per_s`` from the AccZ vibration, with
  ``estimation.filter: complementary`` only (the Kalman filter takes the vibration the
  flight measures as its noise and needs no gain). The vertical complementary filter is
  a steady-state Kalman filter whose gain is ``sqrt(q / r)``: ``q`` the accelerometer's
  noise (variance), ``r`` the laser height rate's. The laser is the same
  on every airframe; the vibration is not. So the gain scales with the noise's standard
  deviation: ``default * noise_z / NOMINAL_NOISE_Z_MPS2``, where the nominal figure is
  what :func:`~mkflight.analysis.identify.identify` measures on a flight of the nominal
  simulated airframe (0.2 m/s² vibration on AccZ). More vibration: more trust in the
  laser's height rate, less of the vibration goes through the vertical velocity into the
  gas. The ratio is kept in :data:`FILTER_GAIN_Z_RATIO_LIMITS` (1 to 1.5): never below
  the default, because the laser's trust also covers what the noise figure cannot see
  (slow motors, a late laser, ground effect); in ``sim hover`` lowering it for quiet
  accelerometers helped one airframe of three and hurt two (z std 0.011 -> 0.019 m). At
  most 1.5: since the vertical channel is model-aided in flight
  (:mod:`mkflight.estimation.tilt_accel`), the vibration reaches it far less.

The constants are module-level so that an envelope run can adjust them.
:func:`write_tuned_config` writes the base configuration with the overrides applied as a
complete YAML file.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Final

import msgspec

import mkflight
from mkflight.analysis.identify import Identification
from mkflight.config import Config, config_to_dict, dump_yaml, load_config
from mkflight.errors import ConfigError

__all__ = [
    "FILTER_GAIN_Z_RATIO_LIMITS",
    "GAIN_TIME_POWERS",
    "MAX_GAIN_FACTOR",
    "NOMINAL_NOISE_Z_MPS2",
    "NOMINAL_RESPONSE_S",
    "REFERENCE",
    "SLOW_RESPONSE_S",
    "Tuned",
    "check_target",
    "time_stretch",
    "tuned_overrides",
    "tuning",
    "write_tuned_config",
]

NOMINAL_RESPONSE_S: Final = 0.2
"""T0: delay + lag of the airframe the default gains were tuned on (SPEC §8: 0.1 + 0.1 s)."""
SLOW_RESPONSE_S: Final = 0.3
"""T_slow: up to this response the default gains keep their margin (not scaled down)."""
GAIN_TIME_POWERS: Final[dict[str, int]] = {"kp_xy": 1, "ki_xy": 2, "kp_vxy": 1, "ki_vxy": 2}
"""``control.<gain>``: the power of 1/s in its unit; it scales by ``s ** -power``."""
MAX_GAIN_FACTOR: Final = 2.5
"""No gain moves more than this factor up or down from the base config's."""
NOMINAL_NOISE_Z_MPS2: Final = 0.21
"""AccZ vibration identified on 30 s flights of the nominal simulated airframe (0.207-0.211;
its AccZ vibration is 0.2 m/s², plus the 1/15.5 m/s² quantisation and the gusts)."""
FILTER_GAIN_Z_RATIO_LIMITS: Final = (1.0, 1.5)
"""``estimation.filter_gain_z_per_s`` / the default's stays in here: never less trust in the
laser than the default's; at most 2.5 times it (10/s: half the laser's rate per step)."""
REFERENCE: Final = Config()
"""The configuration whose gains were tuned for :data:`NOMINAL_RESPONSE_S`: the defaults."""


@dataclass(frozen=True, slots=True)
class Tuned:
    """One key the rule sets: its dotted name, the base config's value, the new one, why."""

    key: str
    old: float
    new: float
    why: str

    @property
    def override(self) -> str:
        """``section.key=value`` for :func:`mkflight.config.load_config`."""
        return f"{self.key}={self.new!r}"


def _range(section: type[msgspec.Struct], name: str) -> tuple[float, float]:
    """The ``Meta`` bounds of a config field (ge/le, or gt/lt treated as closed)."""
    info = msgspec.inspect.type_info(section)
    fields = info.fields if isinstance(info, msgspec.inspect.StructType) else ()
    for f in fields:
        if f.name == name:
            t = f.type
            if isinstance(t, msgspec.inspect.FloatType | msgspec.inspect.IntType):
                lo = t.ge if t.ge is not None else t.gt
                hi = t.le if t.le is not None else t.lt
                return (-math.inf if lo is None else lo, math.inf if hi is None else hi)
            break
    return -math.inf, math.inf


def _clamp(value: float, lo: float, hi: float) -> float:
    return min(max(value, lo), hi)


def time_stretch(response_s: float) -> float:
    """The stretch s the position/velocity gains are scaled by (module docstring's table)."""
    if response_s < NOMINAL_RESPONSE_S:
        return response_s / NOMINAL_RESPONSE_S
    return max(1.0, response_s / SLOW_RESPONSE_S)


def tuning(ident: Identification, cfg: Config) -> list[Tuned]:
    """The keys the rule sets for the airframe of ``ident`` on the base config ``cfg``.

    The module docstring gives the rule and its reasons; a key is left out when its data
    are missing or poor (the attitude fit's ``poor``, NaN hover gas or vibration).
    """
    out: list[Tuned] = []
    fit = ident.attitude
    if fit.good and math.isfinite(ident.fc_counts_per_rad):
        lo, hi = _range(type(cfg.mk), "counts_per_rad")
        cpr = round(_clamp(ident.fc_counts_per_rad, lo, hi), 1)
        why = f"the FC answers {cpr:g} counts/rad (K {fit.gain:.3f}, R² {fit.r2:.3f})"
        out.append(Tuned("mk.counts_per_rad", cfg.mk.counts_per_rad, cpr, why))
        s = time_stretch(fit.response_s)
        for name, power in GAIN_TIME_POWERS.items():
            ref = float(getattr(REFERENCE.control, name))
            base = float(getattr(cfg.control, name))
            value = ref / s**power
            value = _clamp(value, base / MAX_GAIN_FACTOR, base * MAX_GAIN_FACTOR)
            value = _clamp(value, *_range(type(cfg.control), name))
            why = f"default {ref:g} / {s:.3f}^{power} (T {fit.response_s:.3f} s)"
            out.append(Tuned(f"control.{name}", base, round(value, 4), why))
    if math.isfinite(ident.hover_gas_counts):
        gas = ident.hover_gas_counts * ident.hover_voltage_v / cfg.control.hover_voltage_v
        lo, hi = _range(type(cfg.control), "hover_gas")
        gas = round(_clamp(gas, lo, min(hi, cfg.control.gas_max)), 1)
        why = f"holds the weight at {cfg.control.hover_voltage_v:g} V, level"
        out.append(Tuned("control.hover_gas", cfg.control.hover_gas, gas, why))
    noise_z = ident.vibration_mps2[2]
    complementary = cfg.estimation.filter == "complementary"  # the Kalman filter measures it
    if complementary and math.isfinite(noise_z) and noise_z > 0:
        ref = REFERENCE.estimation.filter_gain_z_per_s
        base = cfg.estimation.filter_gain_z_per_s
        k = ref * _clamp(noise_z / NOMINAL_NOISE_Z_MPS2, *FILTER_GAIN_Z_RATIO_LIMITS)
        k = _clamp(k, base / MAX_GAIN_FACTOR, base * MAX_GAIN_FACTOR)
        why = f"default {ref:g} x AccZ noise {noise_z:.3f} / {NOMINAL_NOISE_Z_MPS2} m/s²"
        out.append(Tuned("estimation.filter_gain_z_per_s", base, round(k, 3), why))
    return out


def tuned_overrides(ident: Identification, cfg: Config) -> list[str]:
    """``section.key=value`` items for the airframe of ``ident`` (module docstring: the rule).

    Args:
        ident: what a flight identified (:func:`mkflight.analysis.identify.identify_flight`).
        cfg: the base configuration they apply to (limits are relative to it).
    """
    return [t.override for t in tuning(ident, cfg)]


def _header(ident: Identification, base: str, overrides: list[str], now: datetime) -> str:
    fit = ident.attitude
    lines = [
        f"mkflight {mkflight.__version__} tune: a configuration for the airframe of one flight",
        f"identified from: {ident.log_dir}",
        f"written: {now.isoformat(timespec='seconds')}",
        f"base configuration: {base}",
        f"attitude: delay {fit.delay_s:.3f} s + lag {fit.tau_s:.3f} s, K {fit.gain:.3f}, "
        f"R² {fit.r2:.3f}" + (f" (poor: {fit.poor})" if fit.poor else ""),
        f"FC counts/rad {ident.fc_counts_per_rad:.1f}; hover gas {ident.hover_gas_counts:.1f} "
        f"at {ident.hover_voltage_v:g} V; vibration x y z "
        + " ".join(f"{v:.3f}" for v in ident.vibration_mps2)
        + " m/s²",
        "overrides: " + (" ".join(overrides) if overrides else "none (the data carry none)"),
    ]
    return "".join(f"# {line}\n" for line in lines)


def write_tuned_config(
    path: str | Path,
    ident: Identification,
    *,
    base_path: str | Path | None,
    base_overrides: list[str] | None = None,
    now: datetime,
) -> tuple[Config, list[str]]:
    """Write the base configuration with the tuned overrides as a complete YAML file.

    The base is ``base_path`` (None: the built-in defaults) with ``base_overrides``; the
    file holds every key (``config_to_dict``), a header of comments says what was
    identified, from which folder and when. It is validated by :func:`load_config` before
    it replaces anything, and written atomically (a temporary file in the same folder,
    then a rename). An existing file is refused unless it is ``base_path`` itself
    (re-tuning a config in place; its comments are not kept).

    Returns:
        The configuration written and the overrides applied.

    Raises:
        ConfigError: the base cannot be loaded, the target exists (and is not the base),
            the result is invalid or cannot be written (exit 2).
    """
    target = Path(path)
    base_cfg = load_config(base_path, base_overrides)
    check_target(target, base_path)
    overrides = tuned_overrides(ident, base_cfg)
    tuned = load_config(base_path, [*(base_overrides or []), *overrides])
    base_name = "built-in defaults" if base_path is None else str(base_path)
    if base_overrides:
        base_name += " with --set " + " ".join(base_overrides)
    text = _header(ident, base_name, overrides, now) + dump_yaml(config_to_dict(tuned))
    _replace_atomically(target, text)
    return tuned, overrides


def check_target(path: str | Path, base_path: str | Path | None) -> None:
    """Refuse to write over an existing file other than the base config itself.

    Raises:
        ConfigError: ``path`` exists and is not ``base_path``, or its folder does not exist.
    """
    target = Path(path)
    if target.exists() and not (base_path is not None and _same_file(target, Path(base_path))):
        msg = f"{target}: exists; refusing to overwrite it (only --config's own file may be)"
        raise ConfigError(msg)
    if not target.parent.is_dir():
        msg = f"{target}: no such folder {str(target.parent)!r}"
        raise ConfigError(msg)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:
        return False


def _replace_atomically(target: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``target``, check it loads, rename it."""
    tmp: str | None = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".yaml", dir=target.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        try:
            load_config(tmp)  # what a user's --config will read
        except ConfigError as err:
            msg = f"{target}: the tuned configuration does not load: {err}"
            raise ConfigError(msg) from err
        os.replace(tmp, target)
        tmp = None
    except OSError as err:
        msg = f"{target}: cannot write config file: {err.strerror or err}"
        raise ConfigError(msg) from err
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
