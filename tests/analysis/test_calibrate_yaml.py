"""``calibrate --write-config`` reads and writes config YAML as ``--config`` does (issue 18).

One reader (:func:`mkflight.config.read_yaml`) serves every place that reads a config
file: a file :func:`~mkflight.config.load_config` accepts, calibrate must not refuse
(PyYAML's ``safe_load`` reads ``1e-4`` as a string, which a gain refuses).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from mkflight.cli import main
from mkflight.commands.calibrate import cmd_calibrate_acc
from mkflight.config import dump_yaml, load_config, read_yaml
from mkflight.errors import ConfigError
from tests.analysis.seed_tables import TABLE_I_RUNS, as_text


@pytest.fixture
def table_i(tmp_path: Path) -> Path:
    path = tmp_path / "table1.txt"
    path.write_text(as_text(TABLE_I_RUNS))
    return path


@pytest.fixture
def restore_structlog() -> Iterator[None]:
    """``main`` sets up structlog for the process; put the previous setup back after."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)


def test_write_config_keeps_an_exponent_gain(
    table_i: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    restore_structlog: None,
) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("control:\n  ki_xy: 1e-4\n  kp_xy: 2.5E+0\nmk:\n  port: /dev/ttyUSB7\n")
    assert load_config(cfg).control.ki_xy == 1e-4  # what --config accepts...
    code = main(["calibrate", "acc", str(table_i), "--write-config", str(cfg), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err  # ...calibrate accepts too
    assert round(json.loads(captured.out)["k_counts_per_g"], 1) == 606.3
    loaded = load_config(cfg)
    assert loaded.control.ki_xy == 1e-4
    assert loaded.control.kp_xy == 2.5
    assert loaded.mk.port == "/dev/ttyUSB7"
    assert loaded.mk.acc_nick_counts_per_g == 606.315


def test_a_string_that_looks_like_a_number_stays_a_string(table_i: Path, tmp_path: Path) -> None:
    """The writer quotes what the reader would take for an exponent float."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mk:\n  port: '1e5'\n")
    code = cmd_calibrate_acc(file=str(table_i), axis="roll", as_json=True, write_config=str(cfg))
    assert code == 0
    assert read_yaml(cfg)["mk"]["port"] == "1e5"
    assert load_config(cfg).mk.port == "1e5"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("control: [1, 2\n", "invalid YAML"),
        ("- 1\n- 2\n", "the top level must be a mapping"),
        ("control:\n  ki_xy: not-a-number\n", r"control\.ki_xy: Expected `float`"),
    ],
)
def test_write_config_refuses_what_load_config_refuses(
    table_i: Path, tmp_path: Path, text: str, match: str
) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_config(cfg)
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(cfg))}: {match}"):
        cmd_calibrate_acc(file=str(table_i), axis="nick", as_json=True, write_config=str(cfg))
    assert cfg.read_text() == text  # untouched


def test_read_yaml_of_an_empty_file_is_an_empty_mapping(tmp_path: Path) -> None:
    cfg = tmp_path / "empty.yaml"
    cfg.write_text("# nothing yet\n")
    assert read_yaml(cfg) == {}


def test_dump_yaml_reads_back_unchanged(tmp_path: Path) -> None:
    data = {
        "control": {"ki_xy": 1e-4, "kp_xy": 1e-20},
        "mk": {"port": "1e-3", "other": "2.5e+1", "name": "é"},
        "laser": {"scan_steps": [44, 725]},
    }
    text = dump_yaml(data)
    assert text.index("control") < text.index("mk") < text.index("laser")  # order kept
    path = tmp_path / "c.yaml"
    path.write_text(text, encoding="utf-8")
    assert read_yaml(path) == data
