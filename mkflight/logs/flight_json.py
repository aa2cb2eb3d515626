"""``flight.json``: one flight's metadata (SPEC §6), rewritten atomically.

Format: one JSON object (UTF-8, indented)::

    {
      "log_format": 1,                              # the flight folder's format version
      "start_utc": "2024-05-01T12:00:00.000000Z",  # ISO 8601, UTC
      "mkflight_version": "0.1.0",
      "fc_version": "0.84a",                        # null until the FC answered
      "config": {...},                              # mkflight.config.config_to_dict
      "config_source": {...},                       # where it came from (may be absent)
      "summary": {...}                              # null until the flight ends
    }

``config_source`` is a :class:`~mkflight.config_search.ConfigSource`: the file the command's
search found (``--config``, ``$MKFLIGHT_CONFIG``, ``/etc/mkflight/config.yaml``) or none,
and the ``--set`` items. It is absent when the writer did not know it (a replay, a
library caller, an older mkflight): an optional key, so the format stays 1.

``summary`` is a :class:`~mkflight.logs.schema.FlightSummary` (the daemon's, told by its
``end_reason`` key) or a :class:`~mkflight.logs.schema.HoverSummary` (``sim hover``'s,
told by ``end``); a summary that fits neither is read as an
:class:`~mkflight.logs.schema.UnknownSummary` holding its fields as read (another
version's; :func:`mkflight.logs.load_flight` warns).

It is written at the start and again with the summary at the end. Each write goes to
a new ``flight.json.tmp`` (created, so never written through a symlink planted under
that name), is fsynced and renamed over ``flight.json``, so a reader never sees a
half-written file. Non-finite floats in the summary (e.g. a precision that could not be
computed) are written as ``null``: strict JSON has no NaN.

``log_format`` versions the whole flight folder (the files, their columns, the events'
fields; SPEC §6): it changes only when a reader of the previous format would misread the
folder. A file without the key is format 1; a reader refuses a format newer
than :data:`LOG_FORMAT` with a :class:`~mkflight.errors.ReplayError` naming the file.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final

import msgspec

import mkflight
from mkflight.config import Config, config_to_dict
from mkflight.config_search import ConfigSource
from mkflight.errors import ReplayError
from mkflight.logs._file import MAX_JSON_DEPTH, read_bytes, too_deep
from mkflight.logs.schema import FlightSummary, HoverSummary, UnknownSummary

FILE_NAME = "flight.json"
LOG_FORMAT: Final = 1
"""The flight-folder format this mkflight writes and reads (absent from a file: 1)."""
_KEYS = ("log_format", "start_utc", "mkflight_version", "fc_version", "config", "summary")
Summary = FlightSummary | HoverSummary | UnknownSummary
"""What ``flight.json``'s summary holds once the flight ended."""
#: A larger file is refused unread: a flight's is a few kB (the config and the summary).
MAX_BYTES: Final = 16 * 1024 * 1024


@dataclass(frozen=True, slots=True)
class FlightInfo:
    """The content of ``flight.json``: the config as plain builtins, the summary typed."""

    start_utc: str
    mkflight_version: str
    fc_version: str | None
    config: dict[str, Any]
    summary: Summary | None = None
    log_format: int = LOG_FORMAT
    config_source: ConfigSource | None = None


def new_flight_info(
    start: datetime,
    cfg: Config,
    fc_version: str | None = None,
    config_source: ConfigSource | None = None,
) -> FlightInfo:
    """The metadata at take-off; ``start`` comes from the caller (no clock read here).

    Raises:
        ValueError: ``start`` is naive (no time zone).
    """
    if start.tzinfo is None:
        msg = f"flight.json: start time {start!r} has no time zone"
        raise ValueError(msg)
    stamp = start.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    config = json.loads(json.dumps(config_to_dict(cfg)))  # as read back: lists, not tuples
    return FlightInfo(stamp, mkflight.__version__, fc_version, config, config_source=config_source)


def with_summary(info: FlightInfo, summary: Summary) -> FlightInfo:
    """The same metadata with the end-of-flight summary."""
    return replace(info, summary=summary)


def summary_from_dict(data: dict[str, Any]) -> Summary:
    """A summary as read: the Struct its keys name, or UnknownSummary if it does not fit."""
    try:
        if "end_reason" in data:
            return msgspec.convert(data, FlightSummary, str_keys=True)
        if "end" in data:
            return msgspec.convert(data, HoverSummary, str_keys=True)
    except msgspec.ValidationError as err:
        return UnknownSummary(data, str(err))
    return UnknownSummary(data, "neither an end_reason nor an end key")


