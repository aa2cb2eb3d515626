"""``mkflight config show`` and ``config check``: the effective config, a file's validity.

``show`` prints every key as ``section.key: value  # origin``, one line each: grep-able,
and the part before the ``#`` loads as YAML (a flat mapping of dotted keys, each of them
a ``--set`` item). The origin is ``default``, the file the search found (its path, or
``$MKFLIGHT_CONFIG=path``) or ``--set``. ``check`` validates one file on the defaults,
without the search, as ``--config`` would read it.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from mkflight.commands.args import Command, Subparsers, add_json, config_options, subcommands

if TYPE_CHECKING:
    from mkflight.config_search import ConfigSource, KeyOrigin


def show_lines(keys: list[KeyOrigin]) -> list[str]:
    """``key: value`` (YAML, a list in flow style) and the origin as an aligned comment."""
    from mkflight.config_search import dump_key

    pairs = [dump_key(k.key, k.value) for k in keys]
    width = max((len(p) for p in pairs), default=0)
    return [f"{p:<{width}}  # {k.origin}" for p, k in zip(pairs, keys, strict=True)]


def cmd_config_show(
    *,
    config_path: str | None,
    overrides: list[str],
    as_json: bool,
    config_source: ConfigSource | None = None,
) -> int:
    """Print the effective configuration, one key a line, with where each value came from.

    ``config_source`` is what the CLI's search found (:func:`mkflight.commands.args.use_config`);
    called directly, the file ``config_path`` and ``overrides``.
    """
    import msgspec

    from mkflight.config_search import ConfigSource, key_origins

    if config_source is None:
        config_source = ConfigSource(
            file=config_path,
            found_by="default" if config_path is None else "option",
            overrides=tuple(overrides),
        )
    keys = key_origins(config_source)
    if as_json:
        out = {"source": msgspec.to_builtins(config_source), "keys": msgspec.to_builtins(keys)}
        print(json.dumps(out))
        return 0
    for line in show_lines(keys):
        print(line)
    return 0


def cmd_config_check(*, file: str) -> int:
    """Validate the config file ``file``: ``FILE: ok (N keys set)``, else its ConfigError."""
    from mkflight.config_search import count_keys

    n = count_keys(file)
    print(f"{file}: ok ({n} key{'' if n == 1 else 's'} set)")
    return 0


def add_parser(subparsers: Subparsers) -> None:
    """``config show`` and ``config check``."""
    group = subparsers.add_parser("config", help="the configuration: show it, check a file")
    commands = subcommands(group, "config_command")
    show = commands.add_parser(
        "show",
        parents=[config_options()],
        help="print the effective config and where each value came from",
        description="Print every key of the configuration a command would use, one line "
        "each, as 'section.key: value  # origin' (default, the file, or --set). The file "
        "is --config, else $MKFLIGHT_CONFIG, else /etc/mkflight/config.yaml if it exists; "
        "the part before '#' loads as YAML.",
    )
    add_json(show, "one JSON object: the source and a list of {key, value, origin}")
    show.set_defaults(func=Command(cmd_config_show))
    check = commands.add_parser(
        "check",
        help="validate a config file",
        description="Read FILE as --config would, on the built-in defaults: 'FILE: ok' and "
        "how many keys it sets (exit 0), or the error naming the key (exit 2).",
    )
    check.add_argument("file", metavar="FILE", help="the YAML config file")
    check.set_defaults(func=Command(cmd_config_check))
