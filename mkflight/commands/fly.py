"""``mkflight fly --hover``: the flight daemon on real ports, or on the simulator's ptys."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.commands.args import Command, Subparsers, add_json, add_ports, config_options
from mkflight.errors import ConfigError, FlightError, PortNotFoundError
from mkflight.ground.live_address import DEFAULT_LIVE, LiveAddress, parse_live_address

if TYPE_CHECKING:
    from mkflight.config import Config
    from mkflight.config_search import ConfigSource
    from mkflight.ground.live import LiveView
    from mkflight.logs.schema import FlightSummary


def _folder(cfg: Config, log_dir: str | None) -> Path:
    """The flight folder: a new numbered one in ``logging.dir``, or ``--log-dir``.

    The new one is made at once (:func:`~mkflight.logs.folders.create_flight_folder`,
    ``latest`` pointed at it); its name is made of digits and dashes only, so it stays
    there. ``--log-dir`` must be new or empty (a simulator's ``truth.txt`` may be there
    already); ``latest`` follows it only if it is the newest numbered folder in
    ``logging.dir`` (:func:`~mkflight.logs.folders.note_flight_folder`). Every file in it
    is then created, never opened if it exists (nor through a symlink planted in the
    folder): :class:`~mkflight.flight.flight_logs.FlightLogs`.

    Raises:
        ConfigError: the path is not a folder (a file, a dangling symlink), cannot be
            made or listed, or holds something; ``logging.dir`` cannot be made.
    """
    from mkflight.flight.flight_logs import folder_in_use
    from mkflight.logs.folders import create_flight_folder, note_flight_folder

    if log_dir is None:
        made = create_flight_folder(cfg.logging.dir)
        _warn_latest(made.latest_problem)
        return made.path
    folder = Path(log_dir)
    if os.path.lexists(folder) and not folder.is_dir():
        msg = f"log dir {str(folder)!r} is not a folder"
        raise ConfigError(msg)
    try:
        in_use = folder_in_use(folder)
    except OSError as err:
        msg = f"log dir {str(folder)!r} cannot be read: {err.strerror or err}"
        raise ConfigError(msg) from err
    if in_use:
        msg = f"log dir {str(folder)!r} is not empty: a flight folder is never overwritten"
        raise ConfigError(msg)
    _warn_latest(note_flight_folder(folder, cfg.logging.dir).latest_problem)
    return folder


def _warn_latest(problem: str | None) -> None:
    """One ``warning:`` line on stderr when ``latest`` could not follow the new flight."""
    if problem is not None:
        print(f"warning: {problem}", file=sys.stderr)


def _truth_precision(folder: Path) -> dict[str, float | int] | None:
    """The HOLD precision against the simulator's truth (None without truth or HOLD)."""
    from mkflight.analysis.precision import folder_truth_precision

    p = folder_truth_precision(folder)
    if p is None:
        return None
    return {
        "std_x_m": round(p.x.std_m, 5),
        "std_y_m": round(p.y.std_m, 5),
        "std_z_m": round(p.z.std_m, 5),
        "samples": p.samples,
    }


def _check_ports(mk_port: str | None, laser_port: str | None) -> None:
    """Both ports given exist (a missing device is a usage error, exit 2).

    Raises:
        PortNotFoundError: naming the device, the port and where it came from.
    """
    for what, flag, port in (
        ("FC", "mk.port or --mk-port", mk_port),
        ("laser", "laser.port or --laser-port", laser_port),
    ):
        if port is not None and not Path(port).exists():
            msg = f"{what} port {port} ({flag}): no such device"
            raise PortNotFoundError(msg)


