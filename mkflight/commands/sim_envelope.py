"""``mkflight sim envelope``: fly N random airframes and judge the flight on them (issue 17).

Exit 0 when the criteria hold (:mod:`mkflight.sim.envelope_report`), 1 when not (the
report says which), 2 on bad usage or a bad configuration.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

from mkflight.commands.progress import tty_bar
from mkflight.config import load_config
from mkflight.errors import ConfigError

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
    from mkflight.sim.envelope import MIN_HOLD_S, default_jobs, envelope_jobs, run_envelope
    from mkflight.sim.envelope_report import judge_run, report_dict, summarize
    from mkflight.sim.envelope_text import markdown_table, text_report

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
            runs = run_envelope(
                jobs_list,
                workers=workers,
                on_done=None if bar is None else (lambda _run: bar.update(1)),
            )
    finally:
        if temporary:
            shutil.rmtree(folder, ignore_errors=True)
    wall_s = time.perf_counter() - wall0
    summary = summarize([judge_run(r) for r in runs])
    if plot_dir is not None:
        from mkflight.sim.envelope_plot import envelope_plots

        paths = envelope_plots(runs, plot_dir)
    else:
        paths = []
    if as_json:
        report = report_dict(runs, seed=seed, hold_s=hold_s, wall_s=wall_s)
        report["plots"] = [str(p) for p in paths]
        report["out"] = None if temporary else str(folder)
        print(json.dumps(report))
    elif markdown:
        print("\n".join(markdown_table(runs)))
    else:
        lines = text_report(runs, seed=seed, hold_s=hold_s, workers=workers, wall_s=wall_s)
        print("\n".join(lines))
        if not temporary:
            print(f"flight folders in {folder}")
        for path in paths:
            print(path)
    return EXIT_OK if summary.ok else EXIT_CRITERIA
