"""CARMEN reader: both laser line types, validity, poses, time, malformed lines."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from mkflight.errors import ProtocolError
from mkflight.scanmatch.carmen import MalformedLine, parse_carmen, parse_line, read_carmen

FLASER = "FLASER 4 1.0 2.0 81.83 0.01 0.5 0.6 0.1 0.7 0.8 0.2 12.5 host 12.75"
RL1 = (
    "ROBOTLASER1 0 -2.086214 4.178564 0.006136 5.600 0.010 0 3 1.000 0.000 5.600 "
    "0 0.1 0.2 0.3 0.4 0.5 0.6 0 0 0 0 0 100.000000 synth 100.100000"
)


def test_flaser_fields() -> None:
    rec = parse_line(FLASER, 7)
    assert rec is not None
    assert not isinstance(rec, MalformedLine)
    assert rec.kind == "FLASER"
    assert rec.line_no == 7
    assert rec.t_s == 12.75  # the last field
    assert np.allclose(rec.angles_rad, -math.pi / 2 + np.arange(4) * math.pi / 4)
    assert rec.valid.tolist() == [True, True, False, False]  # >= 80 m, < 2 cm
    assert rec.laser_pose == (0.5, 0.6, 0.1)
    assert rec.robot_pose == (0.7, 0.8, 0.2)


def test_robotlaser1_fields() -> None:
    rec = parse_line(RL1, 3)
    assert rec is not None
    assert not isinstance(rec, MalformedLine)
    assert rec.kind == "ROBOTLASER1"
    assert rec.t_s == pytest.approx(100.1)
    assert np.allclose(rec.angles_rad, -2.086214 + np.arange(3) * 0.006136)
    assert rec.valid.tolist() == [True, False, False]  # 0 = no return, 5.6 = max range
    assert rec.laser_pose == (0.1, 0.2, 0.3)
    assert rec.robot_pose == (0.4, 0.5, 0.6)
    assert rec.max_range_m == 5.6


def test_remissions_are_skipped() -> None:
    line = RL1.replace(" 5.600 0 0.1", " 5.600 2 9.0 9.0 0.1")
    rec = parse_line(line, 1)
    assert rec is not None
    assert not isinstance(rec, MalformedLine)
    assert rec.laser_pose == (0.1, 0.2, 0.3)


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("FLASER 4 1.0 2.0", "FLASER ranges"),
        ("FLASER x 1.0", "beam count"),
        ("FLASER 4 1.0 2.0 abc 0.01 0.5 0.6 0.1 0.7 0.8 0.2 12.5 host 12.75", "not a number"),
        (FLASER + " extra", "must have"),
        (FLASER.replace("12.75", "nan"), "timestamp"),
        (FLASER.replace("0.5 0.6", "inf 0.6"), "non-finite"),
        (RL1.replace(" 3 1.000", " 9 1.000"), "ROBOTLASER1"),
        ("ROBOTLASER1 0 -2.08", "header"),
    ],
)
def test_malformed_lines_are_reported(line: str, reason: str) -> None:
    item = parse_line(line, 42)
    assert isinstance(item, MalformedLine)
    assert item.line_no == 42
    assert reason in item.reason


def test_other_messages_are_skipped_and_bad_lines_do_not_stop_the_rest() -> None:
    lines = ["# comment", "ODOM 0 0 0 0 0 0 1.0 host 1.0", FLASER, "FLASER 2 oops", "", RL1]
    log = parse_carmen(lines)
    assert [r.line_no for r in log.records] == [3, 6]
    assert [m.line_no for m in log.malformed] == [4]


def test_read_plain_and_gzip(tmp_path: Path) -> None:
    text = "\n".join([FLASER, "FLASER 1", RL1]) + "\n"
    plain = tmp_path / "a.log"
    plain.write_text(text)
    packed = tmp_path / "a.log.gz"
    with gzip.open(packed, "wt") as fh:
        fh.write(text)
    for path in (plain, packed):
        log = read_carmen(path)
        assert len(log.records) == 2
        assert [m.line_no for m in log.malformed] == [2]


def test_unreadable_file_raises_protocol_error(tmp_path: Path) -> None:
    with pytest.raises(ProtocolError, match="cannot read CARMEN log"):
        read_carmen(tmp_path / "missing.log")
    bad = tmp_path / "bad.gz"
    bad.write_bytes(b"\x1f\x8bnot really gzip")
    with pytest.raises(ProtocolError, match=r"bad\.gz"):
        read_carmen(bad)
