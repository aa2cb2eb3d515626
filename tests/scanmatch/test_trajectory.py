"""``t x y theta`` trajectory files: written as the matcher writes them, read back."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from mkflight.errors import ProtocolError
from mkflight.scanmatch.trajectory import format_pose_line, read_trajectory, write_trajectory


def test_written_lines_read_back_sorted_to_the_written_precision(tmp_path: Path) -> None:
    poses = [(2.0, (1.0, -2.0, 0.5)), (1.0, (0.1234567, 0.0, -3.1)), (3.5, (0.0, 0.0, 0.0))]
    out = io.StringIO()
    write_trajectory(poses, out)
    assert out.getvalue().splitlines()[1] == "1.000000 0.123457 0.000000 -3.100000"
    path = tmp_path / "traj.txt"
    path.write_text("# t x y theta\n" + out.getvalue())
    t, p = read_trajectory(path)
    np.testing.assert_array_equal(t, [1.0, 2.0, 3.5])
    np.testing.assert_allclose(p[0], (0.123457, 0.0, -3.1), atol=0)
    np.testing.assert_allclose(p[1], (1.0, -2.0, 0.5), atol=0)


def test_format_pose_line_has_six_decimals_and_a_newline() -> None:
    assert format_pose_line(0.5, (1.0, 2.0, 3.0)) == "0.500000 1.000000 2.000000 3.000000\n"


def test_a_bad_line_is_named_by_its_number(tmp_path: Path) -> None:
    path = tmp_path / "traj.txt"
    path.write_text("1 0 0 0\n2 0 x 0\n")
    with pytest.raises(ProtocolError, match=r"traj\.txt:2: expected 't x y theta'"):
        read_trajectory(path)
    path.write_text("1 0 0 nan\n")
    with pytest.raises(ProtocolError, match=r"traj\.txt:1: non-finite value"):
        read_trajectory(path)
