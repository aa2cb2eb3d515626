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
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.background import Background, lower_main_priority

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
    config.addinivalue_line(
        "markers",
        "background(*keys): reads the background flights keys (tests/background.py); "
        "started when the session starts, the module's tests after all others",
    )
    config.addinivalue_line(
        "markers",
        "realtime: flies in this process in real time: runs last, once the background "
        "flights have all ended (tests/background.py)",
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
    # The modules that read background flights after the others, each kept whole (its
    # module fixtures are set up once): their flights fly while the other tests run. Last,
    # the tests that fly in this process, alone.
    waiting = {item.path for item in items if _background_keys(item)}
    items.sort(  # stable: the order is kept otherwise
        key=lambda item: (item.get_closest_marker("realtime") is not None, item.path in waiting)
    )


def _background_keys(item: pytest.Item) -> list[str]:
    """The background flights ``item`` reads (its ``background`` markers' keys; none if it
    is marked to skip)."""
    if item.get_closest_marker("skip") is not None:
        return []
    return [str(key) for marker in item.iter_markers("background") for key in marker.args]


@pytest.fixture(scope="session", autouse=True)
def background(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Background]:
    """The session's background flights (tests/background.py), started in the order their
    tests will run; then this thread, and so the tests, runs below their priority."""
    flights = Background(tmp_path_factory.mktemp("background"))
    flights.start(key for item in request.session.items for key in _background_keys(item))
    lower_main_priority()
    yield flights
    flights.close()


@pytest.fixture(autouse=True)
def _alone_if_realtime(request: pytest.FixtureRequest, background: Background) -> None:
    """A test marked ``realtime`` starts once every background flight has ended."""
    if request.node.get_closest_marker("realtime") is not None:
        background.wait_all()


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The shared documents' folder, for the tests marked ``shared`` (which run only when
    their document is in it)."""
    return SHARED_DIR
