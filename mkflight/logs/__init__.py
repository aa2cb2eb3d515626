"""Flight logs (SPEC §6): one module per format, reader and writer together.

* :mod:`~mkflight.logs.table3` -- ``laser_100ms.log`` (TABLE III of the 2011 QUT CyPhy
  MikroKopter documentation, 10 columns).
* :mod:`~mkflight.logs.table4` -- ``imu_50ms.log`` (its TABLE IV, 14 columns).
* :mod:`~mkflight.logs.flight_json` -- ``flight.json`` (start, versions, config, summary).
* :mod:`~mkflight.logs.events` -- ``events.jsonl`` (everything else, JSON lines).
* :mod:`~mkflight.logs.schema` -- the typed records: one Struct per event kind, and
  ``flight.json``'s summary (the README's schema section is generated from them).
* :mod:`~mkflight.logs.flight` -- :func:`load_flight`: a whole folder as numpy arrays
  with named columns, for your own analysis.
* :mod:`~mkflight.logs.scans` -- :func:`read_scans`: every scan of ``laser.raw``, decoded
  as the driver decoded it, with its scan event's pose.
* :mod:`~mkflight.logs.folders` -- numbered flight folders (``0042-20261126-1057``) and
  the ``latest`` link; :mod:`~mkflight.logs.flight_list` -- ``mkflight flights``' records.

Writers create their file in a flight folder and flush every row; readers raise
:class:`mkflight.errors.ReplayError` naming the file and line, and drop (and report) a
last line cut short by a killed process.
"""

from __future__ import annotations

from mkflight.logs._table import TableData
from mkflight.logs.events import Event, EventsData, EventsWriter, read_events
from mkflight.logs.flight import (
    FlightData,
    event_table,
    extern_control_frames,
    extern_controls,
    load_flight,
)
from mkflight.logs.flight_json import (
    LOG_FORMAT,
    FlightInfo,
    new_flight_info,
    read_flight_json,
    with_summary,
    write_flight_json,
)
from mkflight.logs.scans import ScanLog, read_scans
from mkflight.logs.schema import (
    KINDS,
    FlightEvent,
    FlightSummary,
    HoverSummary,
    KnownEvent,
    UnknownEvent,
    UnknownSummary,
)
from mkflight.logs.table3 import Table3Row, Table3Writer, read_table3
from mkflight.logs.table4 import Table4Row, Table4Writer, read_table4

__all__ = [
    "KINDS",
    "LOG_FORMAT",
    "Event",
    "EventsData",
    "EventsWriter",
    "FlightData",
    "FlightEvent",
    "FlightInfo",
    "FlightSummary",
    "HoverSummary",
    "KnownEvent",
    "ScanLog",
    "Table3Row",
    "Table3Writer",
    "Table4Row",
    "Table4Writer",
    "TableData",
    "UnknownEvent",
    "UnknownSummary",
    "event_table",
    "extern_control_frames",
    "extern_controls",
    "load_flight",
    "new_flight_info",
    "read_events",
    "read_flight_json",
    "read_scans",
    "read_table3",
    "read_table4",
    "with_summary",
    "write_flight_json",
]
