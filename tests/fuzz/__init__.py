"""Fuzz tests (issue 10): both parsers, the MK link and the URG driver.

The stream builders, whose pieces say exactly what a parser must make of them, live in
``tools/fuzz.py`` (the long run) and are shared: this package registers that file as the
module ``fuzz`` before its tests import it (mypy finds it as ``tools/`` is in its files).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "fuzz.py"

if "fuzz" not in sys.modules:
    _spec = importlib.util.spec_from_file_location("fuzz", TOOL)
    assert _spec is not None
    assert _spec.loader is not None
    _module = importlib.util.module_from_spec(_spec)
    sys.modules["fuzz"] = _module  # before exec: its dataclasses look their module up
    _spec.loader.exec_module(_module)
