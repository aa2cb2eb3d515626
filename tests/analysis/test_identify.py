"""Airframe identification (issue 17, item 3): known airframes, synthetic and simulated."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mkflight.analysis.attitude_fit import MIN_EXCITATION_RAD, fit_attitude
from mkflight.analysis.identify import IdentificationError, identify_flight
from mkflight.config import load_config
from mkflight.errors import ReplayError
from tests.analysis.synthetic_flight import G_MPS2, Airframe, step_responses, write_flight


def _square_wave(t: np.ndarray, amplitude: float, seed: int) -> np.ndarray:
    """Random dwell times of 1-2.5 s at +-amplitude, as the HOLD excitation flies."""
    rng = np.random.default_rng(seed)
    edges = np.cumsum(rng.uniform(1.0, 2.5, 64))
    return amplitude * np.where(np.searchsorted(edges, t) % 2 == 0, 1.0, -1.0)


@pytest.mark.parametrize(
    ("delay_s", "tau_s", "gain", "jitter_s"),
    [(0.1, 0.1, 1.0, 0.004), (0.17, 0.08, 1.2, 0.004), (0.063, 0.21, 0.85, 0.04)],
)
def test_fit_recovers_delay_lag_and_gain(
    delay_s: float, tau_s: float, gain: float, jitter_s: float
) -> None:
    """Exact data (step responses superposed), angle noise: the grid point nearest the truth.

    A jitter of 40 ms makes some rows see two command changes of one delay at once.
    """
    rng = np.random.default_rng(3)
    n = 500
    t = np.cumsum(0.05 + rng.uniform(0.0, jitter_s, n))
    cmd = np.vstack([_square_wave(t, 0.05, 1), _square_wave(t, 0.04, 2)])
    cmd += rng.normal(0.0, 0.005, cmd.shape)
    y = np.vstack([gain * step_responses(t, c, delay_s, tau_s) for c in cmd])
    y += np.array([[0.01], [-0.02]]) + rng.normal(0.0, 0.002, y.shape)
    pitch, roll, both = fit_attitude(t, cmd, y, t > 2.0)
    for fit in (pitch, roll, both):
        assert fit.good, fit.poor
        assert fit.delay_s == pytest.approx(delay_s, abs=0.0051)
        assert fit.tau_s == pytest.approx(tau_s, abs=0.0051)
        assert fit.gain == pytest.approx(gain, rel=0.01)
        assert fit.r2 > 0.99
    assert both.offsets_rad == pytest.approx((0.01, -0.02), abs=0.001)
    assert both.samples == pitch.samples + roll.samples


def test_fit_says_poor_without_excitation() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(400) * 0.053
    still = np.zeros((2, 400))
    y = rng.normal(0.0, 0.002, (2, 400))
    for fit in fit_attitude(t, still, y, t > 1.0):
        assert not fit.good
        assert "never changes" in fit.poor
        assert math.isnan(fit.gain)
    calm = rng.normal(0.0, MIN_EXCITATION_RAD / 4, (2, 400))
    fits = fit_attitude(t, calm, y, t > 1.0)
    assert all("little excitation" in f.poor for f in fits)
    short = fit_attitude(t, np.vstack([_square_wave(t, 0.05, 1)] * 2), y, t > t[-30])
    assert [f.poor.split(";")[0] for f in short] == [
        "only 29 rows (need 100)",
        "only 29 rows (need 100)",
        "only 58 rows (need 100)",  # both axes' rows
    ]


def test_identifies_a_synthetic_flight_folder(tmp_path: Path) -> None:
    """Everything against the truth it was written from, with the flight's config (120)."""
    truth = Airframe()
    ident = identify_flight(write_flight(tmp_path / "f", truth))
    fit = ident.attitude
    assert fit.good, fit.poor
    assert fit.response_s == pytest.approx(truth.delay_s + truth.tau_s, abs=0.006)
    assert fit.gain == pytest.approx(120.0 / truth.fc_counts_per_rad, rel=0.01)
    assert ident.fc_counts_per_rad == pytest.approx(truth.fc_counts_per_rad, rel=0.01)
    assert fit.offsets_rad == pytest.approx(truth.offset_rad, abs=0.001)
    assert ident.hover_gas_counts == pytest.approx(truth.hover_gas, abs=0.5)
    assert ident.hover_voltage_v == 11.8
    assert ident.battery_v == truth.battery_v
    assert ident.vibration_mps2 == pytest.approx(truth.vibration_mps2, rel=0.15)
    counts = (606.3 / 9.81, 603.44 / 9.81, 15.5)
    assert ident.vibration_counts == pytest.approx(
        [v * c for v, c in zip(ident.vibration_mps2, counts, strict=True)]
    )
    # The level frame sees the FC's horizon error: a reported tilt turns the thrust.
    bx, by, bz = truth.bias_mps2
    expected = (bx - G_MPS2 * truth.offset_rad[0], by + G_MPS2 * truth.offset_rad[1], bz)
    assert ident.acc_bias_level_mps2 == pytest.approx(expected, abs=0.02)
    assert 28.0 < ident.hold_s < 31.0
    d = ident.as_dict()
    assert d["attitude"]["good"] is True
    assert d["hover_gas_counts"] == round(ident.hover_gas_counts, 2)


