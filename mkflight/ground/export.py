"""A flight folder as one MCAP file, for Foxglove, the ``mcap`` tools and ROS 2 bags.

What goes on which topic, with which fields, from which record, and on which clock:
:mod:`mkflight.ground.export_series`. In short: the original system's ``/pose2D``,
``/mikoImu`` and ``/mikoCmd`` (TABLE V-VII of the 2011 QUT CyPhy MikroKopter
documentation) from TABLE III, TABLE IV and the ExternControls written; ``/scan`` from
``laser.raw``; the estimate, set-points, phases, failsafes, DebugOut and ``truth`` from
the rest. Every message's ``log_time`` and ``publish_time`` (and its ``timestamp`` or
``header.stamp``) are the flight clock's ``t_ns`` of the record it comes from (host
monotonic on the vehicle, the simulator's clock in ``sim hover``; nominal times from 0 for
a folder of the two tables alone). A scan is logged when it was read and stamped when it
was taken, as a ROS driver does.

Encodings:

- default: JSON messages with JSON Schemas (:mod:`mkflight.ground.export_json`), Foxglove's
  ``foxglove.LaserScan``, ``foxglove.PoseInFrame`` and ``foxglove.FrameTransform`` for the
  scan, the poses and the frames. Written with the ``mcap`` library's writer rather than the
  Foxglove SDK's (protobuf): the file then decodes with any MCAP reader and ``json`` alone
  (no protobuf runtime, here or in a lab's scripts), and one writer library serves both
  encodings. The Foxglove app draws Foxglove's schemas in JSON as it does in protobuf; the
  size JSON costs is mostly won back by the chunks' zstd compression.
- ``--ros2``: ROS 2 message definitions, CDR (:mod:`mkflight.ground.ros2_msgs`), with
  ``mcap-ros2-support``'s writer: ``ros2 bag play FILE.mcap`` plays it.

The file is written beside its destination under a temporary name and renamed into place
when whole: a failed export leaves no half file, and an existing file is replaced only
when asked (``force``).
"""

from __future__ import annotations

import contextlib
import heapq
import os
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from mkflight import __version__
from mkflight.errors import ConfigError, MkflightError

if TYPE_CHECKING:
    from mkflight.ground.export_series import Scans, Series
    from mkflight.logs.flight import FlightData

__all__ = ["ExportError", "ExportResult", "ensure_writers", "export_flight", "write_mcap"]

INSTALL_HINT = "pip install 'mkflight[export]'"
#: The MCAP ``library`` field of the files written.
LIBRARY = f"mkflight/{__version__}"


class ExportError(MkflightError):
    """The MCAP file cannot be written (exit 1); names the file."""


@dataclass(frozen=True, slots=True)
class ExportResult:
    """What an export wrote.

    Attributes:
        path: the MCAP file.
        counts: messages per topic, in the order written.
        size_bytes: the file's size.
        left_out: table rows without a time, not exported, by file name.
        warnings: :func:`~mkflight.logs.load_flight`'s (a cut-short tail...).
    """

    path: Path
    counts: dict[str, int]
    size_bytes: int
    left_out: dict[str, int]
    warnings: tuple[str, ...]


def ensure_writers(*, ros2: bool) -> None:
    """Import the MCAP writer the encoding needs, or raise :class:`ExportError` naming it."""
    try:
        if ros2:
            import mcap_ros2.writer  # noqa: F401
        else:
            import mcap.writer  # noqa: F401
    except ImportError as err:
        package = "mcap-ros2-support" if ros2 else "mcap"
        msg = f"the export needs {package}, which is not installed: {INSTALL_HINT}"
        raise ExportError(msg) from err


def check_target(out: Path, *, force: bool) -> None:
    """The destination can be written: its folder exists; it is new or ``force``.

    Raises:
        ConfigError: it exists and not ``force``, it is a folder, or its folder is missing.
    """
    if out.is_dir():
        msg = f"{out}: is a directory; give a file name, e.g. {out / 'flight.mcap'}"
        raise ConfigError(msg)
    if os.path.lexists(out) and not force:
        msg = f"{out}: exists (--force replaces it)"
        raise ConfigError(msg)
    if not out.parent.is_dir():
        msg = f"{out.parent}: no such directory"
        raise ConfigError(msg)


def _messages(series: Sequence[Series]) -> Iterator[tuple[int, int, int]]:
    """``(t_ns, series number, row)`` of every message, in time order (ties: topic order)."""
    return heapq.merge(*(_numbered(k, s) for k, s in enumerate(series)))


def _numbered(k: int, series: Series) -> Iterator[tuple[int, int, int]]:
    for i, t_ns in enumerate(series.t_ns.tolist()):
        yield t_ns, k, i