async def _fly(
    cfg: Config,
    *,
    sim: bool,
    mk_port: str | None,
    laser_port: str | None,
    folder: Path,
    height_m: float | None,
    duration_s: float | None,
    config_path: str | None,
    overrides: list[str],
    config_source: ConfigSource | None,
    live: LiveView | None,
) -> tuple[int, str, FlightSummary]:
    from mkflight.flight.app import FlightApp, FlightOptions
    from mkflight.flight.flight_logs import TRUTH_FILE
    from mkflight.flight.sim_process import SimProcess, start_sim

    child: SimProcess | None = None
    if sim:
        folder.mkdir(parents=True, exist_ok=True)  # noqa: ASYNC240 - before any flight task
        child = await start_sim(
            config_path=config_path, overrides=overrides, truth=folder / TRUTH_FILE
        )
        mk_port, laser_port = child.mk_port, child.laser_port
    if mk_port is None or laser_port is None:  # the caller checked: --sim or both ports
        msg = "fly needs --mk-port and --laser-port (or --sim)"
        raise ConfigError(msg)
    try:
        app = FlightApp(
            cfg,
            FlightOptions(
                mk_port=mk_port,
                laser_port=laser_port,
                log_dir=folder,
                height_m=height_m,
                duration_s=duration_s,
                status_tty=sys.stderr.isatty(),
                config_source=config_source,
            ),
            observer=None if live is None else live.feed,
        )
        report = await (app.fly() if live is None else live.during(app.fly()))
    finally:
        if child is not None:
            await child.stop()
    return report.exit_code, report.reason, report.summary


def _start_live(cfg: Config, address: LiveAddress) -> LiveView:
    """The live view's server, listening before anything flies; its URL on stderr.

    Raises:
        ConfigError: the address cannot be listened on, or the Foxglove SDK is missing.
    """
    try:
        from mkflight.ground.live import start_live_view
    except ModuleNotFoundError as err:
        msg = f"--live needs the Foxglove SDK ({err.name}): pip install 'mkflight[live]'"
        raise ConfigError(msg) from err

    view = start_live_view(cfg, address)
    print(f"live view: {view.address.url()} (Foxglove: Open connection)", file=sys.stderr)
    return view


def _print_summary(
    folder: Path, reason: str, summary: FlightSummary, truth: dict[str, float | int] | None
) -> None:
    """The end-of-flight lines: why it ended, precision, timing, CPU, failsafes."""
    print(f"flight folder: {folder}")
    print(f"ended: {reason} (phase {summary.final_phase})")
    if truth is not None:
        print(
            f"hold precision (truth): std x {truth['std_x_m']:.4f} m  "
            f"y {truth['std_y_m']:.4f} m  z {truth['std_z_m']:.4f} m"
        )
    t = summary.timing
    if t.steps:
        print(
            f"{t.steps} steps: command latency median {t.latency_median_ms:.2f} ms, "
            f"p99 {t.latency_p99_ms:.2f} ms; added jitter p99 {t.added_jitter_p99_ms:.2f} ms"
        )
        print(
            f"DebugOut interval {t.period_median_ms:.1f} ms, p99 deviation "
            f"{t.jitter_p99_ms:.1f} ms, {t.missed_steps} missed"
        )
    print(
        f"CPU: daemon {summary.cpu_percent_of_one_core} % of one core; scan matcher "
        f"{summary.matcher.cpu_ms_per_scan} ms a scan"
    )
    unplanned = [f for f in summary.failsafes if "stop_" not in f]
    print("failsafes: " + ("; ".join(unplanned) if unplanned else "none"))


def _print_result(folder: Path, reason: str, summary: FlightSummary, *, as_json: bool) -> None:
    """The flight's summary on stdout: text, or one JSON object (``--json``)."""
    from mkflight.logs.flight_json import json_safe, to_plain

    truth = _truth_precision(folder)  # when a simulator wrote its truth there
    if as_json:
        head = {"log_dir": str(folder), "reason": reason, "truth_precision": truth}
        print(json.dumps(json_safe({**head, **to_plain(summary)}), allow_nan=False))
    else:
        _print_summary(folder, reason, summary, truth)


