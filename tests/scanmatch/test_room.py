"""Room model and ray caster."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.sim.room import Room, box_room, random_room, raycast


def test_box_room_ranges_are_exact() -> None:
    room = box_room(6.0, 4.0)
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, math.pi / 4])
    r = raycast(room, 0.0, 0.0, 0.0, angles, 10.0)
    assert np.allclose(r[:4], [3.0, 2.0, 3.0, 2.0])
    assert math.isclose(r[4], 2.0 * math.sqrt(2.0))


def test_heading_rotates_beams_counter_clockwise() -> None:
    room = box_room(6.0, 4.0)
    r = raycast(room, 1.0, 0.5, math.pi / 2, np.array([0.0]), 10.0)
    assert math.isclose(float(r[0]), 1.5)  # facing +y from y = 0.5, wall at y = 2


def test_obstacles_and_max_range() -> None:
    room = box_room(20.0, 20.0, [(1.0, -0.5, 2.0, 0.5)])
    r = raycast(room, 0.0, 0.0, 0.0, np.array([0.0, math.pi]), 5.6)
    assert math.isclose(float(r[0]), 1.0)
    assert math.isnan(float(r[1]))  # the wall at 10 m is beyond max range


def test_empty_room_is_all_nan() -> None:
    r = raycast(Room(np.empty((0, 4))), 0.0, 0.0, 0.0, np.zeros(3), 5.0)
    assert np.isnan(r).all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_random_rooms_are_seeded_and_closed(seed: int) -> None:
    a, b = random_room(seed), random_room(seed)
    assert np.array_equal(a.walls_m, b.walls_m)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    r = raycast(a, 0.0, 0.0, 0.0, angles, 100.0)
    assert np.isfinite(r).all()  # closed polygon around the origin
    assert (r > 0.05).all()  # obstacles keep clear of the origin
