"""The attitude's horizontal acceleration, corrected by the accelerometers' view of the rest."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mkflight.estimation.tilt_accel import TiltAcceleration, tilt_acceleration
from mkflight.frames import level_acceleration

G = 9.81
STEP_NS = 53_248_000


@pytest.mark.parametrize(("pitch", "roll"), [(0.1, 0.0), (0.0, -0.12), (0.2, 0.15), (-0.05, 0.3)])
def test_a_hovering_vehicle_accelerates_as_its_thrust_points(pitch: float, roll: float) -> None:
    """Hover thrust g/(cos θ cos φ) along body -z: the specific force a vehicle holding its
    height measures, through the estimator's own level-frame rotation (SPEC §3)."""
    thrust = G / (math.cos(pitch) * math.cos(roll))
    expected = level_acceleration(0.0, 0.0, -thrust, pitch, roll, G)
    assert expected[2] == pytest.approx(0.0, abs=1e-9)  # height held
    assert tilt_acceleration(pitch, roll, G) == pytest.approx(expected[:2])
    ax, ay = tilt_acceleration(0.1, 0.1, G)
    assert ax < 0.0 < ay  # nose up: backwards; right side down: to the right


def run(
    tilt: TiltAcceleration,
    seconds: float,
    *,
    gust: float = 0.0,
    noise: float = 0.0,
    pitch: float = 0.0,
    seed: int = 0,
) -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(seed)
    out = []
    ax_tilt, ay_tilt = tilt_acceleration(pitch, 0.0, G)
    for k in range(round(seconds * 1e9 / STEP_NS)):
        measured = (ax_tilt + gust + float(rng.normal(0.0, noise)), ay_tilt, 0.7)
        out.append(tilt.blend((k + 1) * STEP_NS, measured, pitch, 0.0))
    return out


def test_a_lasting_push_the_attitude_misses_is_followed() -> None:
    tilt = TiltAcceleration(G)
    blended = run(tilt, 2.0, gust=0.2, pitch=0.05)
    assert blended[-1][0] == pytest.approx(tilt_acceleration(0.05, 0.0, G)[0] + 0.2, abs=0.01)
    assert blended[-1][2] == 0.7  # z: the accelerometer as it is


def test_vibration_is_mostly_kept_out() -> None:
    """A worn prop's 0.45 m/s² per sample, known to the filter: half of it at most gets through."""
    tilt = TiltAcceleration(G)
    tilt.set_noise(0.45, 0.45, 0.45)
    blended = np.array([b[0] for b in run(tilt, 60.0, noise=0.45, seed=3)])
    assert float(np.std(blended[20:])) < 0.45 / 2


def test_the_turbulence_is_the_disturbance_less_its_lasting_part() -> None:
    tilt = TiltAcceleration(G)
    run(tilt, 60.0, gust=0.3)  # a steady draught (or an accelerometer offset)
    assert tilt.disturbance_mps2[0] == pytest.approx(0.3, abs=0.01)
    assert tilt.turbulence_mps2[0] == pytest.approx(0.0, abs=0.01)


ANY = st.floats(-50.0, 50.0)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(ANY, ANY, st.floats(-1.4, 1.4), st.floats(-1.4, 1.4)), max_size=40))
def test_the_output_stays_finite(steps: list[tuple[float, float, float, float]]) -> None:
    tilt = TiltAcceleration(G)
    for k, (ax, ay, pitch, roll) in enumerate(steps):
        out = tilt.blend((k + 1) * STEP_NS, (ax, ay, 0.0), pitch, roll)
        assert all(math.isfinite(v) for v in out)
