"""Background flights that several modules read alike (see :mod:`tests.background`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Final

from tests.background import job
from tests.security.helpers import mkflight

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


#: ``fly --hover --sim --duration 1``: the security tests' flight (``recorded``), read-only.
HOVER_SIM_1S: Final = "hover-sim-1s"


@job(HOVER_SIM_1S)
def hover_sim_1s(base: Path) -> Path:
    """One short simulated flight for the replay checks (about 5 s): its folder."""
    folder = base / "flight"
    done = mkflight("fly", "--hover", "--sim", "--duration", "1", "--log-dir", str(folder))
    assert done.returncode == 0, done.stderr
    return folder
