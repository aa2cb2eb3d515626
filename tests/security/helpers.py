"""Running the CLI as a user would, and what a folder tree holds (the security tests)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 120.0  # a hang fails the test instead of stalling the suite


def mkflight(
    *args: str, tmpdir: Path | None = None, timeout: float = TIMEOUT_S
) -> subprocess.CompletedProcess[str]:
    """``python -m mkflight ARGS`` (``tmpdir``: its TMPDIR, to see what it leaves there)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    return subprocess.run(
        [sys.executable, "-m", "mkflight", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        cwd=ROOT,
        env=env,
        check=False,
    )


def error_lines(stderr: str) -> list[str]:
    """The ``error:`` lines of a run's stderr."""
    return [line for line in stderr.splitlines() if line.startswith("error:")]


def one_error(done: subprocess.CompletedProcess[str], code: int) -> str:
    """Assert the run failed with ``code`` and exactly one ``error:`` line; return it."""
    assert "Traceback" not in done.stderr, done.stderr
    lines = error_lines(done.stderr)
    assert len(lines) == 1, done.stderr
    assert done.returncode == code, done.stderr
    return lines[0]


def tree(root: Path) -> dict[str, tuple[str, bytes | str]]:
    """Every entry under ``root`` (not following symlinks): kind and content or target."""
    out: dict[str, tuple[str, bytes | str]] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            if path.is_symlink():
                out[rel] = ("link", os.readlink(path))
            elif path.is_dir():
                out[rel] = ("dir", b"")
            elif path.is_file():
                out[rel] = ("file", path.read_bytes())
            else:
                out[rel] = ("other", b"")
    return out
