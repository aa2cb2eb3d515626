"""Structured events (structlog): a readable console on a TTY, JSON lines otherwise.

Events go to stderr so that stdout stays clean for a command's data (``--json`` lines).
They are the operator's log only: the flight folder's ``events.jsonl`` is no sink of
these, but a format of its own (typed records, :mod:`mkflight.logs.events`), written by
:class:`~mkflight.flight.flight_logs.FlightLogs`.

Under systemd (``StandardError=journal``, the default) the lines are JSON, each with its
syslog priority in front (``<4>{"event": ...}``): journald's ``SyslogLevelPrefix=`` strips
the prefix and files the line at that priority, so ``journalctl -p warning -u mkflight``
shows the warnings and errors. The prefix is written only when stderr *is* the journal
(``JOURNAL_STREAM``, systemd.exec(5)); anything else reading stderr gets plain JSON lines.
An exception logged with ``log.exception(...)`` or ``exc_info=`` carries its traceback in
the line's ``exception`` field (the text Python prints).
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any, Final, TextIO

import structlog

LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING}

SYSLOG_PRIORITY: Final = {
    "critical": 2,  # LOG_CRIT
    "error": 3,  # LOG_ERR
    "warning": 4,  # LOG_WARNING
    "info": 6,  # LOG_INFO
    "debug": 7,  # LOG_DEBUG
}
"""structlog level name -> syslog(3) priority, the ``<N>`` journald reads from a line."""


def _stderr_logger(*_args: object) -> structlog.PrintLogger:
    """A logger on whatever ``sys.stderr`` is *now* (a test harness may swap it)."""
    return structlog.PrintLogger(file=sys.stderr)


def on_journal(stream: TextIO, environ: Mapping[str, str] | None = None) -> bool:
    """Whether ``stream`` is connected to the systemd journal.

    systemd.exec(5): a service whose stdout/stderr goes to the journal gets
    ``JOURNAL_STREAM=<device>:<inode>`` (decimal) of that stream. The variable is inherited
    by children whose stderr may be a pipe or a file, so it only counts when it matches
    ``fstat()`` of ``stream`` itself (as sd_journal_stream_fd's users are told to check).
    """
    value = (os.environ if environ is None else environ).get("JOURNAL_STREAM", "")
    device, sep, inode = value.partition(":")
    if not sep or not device.isdigit() or not inode.isdigit():
        return False
    try:
        st = os.fstat(stream.fileno())
    except (OSError, ValueError):  # io.UnsupportedOperation (StringIO) is a ValueError/OSError
        return False
    return (st.st_dev, st.st_ino) == (int(device), int(inode))


def stderr_prefix(level: str) -> str:
    """``<N>`` for a line of ``level`` printed straight to stderr when it is the journal.

    For what the CLI prints itself (its ``error:`` and ``warning:`` lines), so that
    ``journalctl -p err`` shows them as the event lines' priorities do; "" elsewhere.
    """
    return f"<{SYSLOG_PRIORITY[level]}>" if on_journal(sys.stderr) else ""


class _SyslogPrefixed:
    """Wraps a renderer: when the stream is the journal, each line starts with ``<N>``.

    ``<N>`` is the event's syslog priority, the form systemd's ``SyslogLevelPrefix=`` (on
    by default) parses; journald stores the line without it. Every line of a multi-line
    rendering is prefixed, since journald reads each line as its own entry. Whether the
    stream is the journal is checked again whenever the stream object changes (a test
    harness may swap ``sys.stderr`` for a capture that must get plain lines).
    """

    def __init__(self, renderer: structlog.typing.Processor, stream: Callable[[], TextIO]) -> None:
        self._renderer = renderer
        self._stream = stream
        self._checked: TextIO | None = None
        self._journal = False

    def __call__(
        self, logger: Any, method_name: str, event_dict: MutableMapping[str, Any]
    ) -> structlog.typing.ProcessorReturnValue:
        rendered = self._renderer(logger, method_name, event_dict)
        stream = self._stream()
        if stream is not self._checked:
            self._checked, self._journal = stream, on_journal(stream)
        if not self._journal or not isinstance(rendered, str):
            return rendered
        level = str(event_dict.get("level", method_name))
        prefix = f"<{SYSLOG_PRIORITY.get(level, SYSLOG_PRIORITY['info'])}>"
        return "\n".join(prefix + line for line in rendered.split("\n"))


def exception_text(exc: BaseException) -> str:
    """The traceback of ``exc`` as Python prints it, causes included, no trailing newline.

    The same text a JSON event line carries in its ``exception`` field, for a sink that
    is not structlog (the flight folder's ``events.jsonl``: pass it as a field).
    """
    return "".join(traceback.format_exception(exc)).rstrip("\n")


def configure_events(
    level: str = "info", json_lines: bool | None = None, stream: TextIO | None = None
) -> None:
    """Set up structlog once per process.

    Args:
        level: the lowest level shown: ``debug``, ``info`` or ``warning``.
        json_lines: force JSON lines (True) or the console renderer (False); by default
            JSON unless ``stream`` is a terminal (systemd's journal gets JSON).
        stream: where events go (stderr by default). Whether it is the journal (and so
            gets the ``<N>`` priority prefix) is checked on the stream written to.
    """
    out = stream if stream is not None else sys.stderr
    if json_lines is None:
        json_lines = not out.isatty()
    renderer: structlog.typing.Processor
    exceptions: list[structlog.typing.Processor] = []
    if json_lines:
        renderer = structlog.processors.JSONRenderer()
        # format_exc_info, not dict_tracebacks: the traceback as the one string Python
        # prints (causes included, no frame locals), so an operator reads it in
        # `journalctl -o cat` (or `jq -r .exception`) as on a terminal, a tool parses the
        # line with json.loads, and the line stays short of journald's LineMax (frame
        # locals would put arrays and the whole config into it).
        exceptions.append(structlog.processors.format_exc_info)
    else:
        renderer = structlog.dev.ConsoleRenderer(colors=out.isatty())  # its own tracebacks
    if "JOURNAL_STREAM" in os.environ:  # else never the journal: no wrapper, no cost
        renderer = _SyslogPrefixed(renderer, (lambda: out) if stream else (lambda: sys.stderr))
    structlog.configure(
        processors=[
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            *exceptions,
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(LEVELS[level]),
        logger_factory=(
            structlog.PrintLoggerFactory(file=out) if stream is not None else _stderr_logger
        ),
        cache_logger_on_first_use=False,
    )
