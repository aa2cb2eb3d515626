"""One short simulated flight for the replay checks (``fly --hover --sim``, about 5 s)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.security.helpers import mkflight


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("recorded") / "flight"
    done = mkflight("fly", "--hover", "--sim", "--duration", "1", "--log-dir", str(folder))
    assert done.returncode == 0, done.stderr
    return folder


@pytest.fixture
def flight(recorded: Path, tmp_path: Path) -> Path:
    """A copy of the recorded flight to damage (without the simulator's truth log)."""
    dst = tmp_path / "flight"
    shutil.copytree(recorded, dst)
    (dst / "truth.txt").unlink()
    return dst