def _scalar(obj: Any) -> Any:
    """A numpy scalar as the Python value it holds (a producer's float64, say)."""
    item = getattr(obj, "item", None)
    if callable(item):
        return item()
    msg = f"cannot write a {type(obj).__name__} into flight.json"
    raise TypeError(msg)


def to_plain(value: Any) -> Any:
    """A summary Struct as builtins in its field order (absent fields left out).

    Other values are returned as they are; non-finite floats stay (:func:`json_safe`).
    """
    if isinstance(value, UnknownSummary):
        return value.fields
    if isinstance(value, msgspec.Struct):
        return msgspec.to_builtins(value, enc_hook=_scalar)
    return value


def json_safe(obj: Any) -> Any:
    """Replace non-finite floats by None, recursively (strict JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    return obj


def write_flight_json(folder: str | Path, info: FlightInfo) -> Path:
    """Write ``folder/flight.json`` atomically (tmp file, fsync, rename); return its path.

    Raises:
        TypeError: a summary value JSON cannot represent.
    """
    path = Path(folder) / FILE_NAME
    tmp = path.with_name(FILE_NAME + ".tmp")
    data = {key: json_safe(to_plain(getattr(info, key))) for key in _KEYS}
    if info.config_source is not None:  # after the config, before the summary
        summary = data.pop("summary")
        data["config_source"] = to_plain(info.config_source)
        data["summary"] = summary
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    # A new file ("x": O_EXCL never follows a symlink), so a link planted in the folder
    # under the tmp name is not written through; one left by a killed write is removed.
    tmp.unlink(missing_ok=True)
    with tmp.open("x", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
    return path


def read_flight_json(path: str | Path) -> FlightInfo:
    """Read a ``flight.json`` (or the one in a flight folder).

    Raises:
        ReplayError: unreadable, not a regular file, larger than :data:`MAX_BYTES`, not
            JSON, nested deeper than any flight.json, a key missing or of the wrong type,
            or a ``log_format`` newer than :data:`LOG_FORMAT`; the message names the file
            and the key.
    """
    path = Path(path)
    if path.is_dir():
        path = path / FILE_NAME
    blob = read_bytes(path, what="flight metadata", max_bytes=MAX_BYTES)
    try:
        data = json.loads(blob.decode("utf-8"))
    except (ValueError, RecursionError) as err:  # not UTF-8, not JSON, 4300+ digits, deep
        msg = f"{path}: cannot read flight metadata: {err}"
        raise ReplayError(msg) from err
    if not isinstance(data, dict):
        msg = f"{path}: expected a JSON object, got {type(data).__name__}"
        raise ReplayError(msg)
    if too_deep(data):
        msg = f"{path}: nested more than {MAX_JSON_DEPTH} deep: not flight metadata"
        raise ReplayError(msg)
    expected: dict[str, tuple[type, ...]] = {
        "start_utc": (str,),
        "mkflight_version": (str,),
        "fc_version": (str, type(None)),
        "config": (dict,),
        "summary": (dict, type(None)),
    }
    log_format = data.setdefault("log_format", 1)  # no key: format 1
    if not isinstance(log_format, int) or isinstance(log_format, bool) or log_format < 1:
        msg = f"{path}: log_format: expected a positive integer, got {log_format!r}"
        raise ReplayError(msg)
    if log_format > LOG_FORMAT:
        msg = (
            f"{path}: log_format {log_format} (written by mkflight "
            f"{data.get('mkflight_version')!s}) is newer than this mkflight "
            f"{mkflight.__version__} reads ({LOG_FORMAT}); upgrade mkflight to read it"
        )
        raise ReplayError(msg)
    for key, types in expected.items():
        if key not in data:
            msg = f"{path}: missing key {key!r}"
            raise ReplayError(msg)
        if not isinstance(data[key], types):
            msg = f"{path}: {key}: unexpected type {type(data[key]).__name__}"
            raise ReplayError(msg)
    summary = data["summary"]
    if summary is not None:
        data["summary"] = summary_from_dict(summary)
    return FlightInfo(**{key: data[key] for key in _KEYS}, config_source=_config_source(path, data))


def _config_source(path: Path, data: dict[str, Any]) -> ConfigSource | None:
    """``config_source`` as read (None when absent or null)."""
    raw = data.get("config_source")
    if raw is None:
        return None
    try:
        return msgspec.convert(raw, ConfigSource)
    except msgspec.ValidationError as err:
        msg = f"{path}: config_source: {err}"
        raise ReplayError(msg) from err
