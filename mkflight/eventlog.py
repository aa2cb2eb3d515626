"""Structured events (structlog): a readable console on a TTY, JSON lines otherwise.

Events go to stderr so that stdout stays clean for a command's data (``--json`` lines).
The flight daemon adds a file sink for the flight folder's events log.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

import structlog

LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING}


def _stderr_logger(*_args: object) -> structlog.PrintLogger:
    """A logger on whatever ``sys.stderr`` is *now* (a test harness may swap it)."""
    return structlog.PrintLogger(file=sys.stderr)


def configure_events(
    level: str = "info", json_lines: bool | None = None, stream: TextIO | None = None
) -> None:
    """Set up structlog once per process.

    Args:
        level: the lowest level shown: ``debug``, ``info`` or ``warning``.
        json_lines: force JSON lines (True) or the console renderer (False); by default
            JSON unless ``stream`` is a terminal (systemd's journal gets JSON).
        stream: where events go (stderr by default).
    """
    out = stream if stream is not None else sys.stderr
    if json_lines is None:
        json_lines = not out.isatty()
    renderer: structlog.typing.Processor = (
        structlog.processors.JSONRenderer()
        if json_lines
        else structlog.dev.ConsoleRenderer(colors=out.isatty())
    )
    structlog.configure(
        processors=[
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(LEVELS[level]),
        logger_factory=(
            structlog.PrintLoggerFactory(file=out) if stream is not None else _stderr_logger
        ),
        cache_logger_on_first_use=False,
    )
