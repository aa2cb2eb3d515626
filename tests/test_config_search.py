"""Where the config comes from: the search, the ``config:`` line, ``config show`` and ``check``.

``--config`` beats ``$MKFLIGHT_CONFIG``, which beats ``/etc/mkflight/config.yaml`` (here a
file under ``tmp_path``: :data:`mkflight.config_search.SYSTEM_CONFIG` is patched), which beats the
built-in defaults; ``--set`` goes on top of whichever it is.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import pytest

import mkflight.config_search as config
from mkflight.cli import main
from mkflight.commands.args import Command
from mkflight.config import Config, config_to_dict, load_config, read_yaml
from mkflight.config_search import ConfigSource, leaf_keys, locate_config
from mkflight.errors import ConfigError
from mkflight.logs.flight_json import new_flight_info, read_flight_json, write_flight_json


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """Three config files, each setting control.kp_xy to a value of its own."""
    out = {}
    for name, kp in (("option", 1.1), ("env", 1.2), ("system", 1.3)):
        path = tmp_path / f"{name}.yaml"
        path.write_text(f"control:\n  kp_xy: {kp}\n", encoding="utf-8")
        out[name] = path
    return out


@pytest.fixture
def system(monkeypatch: pytest.MonkeyPatch, files: dict[str, Path]) -> Path:
    """/etc/mkflight/config.yaml, as far as the process knows, is the 'system' file."""
    monkeypatch.setattr(config, "SYSTEM_CONFIG", str(files["system"]))
    monkeypatch.delenv("MKFLIGHT_CONFIG", raising=False)
    return files["system"]


def test_the_search_order(files: dict[str, Path]) -> None:
    env = {"MKFLIGHT_CONFIG": str(files["env"])}
    etc = str(files["system"])
    nowhere = str(files["system"].with_name("absent.yaml"))
    found = [
        locate_config(str(files["option"]), environ=env, system_path=etc),
        locate_config(None, environ=env, system_path=etc),
        locate_config(None, environ={}, system_path=etc),
        locate_config(None, environ={"MKFLIGHT_CONFIG": ""}, system_path=nowhere),
    ]
    assert [(s.file, s.found_by) for s in found] == [
        (str(files["option"]), "option"),
        (str(files["env"]), "environment"),
        (etc, "system"),
        (None, "default"),
    ]
    kp = [load_config(s.file).control.kp_xy for s in found]
    assert kp == [1.1, 1.2, 1.3, Config().control.kp_xy]


def test_a_missing_env_file_is_an_error_naming_the_variable(tmp_path: Path) -> None:
    env = {"MKFLIGHT_CONFIG": str(tmp_path / "typo.yaml")}
    with pytest.raises(ConfigError, match=r"^\$MKFLIGHT_CONFIG=.*typo\.yaml: no such file"):
        locate_config(None, environ=env, system_path=str(tmp_path / "etc.yaml"))


def test_the_default_system_path_is_read_at_the_call(system: Path) -> None:
    assert locate_config(None, environ={}) == ConfigSource(file=str(system), found_by="system")


@pytest.mark.parametrize(
    ("source", "line"),
    [
        (ConfigSource(), "built-in defaults"),
        (ConfigSource(file="/etc/mkflight/config.yaml", found_by="system"), None),
        (ConfigSource(file="/x.yaml", found_by="environment"), "$MKFLIGHT_CONFIG=/x.yaml"),
        (ConfigSource(file="c.yaml", found_by="option", overrides=("a=1", "b=2")), None),
    ],
)
def test_describe(source: ConfigSource, line: str | None) -> None:
    expected = {
        "/etc/mkflight/config.yaml": "/etc/mkflight/config.yaml",
        "c.yaml": "c.yaml with 2 --set",
    }
    assert source.describe() == (line or expected[str(source.file)])


def test_every_config_command_gets_the_file_found_and_says_it(
    system: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Command feeds ``config_path`` from the search, so no command can forget it."""
    import argparse

    seen: dict[str, object] = {}

    def cmd(*, config_path: str | None, overrides: list[str], config_source: ConfigSource) -> int:
        seen.update(path=config_path, source=config_source)
        return 0

    args = argparse.Namespace(config_path=None, overrides=["control.ki_xy=0.1"])
    assert Command(cmd)(args) == 0
    assert seen["path"] == str(system)
    assert seen["source"] == ConfigSource(
        file=str(system), found_by="system", overrides=("control.ki_xy=0.1",)
    )
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == f"config: {system} with 1 --set\n"


