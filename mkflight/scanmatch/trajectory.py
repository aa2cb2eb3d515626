"""Trajectory files: ``t x y theta`` per line, the scan matcher's output and odometry's input.

Plain text, whitespace-separated, one pose per line: the time (s), x and y (m) and theta
(rad, counter-clockwise) in one frame. ``#`` lines are comments and columns after the
fourth are ignored on reading (a ``.gt.txt`` of the laser set carries more); on writing
every value has 6 decimals, the form ``relpose_eval.py`` scores.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import TextIO

import numpy as np
import numpy.typing as npt

from mkflight.errors import ProtocolError
from mkflight.scanmatch.geometry import Pose


def read_trajectory(path: str | Path) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Read a ``t x y theta`` file into times ``(n,)`` and poses ``(n, 3)``, sorted by t.

    Raises:
        ProtocolError: unreadable file, or a line that is not four finite numbers (named by
            its line number).
    """
    rows: list[tuple[float, float, float, float]] = []
    try:
        with Path(path).open(encoding="utf-8", errors="replace") as fh:
            for line_no, line in enumerate(fh, start=1):
                f = line.split()
                if not f or f[0].startswith("#"):
                    continue
                try:
                    t, x, y, th = (float(v) for v in f[:4])
                except ValueError as err:
                    msg = f"{path}:{line_no}: expected 't x y theta', got {line.strip()!r}"
                    raise ProtocolError(msg) from err
                if not all(math.isfinite(v) for v in (t, x, y, th)):
                    msg = f"{path}:{line_no}: non-finite value"
                    raise ProtocolError(msg)
                rows.append((t, x, y, th))
    except OSError as err:
        msg = f"{path}: cannot read trajectory: {err}"
        raise ProtocolError(msg) from err
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    order = np.argsort(a[:, 0], kind="stable")
    return a[order, 0], a[order, 1:4]


def format_pose_line(t_s: float, pose: Pose) -> str:
    """One ``t x y theta`` line (6 decimals, newline included)."""
    return f"{t_s:.6f} {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f}\n"


def write_trajectory(poses: Iterable[tuple[float, Pose]], fh: TextIO) -> None:
    """Write ``(t_s, pose)`` pairs to ``fh`` as :func:`format_pose_line` lines, in order."""
    for t_s, pose in poses:
        fh.write(format_pose_line(t_s, pose))
