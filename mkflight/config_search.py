"""Where a command's configuration comes from, and where each of its values came from.

The search (``--config``, then ``$MKFLIGHT_CONFIG``, then ``/etc/mkflight/config.yaml``, then
the built-in defaults) and what ``mkflight config show`` / ``config check`` print. The
configuration itself (its sections, defaults, decoding) is :mod:`mkflight.config`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final, Literal

import msgspec
import yaml

from mkflight.config import (
    Config,
    YamlDumper,
    config_from_dict,
    config_to_dict,
    load_config,
    parse_override,
    read_yaml,
)
from mkflight.errors import ConfigError

#: The environment variable naming a config file, searched after ``--config``.
CONFIG_ENV: Final = "MKFLIGHT_CONFIG"
#: The vehicle's config file, searched after :data:`CONFIG_ENV` (skipped when absent).
SYSTEM_CONFIG: Final = "/etc/mkflight/config.yaml"
FoundBy = Literal["option", "environment", "system", "default"]


class ConfigSource(msgspec.Struct, frozen=True, kw_only=True):
    """Where a command's configuration came from (:func:`locate_config`).

    ``flight.json`` keeps it as ``config_source``, beside the config itself.
    """

    file: str | None = None
    """The YAML file read; null: the built-in defaults alone."""
    found_by: FoundBy = "default"
    """How the file was found: ``option`` (--config), ``environment`` ($MKFLIGHT_CONFIG),
    ``system`` (/etc/mkflight/config.yaml), ``default`` (no file)."""
    overrides: tuple[str, ...] = ()
    """The ``--set`` items applied on top of it, in order."""

    @property
    def file_label(self) -> str:
        """The file as it was found: its path, ``$MKFLIGHT_CONFIG=path``, or the defaults."""
        if self.file is None:
            return "built-in defaults"
        if self.found_by == "environment":
            return f"${CONFIG_ENV}={self.file}"
        return self.file

    def describe(self) -> str:
        """One line for stderr: the file label, plus ``with N --set`` when there are any."""
        sets = f" with {len(self.overrides)} --set" if self.overrides else ""
        return f"{self.file_label}{sets}"


def locate_config(
    option: str | None,
    overrides: Sequence[str] = (),
    *,
    environ: Mapping[str, str] | None = None,
    system_path: str | None = None,
) -> ConfigSource:
    """The config file a command reads: ``--config``, ``$MKFLIGHT_CONFIG``, the system file.

    The first of them that is given wins; the system file is skipped when it does not
    exist, and with none of them the built-in defaults apply. ``--set`` items go on top of
    whichever it is. Only finds the file: :func:`load_config` reads and checks it.
    ``environ`` and ``system_path`` default to the process's and :data:`SYSTEM_CONFIG`
    (looked up at the call, so a test can point it elsewhere).

    Raises:
        ConfigError: ``$MKFLIGHT_CONFIG`` names a file that does not exist (a variable
            set by mistake must not silently fly the defaults).
    """
    env = os.environ if environ is None else environ
    system_path = SYSTEM_CONFIG if system_path is None else system_path
    items = tuple(overrides)
    if option is not None:
        return ConfigSource(file=option, found_by="option", overrides=items)
    named = env.get(CONFIG_ENV, "")
    if named:
        if not Path(named).exists():
            msg = (
                f"${CONFIG_ENV}={named}: no such file (unset the variable to use "
                f"{system_path} or the built-in defaults)"
            )
            raise ConfigError(msg)
        return ConfigSource(file=named, found_by="environment", overrides=items)
    if Path(system_path).exists():
        return ConfigSource(file=system_path, found_by="system", overrides=items)
    return ConfigSource(overrides=items)


def load_located(source: ConfigSource) -> Config:
    """The configuration :func:`locate_config` found (see :func:`load_config`)."""
    return load_config(source.file, list(source.overrides))


class KeyOrigin(msgspec.Struct, frozen=True, kw_only=True):
    """One key of the effective configuration, its value and where the value came from."""

    key: str
    """Dotted, as ``--set`` takes it: ``control.kp_xy``."""
    value: Any
    origin: str
    """``default``, the file (:attr:`ConfigSource.file_label`) or ``--set``."""


def leaf_keys(data: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping's leaves by dotted key (a list is one value, as in a config)."""
    if not isinstance(data, dict):
        return {prefix: data} if prefix else {}
    out: dict[str, Any] = {}
    for key, value in data.items():
        out.update(leaf_keys(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def key_origins(source: ConfigSource) -> list[KeyOrigin]:
    """Every key of the configuration ``source`` gives, in the Structs' order, with its origin.

    A ``--set`` of a section (``--set mk.signs={nick: 1}``) replaces the file's whole
    section, as :func:`apply_override` does: the keys it leaves out are defaults again.

    Raises:
        ConfigError: as :func:`load_config`.
    """
    cfg = load_located(source)
    origins: dict[str, str] = {}
    if source.file is not None:
        origins = dict.fromkeys(leaf_keys(read_yaml(source.file)), source.file_label)
    for item in source.overrides:
        parts, value = parse_override(item)
        dotted = ".".join(parts)
        origins = {k: v for k, v in origins.items() if not k.startswith(f"{dotted}.")}
        origins.update(dict.fromkeys(leaf_keys(value, dotted), "--set"))
    return [
        KeyOrigin(key=key, value=value, origin=origins.get(key, "default"))
        for key, value in leaf_keys(config_to_dict(cfg)).items()
    ]


def count_keys(path: str) -> int:
    """Check the config file ``path`` alone (on the defaults); how many keys it sets.

    Raises:
        ConfigError: as :func:`load_config`, naming the file and the dotted key.
    """
    data = read_yaml(path)
    config_from_dict(data, path)
    return len(leaf_keys(data))


def dump_key(key: str, value: Any) -> str:
    """``key: value`` on one line, YAML that :func:`read_yaml` reads back (a list in flow style)."""
    text = yaml.dump(
        value, Dumper=YamlDumper, default_flow_style=True, width=10**6, allow_unicode=True
    )
    return f"{key}: " + text.removesuffix("\n").removesuffix("\n...")
