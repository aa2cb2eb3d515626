"""The pilot's stick override (safety/pilot.py, SPEC §5)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mkflight.mk.messages import Ppm
from mkflight.safety.pilot import CH_NICK, CH_ROLL, CH_YAW, PilotWatch


def _ppm(nick: int = 0, roll: int = 0, yaw: int = 0, gas: int = 80) -> Ppm:
    return Ppm.from_channels({1: gas, CH_ROLL: roll, CH_NICK: nick, CH_YAW: yaw})


def test_the_first_answer_is_the_baseline_and_a_moved_stick_latches() -> None:
    watch = PilotWatch(threshold_counts=25)
    assert not watch.update(_ppm(nick=3, roll=-2))  # trims: the baseline, not a movement
    assert not watch.update(_ppm(nick=20, roll=-20))  # within 25 of the baseline
    assert watch.update(_ppm(nick=40))  # 37 from the baseline
    assert watch.moved == {CH_NICK: 40}
    assert watch.update(_ppm(nick=3, roll=-2))  # back to centre: still the pilot's


def test_gas_alone_is_not_an_override() -> None:
    """The gas stick caps extern gas in the FC itself; moving it does not release."""
    watch = PilotWatch(threshold_counts=25)
    watch.update(_ppm(gas=80))
    assert not watch.update(_ppm(gas=-100))


@given(st.integers(-25, 25), st.integers(-25, 25), st.integers(-25, 25))
def test_within_the_threshold_never_overrides(dn: int, dr: int, dy: int) -> None:
    watch = PilotWatch(threshold_counts=25)
    watch.update(_ppm(nick=10, roll=-10, yaw=5))
    assert not watch.update(_ppm(nick=10 + dn, roll=-10 + dr, yaw=5 + dy))
