"""The summary's parts: each producer's plain values fit its Struct, key for key, in order.

``flight_summary`` builds the typed summary from these producers at the end of every
flight; a key one adds or drops must show here, not as a TypeError in a shutdown.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgspec
import pytest

from mkflight.config import Config, load_config
from mkflight.flight.monitor import GcWatch
from mkflight.flight.stats import StepStats
from mkflight.flight.step import FlightCore
from mkflight.flight.summary import _plain
from mkflight.logs.schema import (
    GcStats,
    LaserLinkStats,
    Learned,
    MkLinkStats,
    Timing,
    from_plain,
)
from mkflight.mk.link_types import LinkStats
from mkflight.urg.driver_types import UrgStats


def _same_keys_in_order(cls: type[msgspec.Struct], values: Mapping[str, Any]) -> None:
    typed = from_plain(cls, values)
    assert list(msgspec.to_builtins(typed)) == list(values)
    assert msgspec.to_builtins(typed) == msgspec.to_builtins(dict(values))


@pytest.mark.parametrize(
    ("cls", "values"),
    [
        (Timing, lambda: StepStats().summary()),
        (GcStats, lambda: GcWatch().summary()),
        (MkLinkStats, lambda: LinkStats().summary()),
        (LaserLinkStats, lambda: _plain(UrgStats())),
        (Learned, lambda: FlightCore(Config()).learned()),
        (
            Learned,
            lambda: FlightCore(load_config(None, ["estimation.filter=complementary"])).learned(),
        ),
    ],
    ids=["timing", "gc", "mk_link", "laser_link", "learned-kalman", "learned-complementary"],
)
def test_each_part_fits_its_producer(cls: type[msgspec.Struct], values: Any) -> None:
    _same_keys_in_order(cls, values())


def test_a_key_the_struct_lacks_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        from_plain(GcStats, {**GcWatch().summary(), "young": 3})
