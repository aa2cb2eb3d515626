"""tools/99-mkflight.rules: valid udev syntax, the two names the config and the unit use.

The parser follows udev(7) as far as the file needs: one rule a line, comma-separated
``KEY[{attr}] OP "value"`` items; ``==``/``!=`` match, ``=``/``+=``/``:=`` assign, and a
key is either a match key or an assignment key, never both.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from mkflight.cli import build_parser
from mkflight.config import Config, read_yaml

from .test_service_unit import UNIT, parse_unit

ROOT = Path(__file__).resolve().parents[2]
RULES = ROOT / "tools" / "99-mkflight.rules"
MATCH_OPS = {"==", "!="}
ASSIGN_OPS = {"=", "+=", ":="}
#: The keys the file may use, with what each may do (udev(7)).
KEYS = {
    "SUBSYSTEM": MATCH_OPS,
    "ATTRS{idVendor}": MATCH_OPS,
    "ATTRS{idProduct}": MATCH_OPS,
    "ATTRS{serial}": MATCH_OPS,
    "SYMLINK": ASSIGN_OPS,
    "ENV{ID_MM_DEVICE_IGNORE}": ASSIGN_OPS,
    "MODE": ASSIGN_OPS,
    "GROUP": ASSIGN_OPS,
    "TAG": ASSIGN_OPS,
}
ITEM = re.compile(r'\s*([A-Z_]+(?:\{[A-Za-z0-9_]+\})?)\s*(==|!=|\+=|:=|=)\s*"([^"]*)"\s*')


@dataclass(frozen=True, slots=True)
class Item:
    key: str
    op: str
    value: str


def parse_rules(text: str) -> list[list[Item]]:
    """The rules of a udev rules file, each as its items in order.

    Raises:
        ValueError: a line that is not a comment, blank or a list of valid items.
    """
    rules = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        assert not line.rstrip().endswith("\\"), f"line {number}: continued lines not used"
        items = []
        for part in line.split(","):
            m = ITEM.fullmatch(part)
            if m is None:
                raise ValueError(f'line {number}: not KEY OP "VALUE": {part!r}')
            item = Item(*m.groups())
            if item.key not in KEYS:
                raise ValueError(f"line {number}: unknown key {item.key}")
            if item.op not in KEYS[item.key]:
                raise ValueError(f"line {number}: {item.key} cannot take {item.op}")
            items.append(item)
        rules.append(items)
    return rules


@pytest.fixture(scope="module")
def rules() -> list[list[Item]]:
    return parse_rules(RULES.read_text(encoding="utf-8"))


def test_the_parser_refuses_what_udev_refuses() -> None:
    assert parse_rules('# c\n\nSUBSYSTEM=="tty", MODE="0660"\n') == [
        [Item("SUBSYSTEM", "==", "tty"), Item("MODE", "=", "0660")]
    ]
    for bad in (
        'SUBSYSTEM="tty"',  # an assignment to a match key
        'SYMLINK=="x"',  # a match on an assignment key
        "SUBSYSTEM==tty",  # unquoted
        'SUBSYSTEM=="tty" MODE="0660"',  # no comma
        'NAME="x"',  # not among the keys the file may use
    ):
        with pytest.raises(ValueError, match="line 1"):
            parse_rules(bad)


def _by_symlink(rules: list[list[Item]]) -> dict[str, dict[str, Item]]:
    out = {}
    for rule in rules:
        keys = {item.key: item for item in rule}
        if "SYMLINK" in keys:
            out[keys["SYMLINK"].value] = keys
    return out


def test_two_names_by_usb_id_for_group_dialout(rules: list[list[Item]]) -> None:
    named = _by_symlink(rules)
    assert set(named) == {"mkflight-fc", "mkflight-urg"}
    ids = {
        name: (k["ATTRS{idVendor}"].value, k["ATTRS{idProduct}"].value) for name, k in named.items()
    }
    assert ids == {"mkflight-fc": ("0403", "6001"), "mkflight-urg": ("15d1", "0000")}
    for keys in named.values():
        assert keys["SUBSYSTEM"] == Item("SUBSYSTEM", "==", "tty")  # the tty, not the USB node
        assert keys["SYMLINK"].op == "+="  # added to udev's own links (serial/by-id), not replacing
        assert keys["GROUP"].value == "dialout"
        assert keys["MODE"].value == "0660"  # owner and group only


def test_modemmanager_ignores_both_devices(rules: list[list[Item]]) -> None:
    ignored = set()
    for rule in rules:
        keys = {item.key: item for item in rule}
        if keys.get("ENV{ID_MM_DEVICE_IGNORE}") == Item("ENV{ID_MM_DEVICE_IGNORE}", "=", "1"):
            assert "SUBSYSTEM" not in keys  # every node of the device, the USB device too
            ignored.add((keys["ATTRS{idVendor}"].value, keys["ATTRS{idProduct}"].value))
    assert ignored == {("0403", "6001"), ("15d1", "0000")}


def test_the_config_and_the_unit_use_the_same_names(rules: list[list[Item]]) -> None:
    devices = {f"/dev/{name}" for name in _by_symlink(rules)}
    defaults = Config()
    assert {defaults.mk.port, defaults.laser.port} == devices
    repo = read_yaml(ROOT / "config.yaml")
    assert {repo["mk"]["port"], repo["laser"]["port"]} == devices
    # The unit runs as a member of the rule's group, and may open the tty devices behind.
    unit = parse_unit(UNIT.read_text(encoding="utf-8"))["Service"]
    assert unit["SupplementaryGroups"] == ["dialout"]
    assert {"char-ttyUSB rw", "char-ttyACM rw"} <= set(unit["DeviceAllow"])
    # Its release goes to mk.port, i.e. /dev/mkflight-fc unless the vehicle's config says.
    (stop_post,) = unit["ExecStopPost"]
    args = build_parser().parse_args(shlex.split(stop_post.removeprefix("-"))[1:])
    assert args.port is None


def test_the_comment_shows_a_valid_serial_rule() -> None:
    """The example for two FTDI adapters is itself a valid rule."""
    text = RULES.read_text(encoding="utf-8")
    examples = [ln.lstrip("# ") for ln in text.splitlines() if "ATTRS{serial}==" in ln]
    assert examples
    for rule in parse_rules("\n".join(examples)):
        assert {i.key for i in rule} >= {"ATTRS{serial}", "ATTRS{idVendor}", "SYMLINK"}
