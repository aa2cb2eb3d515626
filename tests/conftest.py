"""The opt-in cross-checks against the ``../shared`` documents.

The suite stands alone: the protocol vectors, the seed's tables and the small laser set the
tests need are transcribed into the project (``tests/mk/vectors.py``, ``tests/urg/vectors.py``,
``tests/mk/test_units.py``, ``tests/data/``), each naming its source. A test marked
``@pytest.mark.shared("protocols/scip2.md")`` compares such a transcription with the document it
came from, so it runs only where that document exists: in ``../shared`` beside the repository,
or in the folder ``MKFLIGHT_SHARED`` names. Elsewhere (a fresh clone) it is deselected rather
than skipped, because nothing is missing: the facts it checks are already in the project.
Run only the cross-checks with ``python -m pytest -m shared``.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The shared documents' folder: ``$MKFLIGHT_SHARED``, else ``../shared`` beside the repository.
SHARED_DIR = Path(
    os.environ.get("MKFLIGHT_SHARED") or Path(__file__).resolve().parents[1].parent / "shared"
)


def pytest_configure(config: pytest.Config) -> None:
    # A config the developer exported must not reach the commands the tests run: they are
    # written against the built-in defaults (tests/test_config_search.py sets its own).
    os.environ.pop("MKFLIGHT_CONFIG", None)
    # The scan matcher's compiled kernel: compiled (≈ 30 s on a fresh clone) and cached once
    # here, before any test starts a flight, so the daemons the tests start load it instead
    # of each compiling it at the same time.
    from mkflight.scanmatch.kernels import load_kernel

    load_kernel("auto")
    config.addinivalue_line(
        "markers",
        "shared(path): cross-checks an in-project transcription against ../shared/<path> "
        "(or $MKFLIGHT_SHARED/<path>); deselected when that file is absent",
    )


def _shared_path(item: pytest.Item) -> Path | None:
    """The document ``item``'s ``shared`` marker names, or None for an ordinary test."""
    marker = item.get_closest_marker("shared")
    if marker is None:
        return None
    (relative,) = marker.args
    return SHARED_DIR / str(relative)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    keep: list[pytest.Item] = []
    absent: list[pytest.Item] = []
    for item in items:
        path = _shared_path(item)
        (absent if path is not None and not path.exists() else keep).append(item)
    if absent:
        config.hook.pytest_deselected(items=absent)
        items[:] = keep
    items.sort(key=_handed_out)  # stable: a file's tests stay in their order


#: The files that take longest (their flights, in real time), in the order the README's
#: test command (``pytest -n 2 --dist loadfile``: a file's tests in one worker, so a
#: module's flights are flown once) hands them out, before all others; otherwise xdist
#: hands out the files with the most tests first and a long one last keeps one worker
#: busy alone. test_fly comes when the campaign is about done, in the same worker:
#: its four flights at once and the campaign's four never add up on two cores. Seconds
#: on a quiet 2-core CI machine.
LONGEST_FIRST = (
    "faults/test_campaign.py",  # 31 flights, four at a time: ~165 s
    "integration/test_replay.py",  # ~55 s
    "integration/test_fly_faults_inprocess.py",  # ~50 s
    "ground/test_live.py",  # ~40 s
    "replay/test_damaged.py",  # ~40 s
    "integration/test_fly.py",  # nine flights, four at a time: ~85 s
    "tools/test_soak.py",  # ~35 s
    "test_lint.py",  # mypy --strict: ~30 s
    "ground/test_report.py",  # ~25 s
    "logs/test_flights_list.py",  # ~20 s
    "ground/test_export.py",  # ~20 s
)
_RANK = {path: i for i, path in enumerate(LONGEST_FIRST)}


def _handed_out(item: pytest.Item) -> int:
    """Where ``item``'s file comes in :data:`LONGEST_FIRST` (after it: the others)."""
    path = Path(item.path).resolve().relative_to(Path(__file__).resolve().parent).as_posix()
    return _RANK.get(path, len(_RANK))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The shared documents' folder, for the tests marked ``shared`` (which run only when
    their document is in it)."""
    return SHARED_DIR
