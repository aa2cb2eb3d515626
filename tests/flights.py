"""Background flights that several modules read alike (see :mod:`tests.background`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Final

from tests.background import job

#: ``fly --hover --sim --duration 8``: the report's, the export's and the flights list's
#: flight, read-only (a test that changes a folder changes its own copy).
HOVER_SIM_8S: Final = "hover-sim-8s"


@job(HOVER_SIM_8S)
def hover_sim_8s(base: Path) -> Path:
    """One real simulated flight (the daemon on the simulator's ptys): its folder."""
    folder = base / "flight"
    args = ["fly", "--hover", "--sim", "--duration", "8", "--log-dir", str(folder)]
    done = subprocess.run(
        [sys.executable, "-m", "mkflight", *args],
        capture_output=True,
        text=True,
        timeout=180,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (folder / "laser.raw").is_file(), done.stdout
    return folder
