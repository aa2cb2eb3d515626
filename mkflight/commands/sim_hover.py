"""``mkflight sim hover``: a lock-step simulated hover, its logs and its precision."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

from mkflight.config import load_config
from mkflight.errors import ConfigError
from mkflight.flight.step import MAX_HOLD_OFFSET_M


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
) -> int:
    """Fly the simulated vehicle (take-off, hold, land) and print the hover precision.

    ``airframe``: ``--airframe`` (:func:`~mkflight.commands.sim_run.airframe_overrides`);
    ``scans``: ray-cast scans through the real laser pipeline.
    """
    from mkflight.commands.sim_run import airframe_overrides
    from mkflight.sim.hover import run_hover

    cfg = load_config(config_path, airframe_overrides(overrides, airframe, seed))
    if not 0.0 <= excite_m <= MAX_HOLD_OFFSET_M:
        msg = f"--excite must be within 0..{MAX_HOLD_OFFSET_M} m, got {excite_m}"
        raise ConfigError(msg)
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    folder = Path(log_dir) if log_dir else Path(cfg.logging.dir) / f"sim-hover-{stamp}"
    if folder.exists() and any(folder.iterdir()):
        msg = f"log dir {str(folder)!r} is not empty: a flight folder is never overwritten"
        raise ConfigError(msg)
    seed_used = cfg.sim.seed if seed is None else seed
    result = run_hover(
        cfg,
        duration_s=duration_s,
        seed=seed_used,
        log_dir=folder,
        height_m=height_m,
        excite_m=excite_m,
        scans=scans,
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
