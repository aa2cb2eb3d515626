"""The truth log's comment lines: the airframe, and touchdowns that never end the file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mkflight.analysis.precision import parse_truth
from mkflight.sim.truth import TruthLog
from mkflight.sim.vehicle import VehicleState

S = 1_000_000_000


def state(height_m: float) -> VehicleState:
    return VehicleState(pos_w_m=(0.1, -0.2, -height_m))


def test_comments_precede_rows_and_every_reader_skips_them(tmp_path: Path) -> None:
    path = tmp_path / "truth.txt"
    log = TruthLog(path, origin_ns=S, airframe={"kind": "random", "seed": 3, "mass_kg": 1.1})
    log.write(S, state(0.0))
    log.touchdown(S + S // 2, 0.31)
    log.write(2 * S, state(0.0))
    log.close()
    lines = path.read_text().splitlines()
    assert lines[0] == "t x y z"
    assert json.loads(lines[2].removeprefix("# airframe ")) == {
        "kind": "random",
        "seed": 3,
        "mass_kg": 1.1,
    }
    assert lines[4] == "# touchdown 0.5000 0.3100"
    assert lines[5].split()[0] == "1.0000"
    assert np.loadtxt(path, skiprows=1).shape == (2, 4)
    assert parse_truth(path.read_text(), str(path)).shape == (2, 4)


def test_a_pending_touchdown_at_close_gets_a_row_after_it_if_time_allows(tmp_path: Path) -> None:
    log = TruthLog(tmp_path / "a.txt", origin_ns=0)
    log.write(S, state(0.3))
    log.touchdown(S + 10_000_000, 0.4)
    log.close(S + 20_000_000, state(0.0))
    last = (tmp_path / "a.txt").read_text().splitlines()[-2:]
    assert last[0].startswith("# touchdown")
    assert [float(v) for v in last[1].split()] == pytest.approx([1.02, 0.1, -0.2, 0.0])
    log = TruthLog(tmp_path / "b.txt", origin_ns=0)
    log.write(S, state(0.3))
    log.touchdown(S, 0.4)
    log.close()  # nothing later to write: the comment alone, no duplicate time
    lines = (tmp_path / "b.txt").read_text().splitlines()
    assert lines[-1].startswith("# touchdown")
    assert parse_truth("\n".join(lines), "b").shape == (1, 4)
