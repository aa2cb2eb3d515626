"""``mkflight sim hover``: a lock-step simulated hover, its logs and its precision."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.commands.args import (
    Command,
    Subparsers,
    add_airframe,
    add_json,
    airframe_overrides,
    config_options,
)
from mkflight.errors import ConfigError

if TYPE_CHECKING:
    from mkflight.config_search import ConfigSource


def cmd_sim_hover(
    *,
    duration_s: float,
    excite_m: float,
    seed: int | None,
    airframe: str | None = None,
    scans: bool = False,
    height_m: float | None,
    log_dir: str | None,
    as_json: bool,
    config_path: str | None,
    overrides: list[str],
    config_source: ConfigSource | None = None,
) -> int:
    """Fly the simulated vehicle (take-off, hold, land) and print the hover precision.

    ``airframe``: ``--airframe`` (:func:`~mkflight.commands.args.airframe_overrides`);
    ``scans``: ray-cast scans through the real laser pipeline.
    """
    from mkflight.config import load_config
    from mkflight.flight.step import MAX_HOLD_OFFSET_M
    from mkflight.sim.hover import run_hover

    cfg = load_config(config_path, airframe_overrides(overrides, airframe, seed))
    if not 0.0 <= excite_m <= MAX_HOLD_OFFSET_M:
        msg = f"--excite must be within 0..{MAX_HOLD_OFFSET_M} m, got {excite_m}"
        raise ConfigError(msg)
    folder = _folder(cfg.logging.dir, log_dir)
    seed_used = cfg.sim.seed if seed is None else seed
    result = run_hover(
        cfg,
        duration_s=duration_s,
        seed=seed_used,
        log_dir=folder,
        height_m=height_m,
        excite_m=excite_m,
        scans=scans,
        config_source=config_source,
    )
    if as_json:
        print(json.dumps(result.as_dict()))
        return 0
    print(
        f"simulated {result.sim_s:.1f} s in {result.wall_s:.2f} s "
        f"({result.realtime_factor:.0f}x real time), logs in {result.log_dir}"
    )
    about = f"the set-point, a ±{excite_m:g} m square wave" if excite_m > 0 else "the set-point"
    print(f"hold {result.hold_s:.1f} s  (precision about {about}, truth):")
    print(f"  std  x {result.std_x_m:.4f} m  y {result.std_y_m:.4f} m  z {result.std_z_m:.4f} m")
    print(f"  rms  x {result.rms_x_m:.4f} m  y {result.rms_y_m:.4f} m  z {result.rms_z_m:.4f} m")
    touchdowns = ", ".join(f"{v:.2f}" for v in result.touchdowns_mps) or "none"
    print(f"  end: {result.end}; touchdowns (truth) {touchdowns} m/s")
    print(f"  failsafe events: {len(result.failsafes)}")
    for line in result.failsafes:
        print(f"    {line}")
    kind = result.airframe_kind
    which = f" (sim.seed {result.airframe_seed})" if kind == "random" else ""
    laser = "ray-cast scans, real scan matcher" if result.scans else "true pose + noise"
    print(f"airframe {kind}{which}; flight seed {seed_used}; laser: {laser}")
    return 0


def _folder(logging_dir: str, log_dir: str | None) -> Path:
    """A new numbered folder in ``logging.dir`` (as ``fly``'s), or ``--log-dir`` if empty.

    ``latest`` follows the numbered folders (:mod:`mkflight.logs.folders`).

    Raises:
        ConfigError: ``--log-dir`` is not empty, or no folder can be made.
    """
    import sys

    from mkflight.logs.folders import create_flight_folder, note_flight_folder

    if log_dir is None:
        made = create_flight_folder(logging_dir)
    else:
        folder = Path(log_dir)
        if folder.exists() and any(folder.iterdir()):
            msg = f"log dir {str(folder)!r} is not empty: a flight folder is never overwritten"
            raise ConfigError(msg)
        made = note_flight_folder(folder, logging_dir)
    if made.latest_problem is not None:
        print(f"warning: {made.latest_problem}", file=sys.stderr)
    return made.path


def add_parser(sim_commands: Subparsers) -> None:
    """``sim hover``: a lock-step hover."""
    hover = sim_commands.add_parser(
        "hover",
        parents=[config_options()],
        help="fly a simulated hover in lock-step and print its precision",
        description="Estimator, controllers, failsafe and vehicle model in lock-step, far "
        "faster than real time: take off, hold, land; writes the flight folder (TABLE III "
        "and IV, flight.json, truth.txt) and prints the hover precision against truth.",
    )
    hover.add_argument(
        "--duration",
        dest="duration_s",
        type=float,
        default=60.0,
        metavar="S",
        help="flight time",
    )
    hover.add_argument(
        "--seed",
        type=int,
        metavar="N",
        help="seeds the flight: noise, gusts, the vehicle's errors (default sim.seed); with "
        "--airframe random also the airframe, unless --set sim.seed=M picks it "
        "(--airframe random --set sim.seed=3 --seed 1: airframe 3, flight 1)",
    )
    add_airframe(hover)
    hover.add_argument(
        "--scans",
        action="store_true",
        help="ray-cast URG scans in the room through the real scan matcher and hat "
        "(slower) instead of the true pose plus noise",
    )
    hover.add_argument(
        "--height", dest="height_m", type=float, metavar="M", help="hover height (default 0.6)"
    )
    hover.add_argument(
        "--log-dir", metavar="DIR", help="flight folder (default: new, numbered, in logging.dir)"
    )
    hover.add_argument(
        "--excite",
        dest="excite_m",
        type=float,
        default=0.0,
        metavar="M",
        help="move the HOLD set-point between +-M m in x and y (random 1.5-3 s dwell): "
        "a response test for 'analyze latency'",
    )
    add_json(hover)
    hover.set_defaults(func=Command(cmd_sim_hover))
