"""``tools/fuzz.py`` (the long run) at a tiny size: it tries what it was asked and finds nothing."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator

import pytest
import structlog
from fuzz import MUST_BE_ZERO, PassResult, format_table, main, report

TINY = ["--frames", "2000", "--scans", "200", "--pty-frames", "150", "--pty-scans", "30"]


@pytest.fixture(autouse=True)
def _events_untouched() -> Iterator[None]:
    """``main`` sets up structlog as the tool does (warnings on stderr); undo it after."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)


def test_a_tiny_run_tries_what_was_asked_and_every_must_be_0_figure_is_0(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main([*TINY, "--seed", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ok"] is True
    passes = {p["pass"]: p for p in out["passes"]}
    tried = {name: p["tried"] for name, p in passes.items()}
    assert tried == {
        "MK parser": 2000,
        "URG parser": 200,
        "MK link (pty)": 150,
        "URG driver (pty)": 30,
    }
    for name, p in passes.items():
        assert [p[k] for k in MUST_BE_ZERO if p[k]] == [], (name, p["problems"])
        assert p["found"] == p["valid"] > 0, name
        assert p["problems"] == [], name
    assert passes["MK link (pty)"]["out_of_limit_commands"] == 0
    assert passes["MK parser"]["notes"]["crc_errors"] > 0
    assert passes["URG parser"]["notes"]["sum_errors"] > 0


def test_the_table_names_every_pass_and_the_verdict(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--frames", "50", "--scans", "10", "--pty-frames", "5", "--pty-scans", "2"]) == 0
    table = capsys.readouterr().out
    for name in ("MK parser", "URG parser", "MK link (pty)", "URG driver (pty)"):
        assert name in table
    assert "OK: every must-be-0 figure is 0" in table


def test_a_figure_that_is_not_0_fails_the_run() -> None:
    args = argparse.Namespace(seed=1, frames=1, scans=0, pty_frames=0, pty_scans=0)
    bad = PassResult("MK parser", tried=1, valid=1, missed=1)
    out = report(args, [bad, PassResult("URG parser")], 0.1)
    assert out["ok"] is False
    assert "FAILED" in format_table(out)


def test_a_negative_count_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--frames", "-1"])
    assert exit_.value.code == 2
    assert "--frames" in capsys.readouterr().err
