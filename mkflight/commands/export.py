"""``mkflight export LOGDIR -o FILE.mcap``: a flight folder as MCAP (Foxglove, ROS 2)."""

from __future__ import annotations

import json

from mkflight.commands.args import DOCUMENT, Command, Subparsers, add_json


def cmd_export(
    *, log_dir: str, out: str, ros2: bool, tables_only: bool, force: bool, as_json: bool
) -> int:
    """Write a flight folder's topics to one MCAP file; print what it holds.

    Args:
        log_dir: the flight folder (SPEC §6), or one with only TABLE III and IV.
        out: the MCAP file.
        ros2: ROS 2 message definitions (CDR) instead of JSON with Foxglove's schemas.
        tables_only: only ``/pose2D``, ``/mikoImu`` and ``/mikoCmd`` (TABLE V-VII).
        force: replace ``out`` if it exists.
        as_json: one object: ``path``, ``size_bytes``, ``counts`` (topic -> messages),
            ``left_out`` (table rows without a time), ``warnings``.

    Raises:
        ConfigError: ``out`` exists (without ``force``) or its folder is missing (exit 2).
        ReplayError: not a flight folder, or a malformed log naming the file (exit 1).
        ExportError: ``mcap`` (``mcap-ros2-support``) is not installed, or the file
            cannot be written (exit 1).
    """
    from mkflight.ground.export import export_flight

    r = export_flight(log_dir, out, ros2=ros2, tables_only=tables_only, force=force)
    if as_json:
        summary = {
            "path": str(r.path),
            "size_bytes": r.size_bytes,
            "encoding": "ros2" if ros2 else "json",
            "counts": r.counts,
            "left_out": r.left_out,
            "warnings": list(r.warnings),
        }
        print(json.dumps(summary))
        return 0
    total = sum(r.counts.values())
    print(f"{r.path}: {total} messages on {len(r.counts)} topics, {r.size_bytes} bytes")
    for topic, n in r.counts.items():
        print(f"  {topic:<12} {n:>7}")
    for name, n in r.left_out.items():
        print(f"  not exported: {n} rows of {name} without a time")
    for warning in r.warnings:
        print(f"  warning: {warning}")
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``export LOGDIR -o FILE.mcap [--ros2] [--tables] [--force]``."""
    p = subparsers.add_parser(
        "export",
        help="write a flight folder as MCAP for Foxglove or ROS 2 (needs the export extra)",
        description="One MCAP file of a flight folder: the original system's /pose2D, "
        f"/mikoImu and /mikoCmd (TABLE V-VII of {DOCUMENT}), /scan from laser.raw, the "
        "estimate, set-points, phases, failsafes, DebugOut, and the truth when present, "
        "each message at its recorded time (the flight clock). JSON with Foxglove's "
        "schemas by default; --ros2 for ROS 2 message definitions. Needs "
        "pip install 'mkflight[export]'.",
    )
    p.add_argument("log_dir", metavar="LOGDIR", help="the flight folder")
    p.add_argument("-o", "--out", metavar="FILE", required=True, help="the MCAP file to write")
    p.add_argument(
        "--ros2",
        action="store_true",
        help="ROS 2 message definitions (sensor_msgs/msg/LaserScan...) for ros2 bag and RViz",
    )
    p.add_argument(
        "--tables",
        dest="tables_only",
        action="store_true",
        help="only the original system's /pose2D, /mikoImu and /mikoCmd (TABLE V-VII)",
    )
    p.add_argument("--force", action="store_true", help="replace FILE if it exists")
    add_json(p, "one JSON object: path, size_bytes, encoding, counts, left_out, warnings")
    p.set_defaults(func=Command(cmd_export))