def cmd_fly(
    *,
    hover: bool,
    sim: bool,
    mk_port: str | None,
    laser_port: str | None,
    height_m: float | None,
    duration_s: float | None,
    log_dir: str | None,
    as_json: bool,
    config_path: str | None,
    overrides: list[str],
    config_source: ConfigSource | None = None,
    live: LiveAddress | None = None,
) -> int:
    """Fly: pre-flight checks, handshake, take-off, hold, soft landing, release (SPEC §7).

    ``live``: also serve the flight to Foxglove there (:mod:`mkflight.ground.live`).

    Raises:
        ConfigError: a usage error (no ``--hover``, missing ports, a non-empty log dir,
            a ``--live`` address that cannot be listened on).
        FlightError: the flight failed (exit 1, after the soft landing and release).
    """
    import asyncio

    from mkflight.config import load_config

    if not hover:
        msg = "fly needs a mission: --hover (the only one so far)"
        raise ConfigError(msg)
    cfg = load_config(config_path, overrides)
    if not sim:  # the ports: the options, else the config's (mk.port, laser.port)
        mk_port = mk_port or cfg.mk.port
        laser_port = laser_port or cfg.laser.port
    for name, value in (("--height", height_m), ("--duration", duration_s)):
        if value is not None and not (value > 0 and value < 1e6):
            msg = f"{name} must be a positive number, got {value}"
            raise ConfigError(msg)
    if height_m is not None and height_m > cfg.safety.max_height_m:
        msg = f"--height {height_m:g} m is above safety.max_height_m {cfg.safety.max_height_m:g}"
        raise ConfigError(msg)
    if not sim:
        _check_ports(mk_port, laser_port)
    if height_m is not None:  # in the config flown, so flight.json (and a replay) has it
        try:
            cfg = load_config(config_path, [*overrides, f"control.takeoff_height_m={height_m}"])
        except ConfigError as err:  # e.g. above the 3 m the config allows
            msg = f"--height {height_m:g}: {err}"
            raise ConfigError(msg) from err
    folder = _folder(cfg, log_dir)
    view = None if live is None else _start_live(cfg, live)
    try:
        code, reason, summary = asyncio.run(
            _fly(
                cfg,
                sim=sim,
                mk_port=mk_port,
                laser_port=laser_port,
                folder=folder,
                height_m=height_m,
                duration_s=duration_s,
                config_path=config_path,
                overrides=overrides,
                config_source=config_source,
                live=view,
            )
        )
    finally:
        if view is not None:
            view.close()
    _print_result(folder, reason, summary, as_json=as_json)
    if code != 0:
        raise FlightError(reason)
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``fly``: the flight daemon."""
    fly = subparsers.add_parser(
        "fly",
        parents=[config_options()],
        help="fly: pre-flight checks, take-off, hold, soft landing, release",
        description="The flight daemon (SPEC §7): pre-flight checks (FC version and "
        "DebugOut rate, level, battery, laser info and scan rate, hat height on the ground, "
        "scan match), the neutral handshake, take-off to --height, hold at the take-off "
        "x, y, psi, and a soft landing and release on SIGINT/SIGTERM, --duration or a "
        "failsafe. Writes a flight folder (TABLE III/IV, events.jsonl, flight.json, raw "
        "recordings of both ports). Exit 0 after a landing, 1 on a failure (after the "
        "landing and release), 2 on bad usage.",
    )
    fly.add_argument("--hover", action="store_true", help="the mission: hold position")
    fly.add_argument(
        "--sim", action="store_true", help="fly the simulated vehicle (its own process, ptys)"
    )
    add_ports(fly, "mk", "laser")
    fly.add_argument(
        "--height", dest="height_m", type=float, metavar="M", help="hover height (default 0.6)"
    )
    fly.add_argument(
        "--duration",
        dest="duration_s",
        type=float,
        metavar="S",
        help="land this long after the checks",
    )
    fly.add_argument(
        "--log-dir",
        metavar="DIR",
        help="flight folder (default: a new numbered one under logging.dir)",
    )
    fly.add_argument(
        "--live",
        nargs="?",
        const=DEFAULT_LIVE,
        type=parse_live_address,
        metavar="[HOST:]PORT",
        help="serve the flight live to Foxglove (WebSocket; default 127.0.0.1:8765, "
        "loopback unless a host is given)",
    )
    add_json(fly, "the summary as one JSON object")
    fly.set_defaults(func=Command(cmd_fly))
