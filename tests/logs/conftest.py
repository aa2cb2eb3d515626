"""A real recorded flight for the flight-folder readers' tests: ``fly --hover --sim``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

MKFLIGHT = [sys.executable, "-m", "mkflight"]
SIM_FLIGHT_S = 8  # seconds of flight after the checks: ~15 s of wall time


def fly_sim(folder: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """``mkflight fly --hover --sim`` into ``folder`` (exit 0 asserted, stderr in the message)."""
    proc = subprocess.run(
        [*MKFLIGHT, "fly", "--hover", "--sim", "--duration", str(SIM_FLIGHT_S), *extra],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (folder / "laser.raw").is_file(), proc.stdout
    return proc


@pytest.fixture(scope="session")
def sim_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One simulated flight's folder (flight.json, events.jsonl, both raw recordings, truth)."""
    folder = tmp_path_factory.mktemp("sim-flight") / "flight"
    fly_sim(folder, "--log-dir", str(folder))
    return folder
