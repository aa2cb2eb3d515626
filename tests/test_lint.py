"""Static checks as tests, so CI enforces them: ruff (check + format) and mypy --strict.

Both come with the ``test`` extra, so they run (never skip) wherever the suite is installed as
the README says; they run as ``python -m`` of the test interpreter, so an environment that is
not on ``PATH`` (a venv used without activating it) checks with its own versions.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.background import MAIN_NICE, Background, job

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.lint


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)


def test_ruff_check_is_clean() -> None:
    result = _run(sys.executable, "-m", "ruff", "check", "mkflight", "tests", "tools")
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format_is_clean() -> None:
    result = _run(sys.executable, "-m", "ruff", "format", "--check", "mkflight", "tests", "tools")
    assert result.returncode == 0, result.stdout + result.stderr


MYPY_TIMEOUT_S = 900  # a cold run here takes ~60 s


@job("mypy")
def _mypy(_: Path) -> subprocess.CompletedProcess[str]:
    """mypy over the whole tree (tens of seconds of CPU on a fresh clone), run in the
    background beside the other tests, at their priority (below the flights')."""
    return subprocess.run(
        [sys.executable, "-m", "mypy"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
        timeout=MYPY_TIMEOUT_S,  # a hung mypy must not hold the session's end
        preexec_fn=lambda: os.nice(MAIN_NICE),
    )


@pytest.mark.background("mypy")
def test_mypy_strict_is_clean(background: Background) -> None:
    result: subprocess.CompletedProcess[str] = background.result("mypy")
    assert result.returncode == 0, result.stdout + result.stderr
