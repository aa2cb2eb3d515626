"""Flight folder names: a monotonic flight number plus the local time, and ``latest``.

A new flight folder in ``logging.dir`` is named ``NNNN-YYYYMMDD-HHMM`` (e.g.
``0042-20261126-1057``): the number is 1 + the highest number among the flight folders
already there (zero-padded to 4 digits, wider when it must be), the time the local wall
time at its creation. The number orders the flights even on a board without a real-time
clock, whose wall time restarts at some old date after every power-up; the time is for
people. Folders of other names (older ``flight-...`` folders, a user's notes) are left
alone and do not count.

Creation is atomic: the number is chosen and the folder made (``mkdir``, which fails if
the name exists: then the next number is tried) while holding an exclusive ``flock`` on
``logging.dir/.lock``, so two daemons starting at once never share a folder nor a number,
even across a minute's turn. In the same critical section ``latest`` is pointed at the
new folder: a relative symlink made under a temporary name and renamed over ``latest``
(``os.replace``), so a reader sees the old link or the new one, never none. A ``latest``
that is not a symlink (a user's file or folder) is never replaced: the flight goes on and
the caller is told why ``latest`` was left alone.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import secrets
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Final

from mkflight.errors import ConfigError

__all__ = [
    "LATEST",
    "LOCK_FILE",
    "NAME_RE",
    "NewFolder",
    "create_flight_folder",
    "flight_folder_name",
    "flight_number",
    "next_flight_number",
    "note_flight_folder",
]

LATEST: Final = "latest"
LOCK_FILE: Final = ".lock"
#: A flight folder's name: the number, the local date and time; a suffix (a replay's
#: ``-replay``) keeps the number.
NAME_RE: Final = re.compile(r"(\d{4,})-(\d{8})-(\d{4})(?:-.*)?")
_MAX_TRIES: Final = 1000


@dataclass(frozen=True, slots=True)
class NewFolder:
    """A flight folder made (or noted) and what became of ``latest``.

    ``latest_problem``: why ``latest`` could not be pointed at a folder it should point
    at, in words naming the path (the flight does not depend on it); None otherwise.
    """

    path: Path
    number: int | None
    latest_updated: bool
    latest_problem: str | None = None


def flight_number(name: str) -> int | None:
    """The flight number of a folder name (``0042-20261126-1057`` -> 42), else None."""
    m = NAME_RE.fullmatch(name)
    return int(m[1]) if m else None


def flight_folder_name(number: int, when: datetime) -> str:
    """``NNNN-YYYYMMDD-HHMM``: the number zero-padded to 4 digits, ``when`` as it is."""
    return f"{number:04d}-{when:%Y%m%d-%H%M}"


def _numbers(log_dir: Path) -> Iterator[tuple[int, str]]:
    """``(number, name)`` of every flight folder (a real directory) in ``log_dir``."""
    with os.scandir(log_dir) as entries:
        for entry in entries:
            number = flight_number(entry.name)
            if number is not None and entry.is_dir(follow_symlinks=False):
                yield number, entry.name


def next_flight_number(log_dir: Path) -> int:
    """1 + the highest flight number in ``log_dir`` (1 in an empty or missing one)."""
    if not log_dir.is_dir():
        return 1
    return 1 + max((n for n, _ in _numbers(log_dir)), default=0)


@contextlib.contextmanager
def _locked(log_dir: Path) -> Iterator[None]:
    """Hold the exclusive lock of ``log_dir`` (``flock`` on its ``.lock`` file)."""
    fd = os.open(log_dir / LOCK_FILE, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _point_latest(log_dir: Path, name: str) -> str | None:
    """Point ``log_dir/latest`` at ``name`` atomically; None, or why it was left alone."""
    latest = log_dir / LATEST
    if os.path.lexists(latest) and not latest.is_symlink():
        return f"{latest} is not a symlink: left alone"
    temp = log_dir / f".{LATEST}-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        os.symlink(name, temp)
        os.replace(temp, latest)
    except OSError as err:
        with contextlib.suppress(OSError):
            temp.unlink()
        return f"{latest}: not updated: {err.strerror or err}"
    return None


def create_flight_folder(
    log_dir: str | Path, now: Callable[[], datetime] | None = None
) -> NewFolder:
    """Make the next numbered flight folder in ``log_dir`` and point ``latest`` at it.

    ``now``: the local wall time (default ``datetime.now()``; a seam for tests). The
    folder is new and empty; ``log_dir`` is made if missing.

    Raises:
        ConfigError: ``log_dir`` (``logging.dir``) cannot be made, locked or listed, or
            no folder can be made in it (the message names the path and the cause).
    """
    base = Path(log_dir)
    clock = now if now is not None else datetime.now
    try:
        base.mkdir(parents=True, exist_ok=True)
        with _locked(base):
            number = next_flight_number(base)
            for _ in range(_MAX_TRIES):
                path = base / flight_folder_name(number, clock())
                try:
                    path.mkdir()
                except FileExistsError:  # a file of that name, or a creator outside the lock
                    number += 1
                    continue
                problem = _point_latest(base, path.name)
                return NewFolder(path, number, problem is None, problem)
    except OSError as err:
        msg = f"logging.dir {str(base)!r}: cannot make a flight folder: {err.strerror or err}"
        raise ConfigError(msg) from err
    msg = f"logging.dir {str(base)!r}: no free flight folder name after {_MAX_TRIES} tries"
    raise ConfigError(msg)


def note_flight_folder(folder: str | Path, log_dir: str | Path) -> NewFolder:
    """A flight folder chosen by the user (``--log-dir``): point ``latest`` at it if it is ours.

    ``latest`` follows only the numbered folders directly in ``log_dir`` (a folder named
    like one of ours, e.g. made by hand with the next number); it is updated when
    ``folder`` is such a folder with at least the highest number there. Any other
    folder is a one-off: ``latest`` is left as it is.
    """
    path = Path(folder)
    number = flight_number(path.name)
    base = Path(log_dir)
    try:
        ours = number is not None and base.is_dir() and path.parent.resolve() == base.resolve()
    except OSError:
        ours = False
    if not ours or number is None:
        return NewFolder(path, number, latest_updated=False)
    try:
        with _locked(base):
            if next_flight_number(base) - 1 > number:
                return NewFolder(path, number, latest_updated=False)
            problem = _point_latest(base, path.name)
    except OSError as err:
        problem = f"{base / LATEST}: not updated: {err.strerror or err}"
    return NewFolder(path, number, problem is None, problem)
