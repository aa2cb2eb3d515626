"""One short simulated flight for the replay checks (``fly --hover --sim``, about 5 s)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.background import Background
from tests.flights import HOVER_SIM_1S


@pytest.fixture(scope="session")
def recorded(background: Background) -> Path:
    """The background flight :data:`~tests.flights.HOVER_SIM_1S` (a module whose tests read
    it, through ``flight`` too, is marked so)."""
    folder: Path = background.result(HOVER_SIM_1S)
    return folder


@pytest.fixture
def flight(recorded: Path, tmp_path: Path) -> Path:
    """A copy of the recorded flight to damage (without the simulator's truth log)."""
    dst = tmp_path / "flight"
    shutil.copytree(recorded, dst)
    (dst / "truth.txt").unlink()
    return dst
