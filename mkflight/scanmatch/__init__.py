"""Laser scan matching: point-to-line ICP (Censi 2008's PL-ICP metric) against keyframes.

Pure code (no I/O apart from the CARMEN log reader in :mod:`mkflight.scanmatch.carmen`):

* :func:`scan_to_points` -- valid beams to points;
* :func:`build_reference` -- a reference scan's line model, sorted by bearing (once per keyframe);
* :func:`match` -- one registration, returning a :class:`MatchResult` with validity,
  quality and a degeneracy flag;
* :class:`KeyframeMatcher` -- tracking over a sequence of scans (laser_scan_matcher's
  keyframe policy, motion prior or constant-velocity prediction).
"""

from __future__ import annotations

from mkflight.scanmatch.carmen import (
    CarmenLog,
    LaserRecord,
    MalformedLine,
    parse_carmen,
    read_carmen,
)
from mkflight.scanmatch.geometry import (
    IDENTITY,
    Pose,
    ReferenceScan,
    between,
    build_reference,
    compose,
    inverse,
    scan_to_points,
    transform_points,
    wrap_angle,
)
from mkflight.scanmatch.icp import MatchResult, match
from mkflight.scanmatch.keyframe import KeyframeMatcher, TrackUpdate

__all__ = [
    "IDENTITY",
    "CarmenLog",
    "KeyframeMatcher",
    "LaserRecord",
    "MalformedLine",
    "MatchResult",
    "Pose",
    "ReferenceScan",
    "TrackUpdate",
    "between",
    "build_reference",
    "compose",
    "inverse",
    "match",
    "parse_carmen",
    "read_carmen",
    "scan_to_points",
    "transform_points",
    "wrap_angle",
]