def test_identification_errors(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="not a flight folder"):
        identify_flight(tmp_path / "missing")
    no_hold = write_flight(tmp_path / "takeoff", hold=False)
    with pytest.raises(IdentificationError, match="no HOLD phase"):
        identify_flight(no_hold)
    short = write_flight(tmp_path / "short", seconds=7.0)  # 4-5 s: 1 s of HOLD
    with pytest.raises(IdentificationError, match="too little data"):
        identify_flight(short)
    (short / "imu_50ms.log").unlink()
    with pytest.raises(IdentificationError, match="no TABLE IV rows"):
        identify_flight(short)
    (short / "events.jsonl").write_text("", encoding="utf-8")
    with pytest.raises(IdentificationError, match="no step events"):
        identify_flight(short)


def test_the_flights_own_config_is_used(tmp_path: Path) -> None:
    """The commanded angle is counts / the FLIGHT's counts_per_rad, even from a config of
    another version (a key this one does not know); without flight.json, the defaults."""
    cfg = load_config(None, ["mk.counts_per_rad=110"])
    folder = write_flight(tmp_path / "f", cfg=cfg)
    info_path = folder / "flight.json"
    info = json.loads(info_path.read_text(encoding="utf-8"))
    info["config"]["scanmatch"]["retired_key"] = 1
    info_path.write_text(json.dumps(info), encoding="utf-8")
    ident = identify_flight(folder)
    assert ident.flight_counts_per_rad == 110.0
    assert ident.attitude.gain == pytest.approx(1.1, rel=0.01)
    assert ident.fc_counts_per_rad == pytest.approx(100.0, rel=0.01)
    assert any("only mk and control read" in w for w in ident.warnings)
    info_path.unlink()
    ident = identify_flight(folder)
    assert ident.flight_counts_per_rad == 120.0  # wrong, and said so
    assert any("default configuration assumed" in w for w in ident.warnings)


# Simulated airframes: (delay s, lag s, FC counts/rad, hover gas at 11.8 V).
AIRFRAMES = [(0.15, 0.12, 100.0, 92.0), (0.07, 0.2, 135.0, 110.0)]


def _fly(tmp_path: Path, airframe: tuple[float, float, float, float], excite_m: float) -> Path:
    from mkflight.sim.hover import run_hover  # the simulator loads only for these tests

    delay, tau, cpr, gas = airframe
    cfg = load_config(
        None,
        [
            f"sim.vehicle.attitude_delay_s={delay}",
            f"sim.vehicle.attitude_tau_s={tau}",
            f"sim.vehicle.counts_per_rad={cpr}",
            f"sim.vehicle.hover_gas={gas}",
        ],
    )
    folder = tmp_path / "flight"
    result = run_hover(cfg, duration_s=30.0, seed=5, log_dir=folder, excite_m=excite_m)
    assert result.hold_s > 20.0
    return folder


def _needed_gas(gas_at_hover_v: float, battery_v: float) -> float:
    """The simulated vehicle's hover gas at ``battery_v`` (thrust ∝ gas V²), expressed in
    the flight's model (∝ gas V, normalised to 11.8 V)."""
    return gas_at_hover_v * (11.8 / battery_v) ** 2 * battery_v / 11.8


@pytest.mark.parametrize("airframe", AIRFRAMES)
def test_identifies_a_simulated_airframe(
    tmp_path: Path, airframe: tuple[float, float, float, float]
) -> None:
    delay, tau, cpr, gas = airframe
    ident = identify_flight(_fly(tmp_path, airframe, excite_m=0.2))
    fit = ident.attitude
    assert fit.good, fit.poor
    assert fit.response_s == pytest.approx(delay + tau, abs=0.03)
    assert ident.fc_counts_per_rad == pytest.approx(cpr, rel=0.05)
    assert ident.hover_gas_counts == pytest.approx(_needed_gas(gas, ident.battery_v), abs=2.0)


def test_a_calm_hover_identifies_or_says_poor(tmp_path: Path) -> None:
    """Without excitation the commands barely move: a sensible answer or an honest 'poor'."""
    ident = identify_flight(_fly(tmp_path, AIRFRAMES[0], excite_m=0.0))
    fit = ident.attitude
    if fit.good:
        assert fit.response_s == pytest.approx(0.27, abs=0.05)
        assert ident.fc_counts_per_rad == pytest.approx(100.0, rel=0.1)
    else:
        assert fit.poor
    assert ident.hover_gas_counts == pytest.approx(_needed_gas(92.0, ident.battery_v), abs=2.0)
    assert 0.15 < ident.vibration_mps2[2] < 0.25  # the nominal 0.2 m/s² on AccZ
