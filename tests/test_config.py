"""Configuration loading: defaults, ``config.yaml``, ``--set`` overrides and every error path."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from mkflight.config import (
    Config,
    ControlConfig,
    MkSigns,
    config_from_dict,
    config_to_dict,
    load_config,
)
from mkflight.errors import ConfigError, MkflightError

REPO_CONFIG = Path(__file__).resolve().parents[1] / "config.yaml"


def write(tmp_path: Path, text: str, name: str = "config.yaml") -> Path:
    """Write ``text`` to a file under ``tmp_path`` and return its path."""
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# --- defaults ----------------------------------------------------------------------------


def test_defaults_load() -> None:
    cfg = load_config(None)
    assert cfg == Config()
    assert cfg.control.kp_xy == 2.0
    assert cfg.control.gas_max == 130
    assert cfg.mk.signs == MkSigns(nick=-1, roll=-1, yaw=-1)
    assert cfg.mk.acc_nick_counts_per_g == 606.3
    assert cfg.mk.acc_roll_counts_per_g == 603.44
    assert cfg.mk.g_mps2 == 9.81
    assert cfg.laser.scan_steps == (150, 725)
    assert cfg.laser.hat_steps == (44, 127)


def test_repo_config_yaml_equals_defaults() -> None:
    assert REPO_CONFIG.is_file(), f"{REPO_CONFIG} is missing: the repository ships it"
    assert load_config(REPO_CONFIG) == Config()


def test_empty_file_and_empty_sections_are_defaults(tmp_path: Path) -> None:
    assert load_config(write(tmp_path, "")) == Config()
    assert load_config(write(tmp_path, "# only a comment\n")) == Config()
    assert load_config(write(tmp_path, "control: {}\nmk: {signs: {}}\n")) == Config()


def test_config_dict_round_trip() -> None:
    data = config_to_dict(Config())
    assert data["control"]["kp_xy"] == 2.0
    assert data["mk"]["signs"]["nick"] == -1
    assert config_from_dict(data) == Config()


def test_file_values_are_used(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "control:\n  kp_xy: 2\n  gas_max: 120\nmk:\n  signs:\n    yaw: 1\n"
        "laser:\n  scan_steps: [160, 700]\n",
    )
    cfg = load_config(path)
    assert cfg.control.kp_xy == 2.0
    assert isinstance(cfg.control.kp_xy, float)
    assert cfg.control.gas_max == 120
    assert cfg.mk.signs == MkSigns(nick=-1, roll=-1, yaw=1)
    assert cfg.laser.scan_steps == (160, 700)
    assert cfg.control.kd_xy == ControlConfig().kd_xy


# --- errors name the dotted key ----------------------------------------------------------


@pytest.mark.parametrize(
    ("yaml_text", "key", "what"),
    [
        # unknown keys
        ("control:\n  kp_xyz: 1\n", "control.kp_xyz", "unknown key"),
        ("bogus:\n  x: 1\n", "bogus", "unknown key"),
        ("mk:\n  signs:\n    pitch: 1\n", "mk.signs.pitch", "unknown key"),
        # wrong types
        ("control:\n  kp_xy: fast\n", "control.kp_xy", "Expected `float`"),
        ("control:\n  kp_xy: true\n", "control.kp_xy", "Expected `float`"),
        ("control:\n  gas_max: 100.5\n", "control.gas_max", "Expected `int`"),
        ("mk:\n  port: 3\n", "mk.port", "Expected `str`"),
        ("mk:\n  signs:\n    nick: x\n", "mk.signs.nick", "Expected `int`"),
        ("mk:\n  signs: 1\n", "mk.signs", "Expected `object`"),
        ("control: 3\n", "control", "Expected `object`"),
        ("control:\n", "control", "Expected `object`"),
        ("laser:\n  scan_steps: [1, 2, 3]\n", "laser.scan_steps", "length 2"),
        # out of range
        ("control:\n  kp_xy: -1\n", "control.kp_xy", ">= 0"),
        ("control:\n  kp_xy: 1001\n", "control.kp_xy", "<= 1000"),
        ("control:\n  gas_max: 256\n", "control.gas_max", "<= 255"),
        ("mk:\n  g_mps2: 20\n", "mk.g_mps2", "<= 9.9"),
        ("mk:\n  confirm_every: 0\n", "mk.confirm_every", ">= 1"),
        ("mk:\n  confirm_every: 21\n", "mk.confirm_every", "<= 20"),
        ("mk:\n  signs:\n    nick: 2\n", "mk.signs.nick", "2"),
        ("mk:\n  signs:\n    roll: 0\n", "mk.signs.roll", "0"),
        ("laser:\n  hat_steps: [44, 2000]\n", "laser.hat_steps[1]", "<= 1080"),
        # NaN and inf
        ("control:\n  kp_xy: .nan\n", "control.kp_xy", "finite"),
        ("control:\n  kp_xy: .inf\n", "control.kp_xy", "finite"),
        ("mk:\n  acc_z_offset_mps2: -.inf\n", "mk.acc_z_offset_mps2", "finite"),
        ("mk:\n  acc_z_offset_mps2: .NaN\n", "mk.acc_z_offset_mps2", "finite"),
        ("control:\n  kp_xy: 1.0e+400\n", "control.kp_xy", "finite"),
    ],
)
def test_invalid_values_name_the_key(tmp_path: Path, yaml_text: str, key: str, what: str) -> None:
    path = write(tmp_path, yaml_text)
    pattern = rf"^{re.escape(str(path))}: {re.escape(key)}: .*{re.escape(what)}"
    with pytest.raises(ConfigError, match=pattern) as info:
        load_config(path)
    assert isinstance(info.value, MkflightError)
    # The same mapping without a file: named "config", same key.
    with pytest.raises(ConfigError, match=rf"^config: {re.escape(key)}: "):
        config_from_dict(yaml.safe_load(yaml_text))


def test_validation_error_is_chained(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"control\.kp_xy") as info:
        load_config(write(tmp_path, "control:\n  kp_xy: fast\n"))
    assert info.value.__cause__ is not None


def test_non_string_key_names_its_section() -> None:
    with pytest.raises(ConfigError, match=r"^config: control[.:]") as info:
        config_from_dict({"control": {1: 2}})
    assert "$" not in str(info.value)


@pytest.mark.parametrize(
    ("yaml_text", "key"),
    [
        ("laser:\n  scan_steps: [700, 150]\n", "laser.scan_steps"),
        ("laser:\n  hat_steps: [127, 44]\n", "laser.hat_steps"),
        ("safety:\n  land_voltage_v: 11.0\n", "safety.land_voltage_v"),
        ("control:\n  takeoff_height_m: 2.0\n", "control.takeoff_height_m"),
        ("mk:\n  reopen_backoff_s: 5\n", "mk.reopen_backoff_s"),
        ("laser:\n  reopen_backoff_s: 5\n", "laser.reopen_backoff_s"),
        ("sim:\n  vehicle:\n    hat_steps: [127, 44]\n", "sim.vehicle.hat_steps"),
    ],
)
def test_cross_checks_name_the_key(tmp_path: Path, yaml_text: str, key: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(key)):
        load_config(write(tmp_path, yaml_text))


# --- --set overrides ---------------------------------------------------------------------


def test_set_overrides_nested_keys() -> None:
    cfg = load_config(None, ["control.kp_xy=1.2"])
    assert cfg.control.kp_xy == 1.2
    assert cfg.control.kd_xy == ControlConfig().kd_xy
    cfg = load_config(None, ["mk.signs.nick=1", "mk.port=/dev/ttyS3", "laser.hat_steps=[44, 100]"])
    assert cfg.mk.signs.nick == 1
    assert cfg.mk.signs.roll == -1
    assert cfg.mk.port == "/dev/ttyS3"
    assert cfg.laser.hat_steps == (44, 100)


def test_set_later_item_wins_and_beats_the_file(tmp_path: Path) -> None:
    path = write(tmp_path, "control:\n  kp_xy: 2.0\n  kd_xy: 0.5\n")
    cfg = load_config(path, ["control.kp_xy=3", "control.kp_xy=4.5"])
    assert cfg.control.kp_xy == 4.5
    assert cfg.control.kd_xy == 0.5


def test_set_spaces_around_key() -> None:
    assert load_config(None, [" control.kp_xy =2"]).control.kp_xy == 2.0


def test_set_errors_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"with --set: control\.kp_xy: .*>= 0"):
        load_config(None, ["control.kp_xy=-3"])
    with pytest.raises(ConfigError, match=r"control\.kp_xy: must be a finite number"):
        load_config(None, ["control.kp_xy=.nan"])
    with pytest.raises(ConfigError, match=r"control\.kp_xyz: unknown key"):
        load_config(None, ["control.kp_xyz=1"])
    with pytest.raises(ConfigError, match=r"mk\.signs\.nick"):
        load_config(None, ["mk.signs.nick=3"])
    with pytest.raises(ConfigError, match=r"--set control\.kp_xy: cannot parse value '\['"):
        load_config(None, ["control.kp_xy=["])


@pytest.mark.parametrize(
    ("item", "match"),
    [
        ("noequals", r"--set 'noequals': expected KEY=VALUE"),
        ("=3", r"--set '=3': expected KEY=VALUE"),
        ("  =3", r"expected KEY=VALUE"),
        ("a..b=1", r"--set 'a\.\.b=1': malformed key 'a\.\.b'"),
        (".kp_xy=1", r"malformed key '\.kp_xy'"),
        ("control.=1", r"malformed key 'control\.'"),
        ("control=3", r"control: Expected `object`, got `int`"),
        ("control.kp_xy.x=1", r"control\.kp_xy: Expected `float`, got `object`"),
    ],
)
def test_malformed_set_items(item: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(None, [item])


def test_set_into_a_value_set_earlier() -> None:
    with pytest.raises(ConfigError, match=r"control\.kp_xy is a value, not a section"):
        load_config(None, ["control.kp_xy=1", "control.kp_xy.x=1"])


def test_set_into_a_value_from_the_file(tmp_path: Path) -> None:
    path = write(tmp_path, "control:\n  kp_xy: 1.0\n")
    with pytest.raises(ConfigError, match=r"control\.kp_xy is a value, not a section"):
        load_config(path, ["control.kp_xy.x=1"])


# --- files that cannot be used -----------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("control: [1, 2\n", "invalid YAML"),
        ("control:\n  kp_xy: 1\n kd_xy: 2\n", "invalid YAML"),
        ("{{{{", "invalid YAML"),
        ("- 1\n- 2\n", "the top level must be a mapping"),
        ("just a string\n", "the top level must be a mapping"),
        ("42\n", "the top level must be a mapping"),
    ],
)
def test_bad_files_name_the_file(tmp_path: Path, text: str, match: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: {match}"):
        load_config(path)


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: cannot read config file"):
        load_config(path)
    with pytest.raises(ConfigError, match=re.escape(str(path))):
        load_config(str(path))


def test_directory_is_unreadable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(tmp_path))}: cannot read"):
        load_config(tmp_path)


def test_non_utf8_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes(b"control:\n  kp_xy: 1 # \xe9t\xe9\n")
    with pytest.raises(ConfigError, match=re.escape(str(path))):
        load_config(path)


@pytest.mark.parametrize(("text", "value"), [("1e-3", 1e-3), ("2E2", 200.0), ("-1.5e-2", -1.5e-2)])
def test_exponent_floats_without_a_dot_are_numbers(tmp_path: Path, text: str, value: float) -> None:
    """YAML 1.1 reads ``1e-3`` as a string; a gain written so is a number here (YAML 1.2)."""
    path = tmp_path / "c.yaml"
    path.write_text(f"control:\n  kp_xy: {text}\n")
    if value < 0:
        with pytest.raises(ConfigError, match=r"control\.kp_xy: Expected `float` >= 0"):
            load_config(path)
        return
    assert load_config(path).control.kp_xy == pytest.approx(value)
    assert load_config(None, [f"control.kp_xy={text}"]).control.kp_xy == pytest.approx(value)


@pytest.mark.parametrize("text", ["nan", "NaN", "inf", "-inf", "Infinity", "1e400"])
def test_set_non_finite_is_refused_as_not_finite(text: str) -> None:
    with pytest.raises(ConfigError, match=r"control\.kp_xy: must be a finite number"):
        load_config(None, [f"control.kp_xy={text}"])


def test_yaml_python_tags_are_refused(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "c.yaml"
    path.write_text(f'control: !!python/object/apply:os.system ["touch {marker}"]\n')
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_config(path)
    with pytest.raises(ConfigError):
        load_config(None, [f'control.kp_xy=!!python/object/apply:os.system ["touch {marker}"]'])
    assert not marker.exists()