def test_a_bad_config_is_only_its_error_line(
    system: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    system.write_text("control:\n  kp_xy: -1\n", encoding="utf-8")
    assert main(["config", "show"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {system}: control.kp_xy: Expected `float` >= 0.0\n"


def test_env_missing_file_through_the_cli(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("MKFLIGHT_CONFIG", str(tmp_path / "nope.yaml"))
    assert main(["mk", "release", "--port", "/dev/null"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines() == [
        f"error: $MKFLIGHT_CONFIG={tmp_path / 'nope.yaml'}: no such file (unset the variable "
        f"to use {config.SYSTEM_CONFIG} or the built-in defaults)"
    ]


def _show(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[list[str], str]:
    assert main(["config", "show", *argv]) == 0
    captured = capsys.readouterr()
    return captured.out.splitlines(), captured.err


def test_show_names_each_values_origin(
    system: Path,
    files: dict[str, Path],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setenv("MKFLIGHT_CONFIG", str(files["env"]))
    lines, err = _show(["--set", "safety.box_m=3", "--set", "laser.scan_steps=[100, 700]"], capsys)
    assert err == f"config: $MKFLIGHT_CONFIG={files['env']} with 2 --set\n"
    by_key = {line.split(":", 1)[0]: line for line in lines}
    assert len(lines) == len(by_key) == len(leaf_keys(config_to_dict(Config())))
    assert by_key["control.kp_xy"].split() == [
        "control.kp_xy:",
        "1.2",
        "#",
        f"$MKFLIGHT_CONFIG={files['env']}",
    ]
    assert by_key["safety.box_m"].split() == ["safety.box_m:", "3.0", "#", "--set"]
    assert by_key["laser.scan_steps"].split("#")[0].split() == [
        "laser.scan_steps:",
        "[100,",
        "700]",
    ]
    assert by_key["control.ki_xy"].endswith("# default")
    # The comments line up, one column for all.
    assert len({line.index("  # ") for line in lines}) == 1


def test_show_values_load_as_yaml_and_round_trip(
    system: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    lines, err = _show(["--set", "sim.fc.version='1e-3'"], capsys)
    assert err == f"config: {system} with 1 --set\n"
    values_part = tmp_path / "values.yaml"
    values_part.write_text("\n".join(line.split("  # ")[0] for line in lines), encoding="utf-8")
    shown = read_yaml(values_part)
    cfg = load_config(str(system), ["sim.fc.version='1e-3'"])
    expected = {
        k: list(v) if isinstance(v, tuple) else v for k, v in leaf_keys(config_to_dict(cfg)).items()
    }
    assert shown == expected
    assert shown["sim.fc.version"] == "1e-3"  # a string that looks like a number stays one
    assert shown["control.kp_xy"] == 1.3
    # Each line is a --set item: feeding them all back gives the same config.
    again = load_config(None, [f"{k}={json.dumps(v)}" for k, v in shown.items()])
    assert again == cfg


def test_a_set_section_replaces_the_files(
    tmp_path: Path, system: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    system.write_text("mk:\n  signs: {nick: 1, roll: 1}\n", encoding="utf-8")
    lines, _ = _show(["--set", "mk.signs={yaw: 1}"], capsys)
    origin = {ln.split(":", 1)[0]: ln.rsplit("# ", 1)[1] for ln in lines}
    assert (origin["mk.signs.nick"], origin["mk.signs.roll"]) == ("default", "default")
    assert origin["mk.signs.yaw"] == "--set"
    assert main(["config", "show", "--json", "--set", "mk.signs={yaw: 1}"]) == 0
    shown = json.loads(capsys.readouterr().out)
    keys = {k["key"]: k for k in shown["keys"]}
    assert keys["mk.signs.nick"] == {"key": "mk.signs.nick", "value": -1, "origin": "default"}
    assert keys["mk.signs.yaw"]["value"] == 1
    assert shown["source"] == {
        "file": str(system),
        "found_by": "system",
        "overrides": ["mk.signs={yaw: 1}"],
    }


def test_show_without_any_file(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(config, "SYSTEM_CONFIG", str(tmp_path / "absent.yaml"))
    lines, err = _show([], capsys)
    assert err == "config: built-in defaults\n"
    assert all(line.endswith("# default") for line in lines)


def test_check_counts_the_keys_and_names_a_bad_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    repo_config = Path(__file__).resolve().parents[1] / "config.yaml"
    assert main(["config", "check", str(repo_config)]) == 0
    n = len(leaf_keys(read_yaml(repo_config)))
    assert capsys.readouterr() == (f"{repo_config}: ok ({n} keys set)\n", "")
    one = tmp_path / "one.yaml"
    one.write_text("safety:\n  box_m: 1.5\n", encoding="utf-8")
    assert main(["config", "check", str(one)]) == 0
    assert capsys.readouterr().out == f"{one}: ok (1 key set)\n"
    bad = tmp_path / "bad.yaml"
    bad.write_text("safety:\n  box_m: 1.5\n  land_voltage_v: 20\n", encoding="utf-8")
    assert main(["config", "check", str(bad)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"error: {bad}: safety.land_voltage_v: must not exceed safety.warn_voltage_v\n"
    )
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("control:\n  kp_xz: 1\n", encoding="utf-8")
    assert main(["config", "check", str(unknown)]) == 2
    assert capsys.readouterr().err == f"error: {unknown}: control.kp_xz: unknown key\n"
    assert main(["config", "check", str(tmp_path / "missing.yaml")]) == 2
    assert "cannot read config file" in capsys.readouterr().err


def test_flight_json_keeps_the_source_and_older_files_read(tmp_path: Path) -> None:
    source = ConfigSource(
        file="/etc/mkflight/config.yaml", found_by="system", overrides=("logging.dir=/f",)
    )
    start = datetime(2026, 1, 1, tzinfo=UTC)
    write_flight_json(tmp_path, new_flight_info(start, Config(), config_source=source))
    data = json.loads((tmp_path / "flight.json").read_text(encoding="utf-8"))
    assert list(data)[-2:] == ["config_source", "summary"]
    assert data["config_source"] == {
        "file": "/etc/mkflight/config.yaml",
        "found_by": "system",
        "overrides": ["logging.dir=/f"],
    }
    assert read_flight_json(tmp_path).config_source == source
    # A file without it (a replay's, an older mkflight's) reads, as None.
    older = tmp_path / "older"
    older.mkdir()
    write_flight_json(older, new_flight_info(start, Config()))
    assert "config_source" not in json.loads((older / "flight.json").read_text("utf-8"))
    assert read_flight_json(older).config_source is None


def test_a_sim_hover_flies_the_system_config_and_records_it(
    system: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The whole path: the search finds the system file, the flight uses and records it."""
    folder = tmp_path / "flight"
    argv = ["sim", "hover", "--duration", "4", "--log-dir", str(folder), "--set", "safety.box_m=3"]
    assert main(argv) == 0
    assert capsys.readouterr().err.startswith(f"config: {system} with 1 --set\n")
    info = read_flight_json(folder)
    assert info.config_source == ConfigSource(
        file=str(system), found_by="system", overrides=("safety.box_m=3",)
    )
    assert info.config["control"]["kp_xy"] == 1.3  # the system file's value was flown
    assert info.config["safety"]["box_m"] == 3.0
