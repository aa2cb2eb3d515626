"""``mkflight tune LOGDIR``: identify the airframe of a flight and tune a config for it."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import TYPE_CHECKING

from mkflight.commands.args import DOCUMENT, Command, Subparsers, add_json, config_options

if TYPE_CHECKING:
    from mkflight.analysis.attitude_fit import AttitudeFit
    from mkflight.analysis.identify import Identification
    from mkflight.analysis.tune import Tuned


def cmd_tune(
    *,
    log_dir: str,
    config_path: str | None,
    overrides: list[str],
    write_config: str | None,
    as_json: bool,
) -> int:
    """Print what a flight identifies of its airframe and the config overrides for it.

    Args:
        log_dir: the flight folder (``mkflight.logs.load_flight``).
        config_path: the base configuration (None: the built-in defaults).
        overrides: ``--set`` items applied to the base.
        write_config: write the tuned configuration (complete YAML) here. An existing
            file is refused unless it is ``config_path`` itself (tuning it in place).
        as_json: print one object: ``identification``, ``overrides``, ``tuned`` (key,
            old, new, why), ``base``, ``written``.

    Raises:
        ConfigError: the base config is invalid, or the target exists (exit 2).
        ReplayError: not a flight folder, or a malformed log (exit 1).
        IdentificationError: no HOLD phase or too little of it (exit 1).
    """
    from mkflight.analysis.identify import identify_flight
    from mkflight.analysis.tune import check_target, tuning, write_tuned_config
    from mkflight.config import load_config

    base_cfg = load_config(config_path, overrides)  # usage errors before the work
    if write_config is not None:
        check_target(write_config, config_path)
    ident = identify_flight(log_dir)
    tuned = tuning(ident, base_cfg)
    written = None
    if write_config is not None:
        now = datetime.now(UTC)
        write_tuned_config(
            write_config, ident, base_path=config_path, base_overrides=overrides, now=now
        )
        written = write_config
    base = "built-in defaults" if config_path is None else config_path
    if as_json:
        out = {
            "identification": ident.as_dict(),
            "overrides": [t.override for t in tuned],
            "tuned": [{"key": t.key, "old": t.old, "new": t.new, "why": t.why} for t in tuned],
            "base": base,
            "written": written,
        }
        print(json.dumps(out))
        return 0
    _print_identification(ident)
    _print_tuned(tuned, base)
    if written is not None:
        print(f"wrote the tuned configuration to {written}")
    return 0


def _fit_row(fit: AttitudeFit, used: bool) -> str:
    row = (
        f"  {fit.axis:<6}{fit.delay_s:8.3f}{fit.tau_s:8.3f}{fit.response_s:8.3f}"
        f"{fit.gain:8.3f}{fit.r2:8.3f}{fit.residual_rad:10.4f}{fit.samples:6d}"
        f"{fit.excitation_rad:10.4f}"
    )
    if fit.poor:
        return f"{row}  poor: {fit.poor}"
    return row + ("  <- used" if used else "")


def _print_identification(ident: Identification) -> None:
    print(f"airframe of {ident.log_dir}: HOLD {ident.hold_s:.1f} s ({ident.hold_steps} steps)")
    print("attitude response (commanded angle -> FC angle: delay + first-order lag, §F):")
    print(
        f"  {'axis':<6}{'delay s':>8}{'lag s':>8}{'sum s':>8}{'gain K':>8}{'R²':>8}"
        f"{'resid rad':>10}{'rows':>6}{'cmd std':>10}"
    )
    for fit in (ident.pitch, ident.roll, ident.attitude):
        print(_fit_row(fit, fit is ident.attitude))
    if ident.attitude.good:
        print(
            f"  the FC's counts per radian: {ident.fc_counts_per_rad:.1f} (the flight's "
            f"{ident.flight_counts_per_rad:g} / K)"
        )
    print(
        f"hover gas: {ident.hover_gas_counts:.1f} counts at {ident.hover_voltage_v:g} V, level "
        f"({ident.hover_gas_steps} steady HOLD steps, battery {ident.battery_v:.2f} V)"
    )
    vx, vy, vz = ident.vibration_mps2
    cx, cy, cz = ident.vibration_counts
    raw_z = ident.vibration_z_raw_mps2
    print(
        f"vibration: x {vx:.3f}  y {vy:.3f}  z {vz:.3f} m/s²  (AccNick {cx:.1f}, AccRoll "
        f"{cy:.1f}, AccZ {cz:.1f} counts; AccZ with the gas's share {raw_z:.3f})"
    )
    bx, by, bz = ident.acc_bias_level_mps2
    print(f"mean level-frame acceleration in HOLD: x {bx:.3f}  y {by:.3f}  z {bz:.3f} m/s²")
    for w in ident.warnings:
        print(f"note: {w}")


def _print_tuned(tuned: list[Tuned], base: str) -> None:
    if not tuned:
        print(f"overrides for {base}: none (the data carry none)")
        return
    print(f"overrides for {base}:")
    for t in tuned:
        print(f"  {t.override:<42} was {t.old:<8g} {t.why}")


def add_parser(subparsers: Subparsers) -> None:
    """``tune LOGDIR``."""
    tune = subparsers.add_parser(
        "tune",
        parents=[config_options()],
        help="identify a flight's airframe and write a config tuned for it",
        description="From the HOLD phase of a flight folder: the attitude response per axis "
        f"(delay + first-order lag and gain, §F of {DOCUMENT}), the hover gas, the "
        "accelerometers' vibration and biases; then the overrides of the base config "
        "(--config, --set) for that airframe by a documented rule (mkflight.analysis.tune).",
    )
    tune.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    tune.add_argument(
        "--write-config",
        metavar="F",
        help="write the tuned configuration (all keys) to the new file F; an existing F is "
        "refused unless it is the --config file itself",
    )
    add_json(tune)
    tune.set_defaults(func=Command(cmd_tune))
