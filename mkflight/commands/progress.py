"""A progress bar for long commands: tqdm on stderr when it is a terminal, else nothing."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def tty_bar(total: int, unit: str) -> Iterator[Any | None]:
    """A tqdm bar of ``total`` ``unit``s, closed on the way out; None off a terminal."""
    if not sys.stderr.isatty():
        yield None
        return
    try:
        from tqdm import tqdm  # type: ignore[import-untyped,unused-ignore]
    except ImportError:
        yield None
        return
    bar = tqdm(total=total, unit=unit, file=sys.stderr, leave=False)
    try:
        yield bar
    finally:
        bar.close()
