"""The events log (``events.jsonl``): everything not in the two tables (SPEC §6).

Format: JSON lines, UTF-8, one object per event, flushed as written::

    {"t_ns": 1234567890, "event": "failsafe", "action": "LAND", "cause": "laser_stale"}

``t_ns`` is the injected clock's time (nanoseconds, int), ``event`` the kind's name,
then the kind's own fields in the order of its Struct (:mod:`mkflight.logs.schema`, which
lists every kind; non-finite floats become ``null``, since strict JSON has no NaN). A
killed process leaves at most a last line without its newline, which
:func:`read_events` drops and reports (``truncated``).

Reading is tolerant where a newer or older writer may differ and strict where the file
is damaged: a line that is not a JSON object with an integer ``t_ns`` and a string
``event`` is a :class:`~mkflight.errors.ReplayError` naming the file and line; a line of
an unknown kind, or of a known kind whose fields do not fit its Struct, is kept as an
:class:`~mkflight.logs.schema.UnknownEvent` (counted in :attr:`EventsData.warnings`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import msgspec

from mkflight.errors import ReplayError
from mkflight.logs._file import MAX_JSON_DEPTH, LineFile, read_lines, too_deep
from mkflight.logs.schema import KINDS, FlightEvent, KnownEvent, UnknownEvent

FILE_NAME = "events.jsonl"

Event = KnownEvent | UnknownEvent
"""What :func:`read_events` gives for a line."""


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
#: replay); it writes non-finite floats as ``null`` and the fields in the Struct's order.
_ENCODER: Final = msgspec.json.Encoder(enc_hook=_builtin)


def event_json(event: FlightEvent) -> str:
    """One event as its line's JSON (no newline): ``t_ns`` first, then ``event``."""
    return event_line(event)[:-1].decode("utf-8")


def event_line(event: FlightEvent) -> bytes:
    """One event as its line, UTF-8 with its newline: ``t_ns`` first, then ``event``.

    msgspec writes a tagged Struct's tag first (``{"event":"step","t_ns":5,...``); the
    format has ``t_ns`` first, so the ``"event":"<kind>"`` member moves behind it. Neither
    member holds a comma (a kind's name is a word, ``t_ns`` an integer), so each ends at
    the next comma, or ``t_ns`` at the closing brace when no field follows. (On the
    encoded bytes: slices and one join, no decoding.)
    """
    line = _ENCODER.encode(event)
    tag_end = line.index(b",")
    t_end = line.find(b",", tag_end + 1)
    if t_end < 0:
        t_end = len(line) - 1
    return b"".join((b"{", line[tag_end + 1 : t_end], b",", line[1:tag_end], line[t_end:], b"\n"))


class EventsWriter(LineFile):
    """Creates ``events.jsonl`` in a flight folder and appends one line per event."""

    def __init__(self, folder: str | Path, file_name: str = FILE_NAME) -> None:
        super().__init__(Path(folder) / file_name, "utf-8")

    def write(self, event: KnownEvent) -> None:
        """Append one event and flush it.

        Raises:
            TypeError: a field value JSON cannot represent.
            RuntimeError: the writer is closed.
        """
        if self.closed:
            msg = f"{self.path}: writer is closed"
            raise RuntimeError(msg)
        try:
            line = event_line(event)
        except (TypeError, msgspec.EncodeError) as err:  # an object JSON cannot represent
            msg = f"{self.path}: event {event.event!r}: {err}"
            raise TypeError(msg) from err
        self.write_encoded(line)


@dataclass(frozen=True, slots=True)
class EventsData:
    """What :func:`read_events` returns.

    Attributes:
        path: the file read.
        events: every complete line's event, in file order.
        truncated: a partial last line was dropped.
        warnings: one line per kind of :class:`~mkflight.logs.schema.UnknownEvent` read
            (how many, the first one's line and why), naming the file.
    """

    path: Path
    events: list[Event]
    truncated: bool
    warnings: tuple[str, ...] = ()


def _typed(obj: dict[str, Any], t_ns: int, name: str) -> Event:
    """The line's Struct, or an UnknownEvent when the kind is unknown or does not fit."""
    cls = KINDS.get(name)
    if cls is not None:
        try:
            return msgspec.convert(obj, cls, str_keys=True)
        except msgspec.ValidationError as err:
            problem = str(err)
    else:
        problem = ""
    fields = {k: v for k, v in obj.items() if k not in ("t_ns", "event")}
    return UnknownEvent(t_ns, name, fields, problem)


def _unknown_warnings(path: Path, seen: dict[tuple[str, str], list[int]]) -> tuple[str, ...]:
    """One line per (kind, problem): how many, the first one's line, why."""
    out: list[str] = []
    for (name, problem), (line_no, n) in seen.items():
        what = f"{n} {name!r} event{'s' * (n > 1)}"
        why = f"not of the kind's shape: {problem}" if problem else "of a kind not known here"
        out.append(f"{path}:{line_no}: {what} {why}: kept as unknown events")
    return tuple(out)


def read_events(path: str | Path) -> EventsData:
    """Read an events log (module docstring: what is an error, what is kept as unknown).

    Raises:
        ReplayError: unreadable file, or a complete line that is not an event object
            with an integer ``t_ns`` and a string ``event`` (or is nested more than
            :data:`~mkflight.logs._file.MAX_JSON_DEPTH` deep); names the file and line.
    """
    path = Path(path)
    lines, truncated = read_lines(path)
    events: list[Event] = []
    seen: dict[tuple[str, str], list[int]] = {}  # (kind, problem) -> [first line, count]
    for line_no, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        obj, t_ns, name = _parse(line, path, line_no)
        event = _typed(obj, t_ns, name)
        if isinstance(event, UnknownEvent):
            seen.setdefault((name, event.problem), [line_no, 0])[1] += 1
        events.append(event)
    return EventsData(path, events, truncated, _unknown_warnings(path, seen))


def _parse(line: str, path: Path, line_no: int) -> tuple[dict[str, Any], int, str]:
    """One line as a JSON object with its ``t_ns`` and ``event`` checked."""
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
    t_ns, name = obj.get("t_ns"), obj.get("event")
    if not isinstance(t_ns, int) or isinstance(t_ns, bool) or not isinstance(name, str):
        msg = f"{path}:{line_no}: needs an integer t_ns and a string event"
        raise ReplayError(msg)
    return obj, t_ns, name
