"""Event lines an operator can use (issue 18): tracebacks in JSON, syslog priorities.

In JSON mode an exception's stack is the line's ``exception`` field; under systemd each
line starts with ``<N>``, its syslog priority, which journald's ``SyslogLevelPrefix=``
parses; anywhere else (a pipe a test or a tool reads) the lines stay plain JSON.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from mkflight.eventlog import configure_events, exception_text, on_journal
from mkflight.logs.events import FILE_NAME, EventsWriter, read_events
from mkflight.logs.schema import Crash, Ready

CHILD = """
import structlog
from mkflight.eventlog import configure_events
configure_events("info")  # as the CLI: JSON because stderr is not a terminal
log = structlog.get_logger()
log.debug("hidden")
log.info("started", port="/dev/ttyUSB0")
log.warning("battery low", battery_v=10.9)
log.error("link lost")
try:
    {}["gas"]
except KeyError:
    log.exception("step crashed")
log.critical("gave up")
"""

EVENTS = ["started", "battery low", "link lost", "step crashed", "gave up"]


@pytest.fixture
def restore_structlog() -> Iterator[None]:
    """Tests here configure structlog in-process; put the previous setup back after."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)


def _run_child(journal_stream: str | None) -> list[str]:
    """Run :data:`CHILD` with stderr on a pipe; ``"pipe"`` points JOURNAL_STREAM at it."""
    read_fd, write_fd = os.pipe()
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    if journal_stream == "pipe":
        st = os.fstat(write_fd)
        env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
    elif journal_stream is not None:
        env["JOURNAL_STREAM"] = journal_stream
    try:
        proc = subprocess.Popen(
            [sys.executable, "-c", CHILD], stderr=write_fd, stdout=subprocess.DEVNULL, env=env
        )
    finally:
        os.close(write_fd)
    with os.fdopen(read_fd, encoding="utf-8") as err:
        text = err.read()
    assert proc.wait(timeout=30) == 0, text
    return text.splitlines()


def test_on_the_journal_each_line_starts_with_its_syslog_priority() -> None:
    lines = _run_child("pipe")
    assert [line[:3] for line in lines] == ["<6>", "<4>", "<3>", "<3>", "<2>"]
    objects = [json.loads(line[3:]) for line in lines]  # the rest is one JSON object
    assert [o["event"] for o in objects] == EVENTS
    assert objects[1]["battery_v"] == 10.9
    assert objects[3]["level"] == "error"
    assert "KeyError: 'gas'" in objects[3]["exception"]


@pytest.mark.parametrize(
    "journal_stream",
    [None, "1:2", "garbage", ""],
    ids=["unset", "another-stream", "malformed", "empty"],
)
def test_elsewhere_lines_are_plain_json(journal_stream: str | None) -> None:
    """No prefix unless JOURNAL_STREAM names stderr itself: a child of the daemon whose
    stderr is a pipe inherits the variable, and its reader parses lines with json.loads."""
    objects = [json.loads(line) for line in _run_child(journal_stream)]
    assert [o["event"] for o in objects] == EVENTS


def test_on_journal_compares_device_and_inode(tmp_path: Path) -> None:
    with (tmp_path / "f").open("w") as f:
        st = os.fstat(f.fileno())
        assert on_journal(f, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})
        assert not on_journal(f, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino + 1}"})
        assert not on_journal(f, {"JOURNAL_STREAM": f"{st.st_dev}"})
        assert not on_journal(f, {})
    assert not on_journal(io.StringIO(), {"JOURNAL_STREAM": "1:2"})  # no file descriptor


def _boom() -> None:
    try:
        int("x")
    except ValueError as err:
        msg = "cannot parse the gas stick"
        raise RuntimeError(msg) from err


def test_json_lines_carry_the_traceback(restore_structlog: None) -> None:
    out = io.StringIO()
    configure_events("info", json_lines=True, stream=out)
    log = structlog.get_logger()
    try:
        _boom()
    except RuntimeError as err:
        log.exception("step crashed", task="mk-step")
        log.error("with exc_info", exc_info=err)
    log.error("no exception here", exc_info=False)
    first, second, third = (json.loads(line) for line in out.getvalue().splitlines())
    for obj in (first, second):
        text = obj["exception"]
        assert text.startswith("Traceback (most recent call last):")
        assert "in _boom" in text  # the stack's frames
        assert "ValueError: invalid literal for int()" in text  # the cause
        assert "direct cause of the following exception" in text
        assert text.endswith("RuntimeError: cannot parse the gas stick")
    assert first["task"] == "mk-step"
    assert "exc_info" not in first
    assert "exception" not in third


def test_the_console_keeps_its_readable_traceback(restore_structlog: None) -> None:
    out = io.StringIO()
    configure_events("info", json_lines=False, stream=out)
    try:
        _boom()
    except RuntimeError:
        structlog.get_logger().exception("step crashed")
    text = out.getvalue()
    assert "step crashed" in text
    assert "RuntimeError" in text
    assert "cannot parse the gas stick" in text
    assert not text.lstrip().startswith("{")
    assert "<3>" not in text


def test_an_exception_in_the_events_log_reads_back(tmp_path: Path) -> None:
    """The flight folder's sink is not structlog: a crash event passes the text as a
    field, and the reader (a replay's) takes it like any other string field."""
    try:
        _boom()
    except RuntimeError as err:
        exc = err
    with EventsWriter(tmp_path) as w:
        w.write(Ready(t_ns=1))
        w.write(Crash(t_ns=2, task="mk-step", error=repr(exc), exception=exception_text(exc)))
    ready, crash = read_events(tmp_path / FILE_NAME).events
    assert ready == Ready(t_ns=1)
    assert isinstance(crash, Crash)
    assert crash.error == repr(exc)
    assert isinstance(crash.exception, str)
    assert crash.exception.splitlines()[-1] == "RuntimeError: cannot parse the gas stick"
    assert "in _boom" in crash.exception


@pytest.mark.parametrize("journal", [True, False])
def test_the_cli_error_line_carries_the_error_priority_on_the_journal(
    journal: bool, tmp_path: Path
) -> None:
    """``error:`` lines are printed by the CLI itself, not structlog: ``<3>`` on the journal."""
    read_fd, write_fd = os.pipe()
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    if journal:
        st = os.fstat(write_fd)
        env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "mkflight", "replay", str(tmp_path / "nothing")],
            stderr=write_fd,
            stdout=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
            env=env,
        )
    finally:
        os.close(write_fd)
    with os.fdopen(read_fd, encoding="utf-8") as err:
        lines = err.read().splitlines()
    assert proc.wait(timeout=60) == 1
    assert lines[-1].startswith("<3>error: " if journal else "error: "), lines
