"""Hover precision (seed §O-P, TABLE IX) against the simulator's own truth figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mkflight.analysis.precision import (
    SEED_TABLE_IX,
    AnalysisInputError,
    hold_samples,
    parse_truth,
    precision,
    with_truth,
)
from mkflight.config import Config
from mkflight.logs.events import read_events
from mkflight.logs.schema import Step
from mkflight.sim.hover import IMU_PERIOD_NS, SETTLE_S, run_hover

NS = 1_000_000_000


def _step(t_s: float, phase: str, x: float, sp: float | None) -> Step:
    return Step(
        t_ns=int(t_s * NS),
        x_m=x,
        y_m=0.0,
        sp_x_m=sp,
        sp_y_m=None if sp is None else 0.0,
        sp_height_m=None if sp is None else 0.6,
        height_m=0.6,
        vz_up_mps=0.0,
        gas_counts=100,
        battery_v=12.0,
        phase=phase,
        action="NONE",
    )


def test_agrees_with_the_simulators_truth_figures(tmp_path: Path) -> None:
    result = run_hover(Config(), duration_s=20, seed=2, log_dir=tmp_path)
    samples = hold_samples(read_events(tmp_path / "events.jsonl").events, SETTLE_S)
    truth = parse_truth((tmp_path / "truth.txt").read_text(), "truth.txt")
    p = precision(with_truth(samples, truth), "truth")
    assert p.samples == round(result.hold_s * NS / IMU_PERIOD_NS)
    for got, want in (
        (p.x.std_m, result.std_x_m),
        (p.y.std_m, result.std_y_m),
        (p.z.std_m, result.std_z_m),
        (p.x.rms_m, result.rms_x_m),
        (p.y.rms_m, result.rms_y_m),
        (p.z.rms_m, result.rms_z_m),
    ):
        assert got == pytest.approx(want, abs=1e-3)
    assert p.x.max_m >= p.x.rms_m >= p.x.std_m
    d = p.as_dict()
    assert d["samples"] == p.samples
    assert {"std_x_m", "rms_z_m", "mean_y_m", "max_z_m"} <= set(d)


def test_statistics_and_settling() -> None:
    # HOLD from 10 s; before 13 s a big error that must not count.
    events = [_step(9.0, "TAKEOFF", 0.5, 0.0)]
    events += [_step(10.0 + 0.05 * i, "HOLD", 0.9, 0.0) for i in range(60)]  # < 13 s
    events += [_step(13.0 + 0.05 * i, "HOLD", (0.1, -0.1)[i % 2], 0.0) for i in range(40)]
    events += [_step(15.0, "LAND", 0.5, 0.0), _step(15.1, "HOLD", 0.1, None)]
    p = precision(hold_samples(events), "estimate")
    assert p.samples == 40
    assert p.x.mean_m == pytest.approx(0.0, abs=1e-12)
    assert p.x.std_m == pytest.approx(0.1)
    assert p.x.rms_m == pytest.approx(0.1)
    assert p.x.max_m == pytest.approx(0.1)
    assert p.z.rms_m == 0.0


def test_truth_nearest_within_30_ms() -> None:
    samples = hold_samples([_step(5.0 + 0.05 * i, "HOLD", 0.0, 0.0) for i in range(100)], 0.0)
    truth = np.array([[5.0, 0.2, 0.0, 0.6], [5.025, 0.3, 0.0, 0.6], [20.0, 0.4, 0.0, 0.6]])
    out = with_truth(samples, truth)
    assert list(out.t_ns) == [5 * NS, int(5.05 * NS)]
    assert out.position_m[:, 0].tolist() == [0.2, 0.3]


def test_parse_truth_errors_name_file_and_line() -> None:
    assert parse_truth("t x y z\n0 1 2 3\n0.05 1 2 3\n", "f").shape == (2, 4)
    with pytest.raises(AnalysisInputError, match=r"^f:3: "):
        parse_truth("t x y z\n0 1 2 3\n0.05 1 oops 3\n", "f")
    with pytest.raises(AnalysisInputError, match=r"^f:2: expected 4"):
        parse_truth("t x y z\n0 1 2\n", "f")
    with pytest.raises(AnalysisInputError, match=r"^f:3: time"):
        parse_truth("0 1 2 3\n\n0 1 2 3\n", "f")
    with pytest.raises(AnalysisInputError, match="no 't x y z' rows"):
        parse_truth("t x y z\n", "f")


def test_no_hold_is_an_error() -> None:
    with pytest.raises(AnalysisInputError, match="no HOLD samples"):
        precision(hold_samples([_step(1.0, "TAKEOFF", 0.0, 0.0)]), "estimate")


def test_seed_table_ix() -> None:
    names = [r.name for r in SEED_TABLE_IX]
    assert len(names) == 4
    assert SEED_TABLE_IX[3].x_m == 0.075368