def _write_json(f: IO[bytes], series: Sequence[Series]) -> None:
    from mcap.writer import Writer

    from mkflight.ground.export_json import json_message, json_schema

    writer = Writer(f)
    writer.start(profile="", library=LIBRARY)
    schemas: dict[str, int] = {}
    channels: list[int] = []
    for s in series:
        if s.kind not in schemas:
            name, data = json_schema(s.kind)
            schemas[s.kind] = writer.register_schema(name, "jsonschema", data)
        channels.append(writer.register_channel(s.topic, "json", schemas[s.kind]))
    for t_ns, k, i in _messages(series):
        s = series[k]
        data = json_message(s.kind, s.row(i), t_ns)
        writer.add_message(channels[k], log_time=t_ns, data=data, publish_time=t_ns, sequence=i)
    writer.finish()  # type: ignore[no-untyped-call]


def _write_ros2(f: IO[bytes], series: Sequence[Series]) -> None:
    from mcap_ros2.writer import Writer

    from mkflight.ground.ros2_msgs import TYPE_NAMES, msgdef, ros2_message

    writer = Writer(f)
    schemas: dict[str, Any] = {}
    for s in series:
        if s.kind not in schemas:
            schemas[s.kind] = writer.register_msgdef(*msgdef(TYPE_NAMES[s.kind]))
    for t_ns, k, i in _messages(series):
        s = series[k]
        message = ros2_message(s.kind, s.row(i), t_ns)
        writer.write_message(s.topic, schemas[s.kind], message, t_ns, t_ns, sequence=i)
    writer.finish()  # type: ignore[no-untyped-call]


def write_mcap(out: Path, series: Sequence[Series], *, ros2: bool, force: bool) -> int:
    """Write ``series`` to ``out`` through a temporary file in its folder; its size.

    Raises:
        ConfigError: ``out`` exists and not ``force`` (checked again at the rename).
        ExportError: the file cannot be written (the disk, permissions).
    """
    check_target(out, force=force)
    tmp: Path | None = None
    try:
        with tempfile.NamedTemporaryFile(
            dir=out.parent, prefix=f".{out.name}.", suffix=".tmp", delete=False
        ) as f:
            tmp = Path(f.name)
            (_write_ros2 if ros2 else _write_json)(f, series)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # as an open() would have made it
        _place(tmp, out, force=force)
        tmp = None
        return out.stat().st_size
    except FileExistsError as err:
        msg = f"{out}: exists (--force replaces it)"
        raise ConfigError(msg) from err
    except OSError as err:
        msg = f"{out}: cannot write: {err.strerror or err}"
        raise ExportError(msg) from err
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _place(tmp: Path, out: Path, *, force: bool) -> None:
    """Rename the whole file ``tmp`` to ``out``; without ``force``, never over a file.

    Raises:
        FileExistsError: ``out`` exists and not ``force``.
    """
    if force:
        os.replace(tmp, out)
        return
    try:
        os.link(tmp, out)  # atomic, and fails if out appeared meanwhile
    except FileExistsError:
        raise
    except OSError:  # a file system without hard links (FAT, some network shares)
        if os.path.lexists(out):
            raise FileExistsError(out) from None
        os.replace(tmp, out)
        return
    tmp.unlink()


def _scans(flight: FlightData) -> Scans | None:
    """The flight's scans (``laser.raw``), the beams of its scan plane; None without one."""
    scans = flight.laser_scans
    return None if scans is None else scans.only_steps(*scans.scan_steps)


def export_flight(
    log_dir: str | Path,
    out: str | Path,
    *,
    ros2: bool = False,
    tables_only: bool = False,
    force: bool = False,
) -> ExportResult:
    """Export one flight folder to ``out`` (module docstring).

    Args:
        log_dir: the flight folder, or a folder with only TABLE III and IV.
        out: the MCAP file to write.
        ros2: ROS 2 message definitions (CDR) instead of JSON.
        tables_only: only the original system's ``/pose2D``, ``/mikoImu``, ``/mikoCmd``.
        force: replace ``out`` if it exists.

    Raises:
        ConfigError: ``out`` exists (and not ``force``), or its folder is missing (exit 2).
        ReplayError: not a flight folder, or a malformed log naming the file (exit 1).
        ExportError: the writer is not installed, or the file cannot be written (exit 1).
    """
    from mkflight.ground.export_series import flight_series, left_out
    from mkflight.logs.flight import load_flight

    target = Path(out)
    ensure_writers(ros2=ros2)  # the likeliest failures first, before the work
    check_target(target, force=force)
    flight = load_flight(log_dir)
    scans = None if tables_only else _scans(flight)
    series = flight_series(flight, scans, tables_only=tables_only)
    size = write_mcap(target, series, ros2=ros2, force=force)
    return ExportResult(
        path=target,
        counts={s.topic: len(s) for s in series},
        size_bytes=size,
        left_out=left_out(flight),
        warnings=flight.warnings,
    )
