"""Fuzz tests (issue 10): both parsers, the MK link and the URG driver.

The stream builders, whose pieces say exactly what a parser must make of them, live in
``tools/fuzz_*.py`` beside the long run ``tools/fuzz.py``, which re-exports the ones these
tests use. ``tools/`` is not a package: this package imports that file as the module ``fuzz``
(its siblings, which it imports by bare name, with it) with ``tools/`` on ``sys.path`` for that
import only (mypy finds them all as ``tools/`` is in its files).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

TOOLS = str(Path(__file__).resolve().parents[2] / "tools")

if "fuzz" not in sys.modules:
    sys.path.insert(0, TOOLS)
    try:
        importlib.import_module("fuzz")
    finally:
        sys.path.remove(TOOLS)
