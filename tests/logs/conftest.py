"""A real recorded flight for the flight-folder readers' tests: ``fly --hover --sim``."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.background import Background
from tests.flights import HOVER_SIM_8S


@pytest.fixture(scope="session")
def sim_flight(background: Background) -> Path:
    """One simulated flight's folder (flight.json, events.jsonl, both raw recordings, truth),
    the background flight :data:`HOVER_SIM_8S` (a test that reads it is marked so)."""
    folder: Path = background.result(HOVER_SIM_8S)
    return folder
