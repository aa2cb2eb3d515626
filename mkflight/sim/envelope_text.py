"""The envelope's human reports: the text report and the README's markdown table."""

from __future__ import annotations

import math
from collections.abc import Sequence

from mkflight.sim.envelope import AirframeRun, FlightFigures
from mkflight.sim.envelope_report import (
    CRITERIA,
    KEY_PARAMETERS,
    Criteria,
    Verdict,
    judge_run,
    statistics,
    summarize,
    worst,
)


def _m(value: float, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if math.isfinite(value) else "-"


def _std(f: FlightFigures) -> str:
    if f.error is not None:
        return "error"
    return f"{_m(f.std_x_m)} / {_m(f.std_y_m)} / {_m(f.std_z_m)}"


def _touchdowns(run: AirframeRun) -> str:
    parts = []
    for f in (run.defaults, run.stall, run.tuned):
        speeds = ", ".join(f"{v:.2f}" for v in f.touchdowns_mps) or "-"
        parts.append(speeds)
    return " | ".join(parts)


def _ends(run: AirframeRun, sep: str = " | ") -> str:
    return sep.join(f.end for f in (run.defaults, run.stall, run.tuned))


def _verdict(v: Verdict) -> str:
    if v.passed:
        return "pass"
    failed = [
        name
        for name, ok in (
            ("precision", v.precision),
            ("touchdown", v.touchdowns),
            ("stall", v.stall_landed),
            ("tuned", v.tuned),
        )
        if not ok
    ]
    return "FAIL " + ",".join(failed)


def _response_s(run: AirframeRun) -> float:
    return run.drawn.get("attitude_delay_s", math.nan) + run.drawn.get("attitude_tau_s", math.nan)


def parameters_line(run: AirframeRun) -> str:
    """The airframe's key drawn parameters in one line."""
    parts = []
    for key, label, digits in KEY_PARAMETERS:
        value = run.drawn.get(key, math.nan)
        parts.append(f"{label} {value:.{digits}f}")
    return ", ".join(parts)


def text_report(
    runs: Sequence[AirframeRun],
    *,
    seed: int,
    hold_s: float,
    workers: int,
    wall_s: float,
    criteria: Criteria = CRITERIA,
) -> list[str]:
    """The report's lines: per airframe, the criteria, the worst five, the statistics."""
    verdicts = [judge_run(r, criteria) for r in runs]
    summary = summarize(verdicts, criteria)
    n = len(runs)
    lines = [
        f"envelope: {n} random airframes (seeds {seed}..{seed + n - 1}), hold {hold_s:g} s, "
        f"{workers} processes, {wall_s:.0f} s",
        "std in m (x / y / z, truth); touchdowns in m/s, ends and failsafe events of the "
        "flights defaults | stall | tuned",
    ]
    for run, v in zip(runs, verdicts, strict=True):
        failsafes = "/".join(str(len(f.failsafes)) for f in (run.defaults, run.stall, run.tuned))
        lines += [
            f"seed {run.seed:4d}  delay+lag {_response_s(run):.2f} s  "
            f"{run.drawn.get('counts_per_rad', math.nan):3.0f} counts/rad  "
            f"hover gas {run.drawn.get('hover_gas_counts', math.nan):3.0f}  "
            f"vibration {run.drawn.get('vibration_counts', math.nan):2.0f}  "
            f"gusts {run.drawn.get('gust_accel_std_mps2', math.nan):.2f} m/s2  {_verdict(v)}",
            f"    std {_std(run.defaults)}  tuned {_std(run.tuned)}  oracle "
            f"{_m(run.oracle.std_x_m)} / {_m(run.oracle.std_y_m)}  touchdowns {_touchdowns(run)}"
            f"  ends {_ends(run)}  failsafes {failsafes}",
        ]
        lines += [f"    - {reason}" for reason in v.reasons]

    def share(k: int) -> str:
        return f"{k}/{n} ({k / n:.0%})" if n else f"{k}/0"

    lines += [
        "criteria:",
        f"  precision std x,y <= max({criteria.floor_m} m, {criteria.oracle_factor} x oracle), "
        f"z <= {criteria.max_std_z_m} m: {share(summary.precision_pass)}, "
        f"need >= {criteria.precision_share:.0%}",
        f"  every touchdown <= {criteria.max_touchdown_mps} m/s: "
        f"{share(summary.touchdown_pass)}, need 100%",
        f"  the laser-stall flight lands: {share(summary.stall_pass)}, need 100%",
        f"  the tuned config at least as good: {share(summary.tuned_pass)}, "
        f"need >= {criteria.tuned_share:.0%}",
        "  verdict: " + ("criteria hold" if summary.ok else "FAIL: " + "; ".join(summary.failed)),
        "worst by std / oracle:",
    ]
    for i in worst(runs, verdicts):
        run, v = runs[i], verdicts[i]
        ratio = f"{v.ratio:.2f}" if math.isfinite(v.ratio) else "-"
        lines.append(
            f"  seed {run.seed}: ratio {ratio}, std {_std(run.defaults)}, oracle "
            f"{_m(run.oracle.std_x_m)} / {_m(run.oracle.std_y_m)}; {parameters_line(run)}"
        )
    lines.append("statistics (median / p95 / max over airframes):")
    for key, stats in statistics(runs).items():
        values = " / ".join("-" if stats[k] is None else f"{stats[k]:.3f}" for k in stats)
        lines.append(f"  {key:20s} {values}")
    return lines


def markdown_table(runs: Sequence[AirframeRun], criteria: Criteria = CRITERIA) -> list[str]:
    """The README's table: one row per airframe, then the pass counts."""
    verdicts = [judge_run(r, criteria) for r in runs]
    summary = summarize(verdicts, criteria)
    lines = [
        "| seed | delay+lag s | counts/rad | hover gas | vibration | std x / y / z m (defaults) "
        "| tuned | oracle x / y | touchdowns m/s (defaults; stall; tuned) | ends (same) "
        "| verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for run, v in zip(runs, verdicts, strict=True):
        touch = "; ".join(
            ", ".join(f"{s:.2f}" for s in f.touchdowns_mps) or "-"
            for f in (run.defaults, run.stall, run.tuned)
        )
        lines.append(
            f"| {run.seed} | {_response_s(run):.2f} | "
            f"{run.drawn.get('counts_per_rad', math.nan):.0f} | "
            f"{run.drawn.get('hover_gas_counts', math.nan):.0f} | "
            f"{run.drawn.get('vibration_counts', math.nan):.0f} | {_std(run.defaults)} | "
            f"{_std(run.tuned)} | {_m(run.oracle.std_x_m)} / {_m(run.oracle.std_y_m)} | "
            f"{touch} | {_ends(run, '; ')} | {_verdict(v)} |"
        )
    n = summary.n
    lines += [
        "",
        f"Precision {summary.precision_pass}/{n}, touchdowns {summary.touchdown_pass}/{n}, "
        f"stall landings {summary.stall_pass}/{n}, tuned at least as good "
        f"{summary.tuned_pass}/{n}: "
        + ("the criteria hold." if summary.ok else "FAIL: " + "; ".join(summary.failed) + "."),
    ]
    return lines
