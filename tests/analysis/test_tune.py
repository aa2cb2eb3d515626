"""The tuning rule, the tuned config file and ``mkflight tune`` (issue 17, item 3)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import pytest
import yaml

from mkflight.analysis.attitude_fit import AttitudeFit
from mkflight.analysis.identify import Identification
from mkflight.analysis.tune import (
    MAX_GAIN_FACTOR,
    NOMINAL_NOISE_Z_MPS2,
    NOMINAL_RESPONSE_S,
    SLOW_RESPONSE_S,
    time_stretch,
    tuned_overrides,
    write_tuned_config,
)
from mkflight.cli import main
from mkflight.config import Config, load_config
from mkflight.errors import ConfigError
from tests.analysis.synthetic_flight import Airframe, write_flight

NOW = datetime(2026, 11, 26, 12, 0, tzinfo=UTC)


def _fit(
    delay_s: float = 0.1, tau_s: float = 0.1, gain: float = 1.0, poor: str = ""
) -> AttitudeFit:
    return AttitudeFit("both", delay_s, tau_s, gain, (0.0, 0.0), 0.99, 0.002, 1000, 0.05, poor)


def _ident(
    fit: AttitudeFit | None = None, hover_gas: float = 96.0, noise_z: float = NOMINAL_NOISE_Z_MPS2
) -> Identification:
    fit = fit or _fit()
    return Identification(
        log_dir="flight",
        hold_s=30.0,
        hold_steps=560,
        pitch=replace(fit, axis="pitch"),
        roll=replace(fit, axis="roll"),
        attitude=fit,
        flight_counts_per_rad=120.0,
        fc_counts_per_rad=120.0 / fit.gain,
        hover_gas_counts=hover_gas,
        hover_voltage_v=11.8,
        hover_gas_steps=500,
        battery_v=12.1,
        vibration_mps2=(0.2, 0.2, noise_z),
        vibration_counts=(12.4, 12.3, noise_z * 15.5),
        vibration_z_raw_mps2=noise_z * 1.3,
        acc_bias_level_mps2=(0.0, 0.0, 0.0),
    )


def _as_dict(items: list[str]) -> dict[str, float]:
    return {k: float(v) for k, v in (item.split("=") for item in items)}


D = Config().control
KZ = Config().estimation.filter_gain_z_per_s
COMPLEMENTARY = load_config(None, ["estimation.filter=complementary"])


def test_the_nominal_airframe_keeps_the_defaults() -> None:
    tuned = _as_dict(tuned_overrides(_ident(), Config()))
    assert tuned == {
        "mk.counts_per_rad": 120.0,
        "control.kp_xy": D.kp_xy,
        "control.ki_xy": D.ki_xy,
        "control.kp_vxy": D.kp_vxy,
        "control.ki_vxy": D.ki_vxy,
        "control.hover_gas": 96.0,
    }
    complementary = load_config(None, ["estimation.filter=complementary"])
    tuned = _as_dict(tuned_overrides(_ident(), complementary))
    assert tuned["estimation.filter_gain_z_per_s"] == KZ


@pytest.mark.parametrize(
    ("response_s", "stretch"),
    [(0.1, 0.5), (0.16, 0.8), (0.2, 1.0), (0.27, 1.0), (0.3, 1.0), (0.45, 1.5), (0.6, 2.0)],
)
def test_the_time_stretch(response_s: float, stretch: float) -> None:
    """Faster than T0: scaled from T0; up to T_slow: the defaults; slower: from T_slow."""
    assert time_stretch(response_s) == pytest.approx(stretch)
    assert time_stretch(NOMINAL_RESPONSE_S) == time_stretch(SLOW_RESPONSE_S) == 1.0


def test_a_slow_airframe_scales_the_gains_by_their_units() -> None:
    """T = 0.45 s, T_slow = 0.3 s: 1/s gains by 1/1.5, 1/s² gains by 1/2.25."""
    ident = _ident(_fit(0.25, 0.2, gain=1.2))
    tuned = _as_dict(tuned_overrides(ident, Config()))
    assert tuned["mk.counts_per_rad"] == 100.0
    assert tuned["control.kp_xy"] == pytest.approx(D.kp_xy / 1.5, abs=1e-4)
    assert tuned["control.kp_vxy"] == pytest.approx(D.kp_vxy / 1.5, abs=1e-4)
    assert tuned["control.ki_xy"] == pytest.approx(D.ki_xy / 2.25, abs=1e-4)
    assert tuned["control.ki_vxy"] == pytest.approx(D.ki_vxy / 2.25, abs=1e-4)
    load_config(None, tuned_overrides(ident, Config()))
    mid = _as_dict(tuned_overrides(_ident(_fit(0.15, 0.12)), Config()))  # T 0.27 s
    assert (mid["control.kp_xy"], mid["control.ki_vxy"]) == (D.kp_xy, D.ki_vxy)
    fast = _as_dict(tuned_overrides(_ident(_fit(0.07, 0.09)), Config()))  # T 0.16 s
    assert fast["control.kp_vxy"] == pytest.approx(D.kp_vxy / 0.8, abs=1e-4)
    assert fast["control.ki_xy"] == pytest.approx(D.ki_xy / 0.64, abs=1e-4)


def test_the_gains_move_at_most_2_5_times_from_the_base() -> None:
    slow = _as_dict(tuned_overrides(_ident(_fit(0.75, 0.75)), Config()))  # s = 5
    assert slow["control.kp_xy"] == pytest.approx(D.kp_xy / MAX_GAIN_FACTOR)
    assert slow["control.ki_xy"] == pytest.approx(D.ki_xy / MAX_GAIN_FACTOR)
    base = load_config(None, ["control.ki_xy=0", "control.kp_vxy=500"])
    fast = _as_dict(tuned_overrides(_ident(_fit(0.0001, 0.0001)), base))  # s = 1e-3
    assert fast["control.ki_xy"] == 0.0  # a gain switched off stays off
    assert fast["control.kp_xy"] == pytest.approx(D.kp_xy * MAX_GAIN_FACTOR)
    assert fast["control.kp_vxy"] == 1000.0  # the config's range: 0..1000


def test_poor_or_missing_data_leave_their_keys_alone() -> None:
    ident = _ident(_fit(poor="little excitation"), hover_gas=math.nan, noise_z=math.nan)
    assert tuned_overrides(ident, Config()) == []
    partial = _as_dict(tuned_overrides(_ident(_fit(poor="R² 0.3 < 0.6")), COMPLEMENTARY))
    assert set(partial) == {"control.hover_gas", "estimation.filter_gain_z_per_s"}


def test_the_hover_gas_moves_to_the_configs_voltage() -> None:
    base = load_config(None, ["control.hover_voltage_v=12.0"])
    tuned = _as_dict(tuned_overrides(_ident(hover_gas=96.0), base))
    assert tuned["control.hover_gas"] == pytest.approx(96.0 * 11.8 / 12.0, abs=0.05)


@pytest.mark.parametrize(("noise_ratio", "factor"), [(1.2, 1.2), (10.0, 1.5), (0.1, 1.0)])
def test_the_vertical_filter_trusts_the_laser_more_with_vibration(
    noise_ratio: float, factor: float
) -> None:
    """Up with the AccZ noise, 1.5 times the default at most, never below the default;
    only for the complementary filter (the Kalman filter measures the noise in flight)."""
    ident = _ident(noise_z=NOMINAL_NOISE_Z_MPS2 * noise_ratio)
    tuned = _as_dict(tuned_overrides(ident, COMPLEMENTARY))
    assert tuned["estimation.filter_gain_z_per_s"] == pytest.approx(KZ * factor)
    assert "estimation.filter_gain_z_per_s" not in _as_dict(tuned_overrides(ident, Config()))


def test_the_written_config_loads_and_holds_the_overrides(tmp_path: Path) -> None:
    target = tmp_path / "tuned.yaml"
    ident = _ident(_fit(0.15, 0.12, gain=1.2), hover_gas=90.0, noise_z=0.3)
    cfg, overrides = write_tuned_config(target, ident, base_path=None, now=NOW)
    assert overrides == tuned_overrides(ident, Config())
    loaded = load_config(target)
    assert loaded == cfg
    assert loaded == load_config(None, overrides)
    assert loaded.mk.counts_per_rad == 100.0
    assert loaded.control.hover_gas == 90.0
    text = target.read_text(encoding="utf-8")
    assert "# identified from: flight\n" in text
    assert "# written: 2026-11-26T12:00:00+00:00\n" in text
    assert set(yaml.safe_load(text)) == set(Config.__struct_fields__)  # every section
    with pytest.raises(ConfigError, match="exists; refusing to overwrite"):
        write_tuned_config(target, ident, base_path=None, now=NOW)
    assert load_config(target) == cfg  # untouched


def test_the_base_config_is_kept_and_may_be_tuned_in_place(tmp_path: Path) -> None:
    base = tmp_path / "mine.yaml"
    base.write_text("control:\n  kp_z: 3.0\n  hover_voltage_v: 12.0\n", encoding="utf-8")
    ident = _ident(hover_gas=96.0)
    cfg, _ = write_tuned_config(
        base, ident, base_path=base, base_overrides=["control.kd_vxy=0.4"], now=NOW
    )
    assert load_config(base) == cfg
    assert (cfg.control.kp_z, cfg.control.kd_vxy) == (3.0, 0.4)
    assert cfg.control.hover_gas == pytest.approx(96.0 * 11.8 / 12.0, abs=0.05)
    assert [p.name for p in tmp_path.iterdir()] == ["mine.yaml"]  # no temporary left


# The command line, on a synthetic flight of a known airframe (FC 100 counts/rad).


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_flight(tmp_path_factory.mktemp("tune") / "flight", Airframe())


def test_tune_prints_the_identification_and_the_overrides(
    flight: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["tune", str(flight)]) == 0
    out = capsys.readouterr().out
    assert "attitude response" in out
    assert "the FC's counts per radian: 100." in out
    assert "mk.counts_per_rad=100." in out
    assert "control.hover_gas=95." in out


def test_tune_json_and_write_config(
    flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "tuned.yaml"
    assert main(["tune", str(flight), "--json", "--write-config", str(target)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"identification", "overrides", "tuned", "base", "written"}
    assert out["written"] == str(target)
    assert out["base"] == "built-in defaults"
    ident = out["identification"]
    assert {"pitch", "roll", "attitude", "hover_gas_counts", "vibration_mps2"} <= set(ident)
    assert ident["attitude"]["good"] is True
    assert load_config(target) == load_config(None, out["overrides"])
    assert [t["key"] for t in out["tuned"]] == [o.split("=")[0] for o in out["overrides"]]


def test_tune_errors_are_one_line(
    flight: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = [
        (["tune", str(tmp_path / "missing")], 1, "not a flight folder"),
        (["tune", str(write_flight(tmp_path / "t", hold=False))], 1, "no HOLD phase"),
        (["tune", str(flight), "--write-config", str(flight / "flight.json")], 2, "exists"),
        (["tune", str(flight), "--set", "control.kp_xy=-1"], 2, "control.kp_xy"),
        (["tune"], 2, "LOGDIR"),
    ]
    for argv, code, text in cases:
        assert main(argv) == code, argv
        err = capsys.readouterr().err
        # The config found is said first, unless it is the config that failed.
        err = err.removeprefix("config: built-in defaults\n")
        assert err.startswith("error: "), argv
        assert text in err
        assert len(err.splitlines()) == 1
