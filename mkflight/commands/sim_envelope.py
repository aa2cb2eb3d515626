"""``mkflight sim envelope``: fly N random airframes and judge the flight on them.

Exit 0 when the criteria hold (:mod:`mkflight.sim.envelope_report`), 1 when not (the
report says which), 2 on bad usage or a bad configuration.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from mkflight.commands.args import Command, Subparsers, config_options
from mkflight.errors import ConfigError

if TYPE_CHECKING:
    from mkflight.sim.envelope import AirframeRun

EXIT_OK = 0
EXIT_CRITERIA = 1


def _out_folder(out_dir: str | None) -> tuple[Path, bool]:
    """The folder for the flight folders and whether it is a temporary one (removed)."""
    if out_dir is None:
        return Path(tempfile.mkdtemp(prefix="mkflight-envelope-")), True
    folder = Path(out_dir)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        msg = f"--out {str(folder)!r} is not an empty folder: flight folders are never overwritten"
        raise ConfigError(msg)
    folder.mkdir(parents=True, exist_ok=True)
    return folder, False


def _workers(n: int, jobs: int | None, hold_s: float) -> int:
    """The number of processes, once ``n``, ``jobs`` and ``hold_s`` are checked.

    Raises:
        ConfigError: a value out of range (exit 2).
    """
    from mkflight.sim.envelope import MIN_HOLD_S, default_jobs

    if n < 1:
        msg = f"--n must be >= 1, got {n}"
        raise ConfigError(msg)
    if hold_s < MIN_HOLD_S:
        msg = f"--hold must be >= {MIN_HOLD_S} s, got {hold_s}"
        raise ConfigError(msg)
    workers = default_jobs() if jobs is None else jobs
    if workers < 1:
        msg = f"--jobs must be >= 1, got {workers}"
        raise ConfigError(msg)
    return workers


def cmd_sim_envelope(
    *,
    n: int,
    seed: int,
    jobs: int | None,
    hold_s: float,
    as_json: bool,
    markdown: bool,
    plot_dir: str | None,
    out_dir: str | None,
    config_path: str | None,
    overrides: list[str],
) -> int:
    """Fly ``n`` random airframes (seeds ``seed ..``), print the report; 0 if criteria hold.

    Raises:
        ConfigError: a bad value, configuration or ``--out`` folder (exit 2).
        PlotError: ``--plot`` without matplotlib (said before any flight; exit 1).
    """
    from mkflight.commands.progress import tty_bar
    from mkflight.config import load_config
    from mkflight.sim.envelope import envelope_jobs, run_envelope
    from mkflight.sim.envelope_report import judge_run, summarize

    workers = _workers(n, jobs, hold_s)
    load_config(config_path, [*overrides, "sim.airframe=random", f"sim.seed={seed}"])
    if plot_dir is not None:
        from mkflight.analysis.plots import ensure_matplotlib

        ensure_matplotlib()  # before hours of flying
    folder, temporary = _out_folder(out_dir)
    wall0 = time.perf_counter()
    try:
        jobs_list = envelope_jobs(
            n=n,
            seed=seed,
            hold_s=hold_s,
            folder=folder,
            config_path=config_path,
            overrides=overrides,
        )
        with tty_bar(n, "airframe") as bar:
            flown = run_envelope(
                jobs_list,
                workers=workers,
                on_done=None if bar is None else (lambda _run: bar.update(1)),
            )
    finally:
        if temporary:
            shutil.rmtree(folder, ignore_errors=True)
    wall_s = time.perf_counter() - wall0
    summary = summarize([judge_run(r) for r in flown])
    if plot_dir is not None:
        from mkflight.sim.envelope_plot import envelope_plots

        paths = envelope_plots(flown, plot_dir)
    else:
        paths = []
    _print_report(
        flown,
        paths,
        seed=seed,
        hold_s=hold_s,
        workers=workers,
        wall_s=wall_s,
        out=None if temporary else folder,
        as_json=as_json,
        markdown=markdown,
    )
    return EXIT_OK if summary.ok else EXIT_CRITERIA


def _print_report(
    flown: list[AirframeRun],
    paths: list[Path],
    *,
    seed: int,
    hold_s: float,
    workers: int,
    wall_s: float,
    out: Path | None,
    as_json: bool,
    markdown: bool,
) -> None:
    """Print the report: one JSON object, the README's markdown table, or text.

    ``out``: where the flight folders stay (None: in a temporary folder, removed).
    """
    from mkflight.sim.envelope_report import report_dict
    from mkflight.sim.envelope_text import markdown_table, text_report

    if as_json:
        report = report_dict(flown, seed=seed, hold_s=hold_s, wall_s=wall_s)
        report["plots"] = [str(p) for p in paths]
        report["out"] = None if out is None else str(out)
        print(json.dumps(report))
    elif markdown:
        print("\n".join(markdown_table(flown)))
    else:
        lines = text_report(flown, seed=seed, hold_s=hold_s, workers=workers, wall_s=wall_s)
        print("\n".join(lines))
        if out is not None:
            print(f"flight folders in {out}")
        for path in paths:
            print(path)


def add_parser(sim_commands: Subparsers) -> None:
    """``sim envelope``: the flight judged on N random airframes."""
    envelope = sim_commands.add_parser(
        "envelope",
        parents=[config_options()],
        help="fly N random airframes (hover, laser stall, tuned, oracle) and judge the flight",
        description="For each of N random airframes (seeds S..S+N-1), in parallel processes, "
        "in lock-step: a hover (take-off, hold, land), a second flight with the laser dead "
        "from 10 s into the hold, a third with the config 'mkflight tune' makes from the "
        "first, and the oracle (the same airframe and gusts flown on the true state with "
        "searched gains). Reports truth std, touchdown speeds, ends and failsafes per "
        "airframe, the pass rates, the worst five and summary statistics. Exit 0 when the "
        "criteria hold (precision on >= 95 %, every touchdown <= 0.5 m/s, every stall "
        "landed, the tuned config at least as good on >= 95 %), 1 when not.",
    )
    envelope.add_argument("--n", type=int, default=50, metavar="N", help="airframes")
    envelope.add_argument("--seed", type=int, default=1, metavar="S", help="first airframe seed")
    envelope.add_argument("--jobs", type=int, metavar="J", help="processes (default: CPUs)")
    envelope.add_argument(
        "--hold", dest="hold_s", type=float, default=60.0, metavar="S", help="hold time, s"
    )
    shown = envelope.add_mutually_exclusive_group()
    shown.add_argument("--json", dest="as_json", action="store_true", help="one JSON object")
    shown.add_argument(
        "--markdown", action="store_true", help="the README's table (markdown) instead"
    )
    envelope.add_argument("--plot", dest="plot_dir", metavar="DIR", help="write PNG figures here")
    envelope.add_argument(
        "--out", dest="out_dir", metavar="DIR", help="keep the flight folders here (default: none)"
    )
    envelope.set_defaults(func=Command(cmd_sim_envelope))
