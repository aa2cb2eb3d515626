"""Argument types of the ``mkflight`` command line: numbers checked where they are parsed.

A bad value is an argparse usage error (one ``error:`` line, exit 2), never a traceback.
And :func:`printable`, for what the command line prints that a file it read supplied.
"""

from __future__ import annotations

import argparse
import math


def count(text: str) -> int:
    """A count: an integer >= 0."""
    value = int(text)
    if value < 0:
        msg = f"must be >= 0, got {value}"
        raise argparse.ArgumentTypeError(msg)
    return value


def positive(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        msg = f"expected a number, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None
    if not (math.isfinite(value) and value > 0):
        msg = f"must be a finite number > 0, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative(text: str) -> float:
    """A finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        msg = f"expected a number, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None
    if not (math.isfinite(value) and value >= 0):
        msg = f"must be a finite number >= 0, got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def fraction(text: str) -> float:
    """A fraction in (0, 1]."""
    value = positive(text)
    if value > 1:
        msg = f"must be in (0, 1], got {text}"
        raise argparse.ArgumentTypeError(msg)
    return value


def printable(text: str) -> str:
    r"""``text`` with control characters escaped (``\n``, ``\x1b``): one line, inert.

    Messages and reports quote what a log holds (a config key, a stop reason, a table
    row): a newline in it would split an ``error:`` line, an escape sequence would act on
    the terminal.
    """
    if text.isprintable():
        return text
    return "".join(
        c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text
    )
