"""The events log (``events.jsonl``): everything not in the two tables (SPEC §6).

Format: JSON lines, UTF-8, one object per event, flushed as written::

    {"t_ns": 1234567890, "event": "failsafe", "action": "land", "cause": "laser stale"}

``t_ns`` is the injected clock's time (nanoseconds, int), ``event`` a short name, then
the event's own fields (builtins only; non-finite floats become ``null``, since strict
JSON has no NaN). A killed process leaves at most a last line without its newline,
which :func:`read_events` drops and reports (``truncated``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from mkflight.errors import ReplayError
from mkflight.logs._file import MAX_JSON_DEPTH, LineFile, read_lines, too_deep

FILE_NAME = "events.jsonl"


@dataclass(frozen=True, slots=True)
class Event:
    """One event: its time, its name and its fields."""

    t_ns: int
    event: str
    fields: dict[str, Any]


def _builtin(obj: Any) -> Any:
    """Numpy scalars (a float64 from an array, say) as the Python values they hold."""
    item = getattr(obj, "item", None)
    if callable(item):
        value = item()
        if isinstance(value, bool | int | float | str):
            return value
    msg = f"cannot write a {type(obj).__name__} into an event"
    raise TypeError(msg)


#: msgspec's encoder: ~7x faster than ``json.dumps`` (an event every step matters in a
#: replay); it writes non-finite floats as ``null`` and keeps the key order.
_ENCODER = msgspec.json.Encoder(enc_hook=_builtin)


class EventsWriter(LineFile):
    """Creates ``events.jsonl`` in a flight folder and appends one line per event."""

    def __init__(self, folder: str | Path, file_name: str = FILE_NAME) -> None:
        super().__init__(Path(folder) / file_name, "utf-8")

    def write(self, t_ns: int, event: str, /, **fields: Any) -> None:
        """Append one event and flush it.

        Raises:
            ValueError: a field named ``t_ns`` or ``event``.
            TypeError: a field value JSON cannot represent.
            RuntimeError: the writer is closed.
        """
        if self.closed:
            msg = f"{self.path}: writer is closed"
            raise RuntimeError(msg)
        if "t_ns" in fields or "event" in fields:
            msg = f"{self.path}: field names t_ns and event are reserved"
            raise ValueError(msg)
        record = {"t_ns": int(t_ns), "event": event, **fields}
        try:
            line = _ENCODER.encode(record)
        except (TypeError, msgspec.EncodeError) as err:  # an object JSON cannot represent
            msg = f"{self.path}: event {event!r}: {err}"
            raise TypeError(msg) from err
        self.write_line(line.decode("utf-8") + "\n")


@dataclass(frozen=True, slots=True)
class EventsData:
    """What :func:`read_events` returns; ``truncated``: a partial last line was dropped."""

    path: Path
    events: list[Event]
    truncated: bool


def read_events(path: str | Path) -> EventsData:
    """Read an events log.

    Raises:
        ReplayError: unreadable file, or a complete line that is not an event object
            with an integer ``t_ns`` and a string ``event`` (or is nested more than
            :data:`~mkflight.logs._file.MAX_JSON_DEPTH` deep); names the file and line.
    """
    path = Path(path)
    lines, truncated = read_lines(path)
    events: list[Event] = []
    for line_no, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as err:
            msg = f"{path}:{line_no}: not JSON: {err.msg}"
            raise ReplayError(msg) from err
        except ValueError as err:  # a number of more than 4300 digits
            msg = f"{path}:{line_no}: cannot decode: {err}"
            raise ReplayError(msg) from err
        except RecursionError as err:  # a line nested thousands deep: not an event
            msg = f"{path}:{line_no}: nested too deeply to be an event"
            raise ReplayError(msg) from err
        # Less, but still too deep for what reads the fields (fewer brackets cannot be).
        if line.count("[") + line.count("{") > MAX_JSON_DEPTH and too_deep(obj):
            msg = f"{path}:{line_no}: nested too deeply to be an event"
            raise ReplayError(msg)
        if not isinstance(obj, dict):
            msg = f"{path}:{line_no}: expected an object, got {type(obj).__name__}"
            raise ReplayError(msg)
        t_ns, name = obj.pop("t_ns", None), obj.pop("event", None)
        if not isinstance(t_ns, int) or isinstance(t_ns, bool) or not isinstance(name, str):
            msg = f"{path}:{line_no}: needs an integer t_ns and a string event"
            raise ReplayError(msg)
        events.append(Event(t_ns, name, obj))
    return EventsData(path, events, truncated)
