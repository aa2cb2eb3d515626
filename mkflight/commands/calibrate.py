"""``mkflight calibrate acc``: the accelerometer scale factor from a tilt table (§D)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mkflight.commands.args import DOCUMENT, Command, Subparsers, add_json, subcommands
from mkflight.errors import ConfigError

if TYPE_CHECKING:
    from mkflight.analysis.calibrate import AccFit

_KEYS = {"nick": "acc_nick_counts_per_g", "roll": "acc_roll_counts_per_g"}
#: The documented k of each axis: the table it was measured in, and its value (counts/g).
_DOCUMENTED_K = {"nick": ("TABLE I", "606.3"), "roll": ("TABLE II", "603.44")}


def cmd_calibrate_acc(*, file: str, axis: str, as_json: bool, write_config: str | None) -> int:
    """Fit ``counts = -k·sin(angle)`` (eq 7) to FILE and print k, residual and errors.

    Args:
        file: the table of ``angle_deg counts`` rows (format: :mod:`mkflight.analysis.calibrate`).
        axis: ``nick`` (pitch, TABLE I) or ``roll`` (TABLE II): which config key to write.
        as_json: print one object ``{"k_counts_per_g", "residual_rms_counts", "rows"}``.
        write_config: a YAML config file whose ``mk.acc_<axis>_counts_per_g`` is set to k
            (created if missing). Other keys are kept, but the file is re-written by
            :func:`~mkflight.config.dump_yaml`: its comments and formatting are not
            preserved.

    Raises:
        CalibrationInputError: FILE unreadable, a malformed row (naming file and line), no
            rows (exit 1).
        ConfigError: the config file cannot be read, parsed, validated or written (exit 2).
    """
    from mkflight.analysis.calibrate import CalibrationInputError, fit_acc_scale, parse_rows

    if axis not in _KEYS:
        msg = f"axis must be 'nick' or 'roll', got {axis!r}"
        raise ConfigError(msg)
    try:
        text = Path(file).read_text(encoding="utf-8")
    except OSError as err:
        msg = f"{file}: cannot read calibration table: {err.strerror or err}"
        raise CalibrationInputError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{file}: not UTF-8 text (byte {err.start}): {err.reason}"
        raise CalibrationInputError(msg) from err
    fit = fit_acc_scale(parse_rows(text, file), file)
    if write_config is not None:
        _write_k(write_config, _KEYS[axis], fit.k_counts_per_g)
    if as_json:
        print(
            json.dumps(
                {
                    "k_counts_per_g": fit.k_counts_per_g,
                    "residual_rms_counts": fit.residual_rms_counts,
                    "rows": len(fit.rows),
                }
            )
        )
        return 0
    _print_fit(fit, axis, file)
    if write_config is not None:
        print(f"wrote mk.{_KEYS[axis]} = {round(fit.k_counts_per_g, 3)} to {write_config}")
    return 0


def _print_fit(fit: AccFit, axis: str, file: str) -> None:
    table, k = _DOCUMENTED_K[axis]
    print(
        f"acc {axis}: k = {fit.k_counts_per_g:.3f} counts/g  "
        f"({table}: {k}; model counts = -k*sin(angle), eq 7)"
    )
    print(f"residual RMS {fit.residual_rms_counts:.2f} counts over {len(fit.rows)} rows of {file}")
    print(f"{'line':>6} {'angle_deg':>10} {'counts':>10} {'fit':>10} {'error':>8}")
    for row, error in zip(fit.rows, fit.errors_counts, strict=True):
        print(
            f"{row.line:>6} {row.angle_deg:>10.2f} {row.counts:>10.2f} "
            f"{fit.fitted_counts(row):>10.2f} {error:>8.2f}"
        )


def _write_k(path: str, key: str, k_counts_per_g: float) -> None:
    """Set ``mk.<key>`` in the YAML file ``path``, keep the other keys, validate, then write.

    The file is read by :func:`~mkflight.config.read_yaml`, as ``--config`` reads it (a
    gain written ``1e-4`` is a number to both), and written back by
    :func:`~mkflight.config.dump_yaml`, which it reads back unchanged. Comments are not
    preserved. The file is replaced atomically, and only if the result is a valid
    configuration.
    """
    import os
    import tempfile

    from mkflight.config import config_from_dict, dump_yaml, read_yaml

    target = Path(path)
    data: dict[str, Any] = read_yaml(path) if target.exists() else {}
    mk = data.setdefault("mk", {})
    if not isinstance(mk, dict):
        msg = f"{path}: mk: must be a mapping of keys"
        raise ConfigError(msg)
    mk[key] = round(k_counts_per_g, 3)
    config_from_dict(data, path)
    text = dump_yaml(data)
    tmp: str | None = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp, target)
    except OSError as err:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        msg = f"{path}: cannot write config file: {err.strerror or err}"
        raise ConfigError(msg) from err


def add_parser(subparsers: Subparsers) -> None:
    """``calibrate acc FILE``."""
    calibrate = subparsers.add_parser("calibrate", help="calibrations from measurements")
    acc = subcommands(calibrate, "calibrate_command").add_parser(
        "acc",
        help="fit the accelerometer scale k (counts/g) to a tilt table",
        description="Least-squares fit of counts = -k*sin(angle) (eq 7, §D and TABLE I/II "
        f"of {DOCUMENT}) to rows of 'angle_deg counts' (spaces, tabs or a comma; optional "
        "header; # comments); prints k, the residual RMS and each row's error.",
    )
    acc.add_argument("file", metavar="FILE", help="the table: one 'angle_deg counts' row a line")
    acc.add_argument(
        "--axis",
        choices=("nick", "roll"),
        default="nick",
        help="nick (pitch, TABLE I) or roll (TABLE II): the config key to write (default nick)",
    )
    add_json(acc)
    acc.add_argument(
        "--write-config",
        metavar="F",
        help="set mk.acc_<axis>_counts_per_g in the YAML file F (comments are not kept)",
    )
    acc.set_defaults(func=Command(cmd_calibrate_acc))
