"""A flight recorded before a config key existed replays with what it did then."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec

from mkflight.config import Config
from mkflight.replay.run import BEFORE_THE_KEY, replay_config


def _recorded_without(section: str, key: str) -> dict[str, Any]:
    recorded: dict[str, Any] = msgspec.to_builtins(Config())
    del recorded[section][key]
    return recorded


def test_a_flight_from_before_confirm_every_numbered_every_command() -> None:
    cfg = replay_config(_recorded_without("mk", "confirm_every"), [], Path("old"))
    assert cfg.mk.confirm_every == 1
    assert Config().mk.confirm_every != 1  # the default does otherwise: the table matters


def test_a_recorded_value_and_a_set_win_over_the_table() -> None:
    recorded: dict[str, Any] = msgspec.to_builtins(Config())
    recorded["mk"]["confirm_every"] = 5
    assert replay_config(recorded, [], Path("new")).mk.confirm_every == 5
    old = _recorded_without("mk", "confirm_every")
    assert replay_config(old, ["mk.confirm_every=3"], Path("old")).mk.confirm_every == 3


def test_every_key_of_the_table_is_a_key_of_the_config() -> None:
    defaults: dict[str, Any] = msgspec.to_builtins(Config())
    for section, key in BEFORE_THE_KEY:
        assert key in defaults[section]
