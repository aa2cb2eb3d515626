"""The README's schema section, generated from the Structs of ``mkflight.logs.schema``.

Prints the Markdown that stands between ``<!-- schema:begin -->`` and
``<!-- schema:end -->`` in README.md: every ``events.jsonl`` kind with its fields (JSON
type, meaning), then ``flight.json``'s summary and its parts. The types come from
``msgspec.json.schema_components``, the meanings from the Structs' docstrings and field
descriptions, so the README cannot drift from the code (``tests/tools/test_schema.py``).

Run: ``python tools/schema.py`` (print) or ``python tools/schema.py --write README.md``
(replace the section in place).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec

from mkflight.logs import schema
from mkflight.logs.schema import KINDS

BEGIN = "<!-- schema:begin -->"
END = "<!-- schema:end -->"

SUMMARY_PARTS: tuple[type[msgspec.Struct], ...] = (
    schema.FlightSummary,
    schema.Learned,
    schema.Timing,
    schema.CpuInHold,
    schema.PrecisionEstimate,
    schema.GcStats,
    schema.MatcherStats,
    schema.PreflightFigures,
    schema.MkLinkStats,
    schema.LaserLinkStats,
    schema.RawCounters,
    schema.HoverSummary,
)

INTRO = """\
Generated from `mkflight/logs/schema.py` by `python tools/schema.py` (a test checks this
section against it). Units are in the names; x and y are in the world frame W, height is
up. `null` is a value that is not finite or not known. A field marked *may be absent* is
left out of the line when there is nothing to say (which says something else than
`null`).

#### `events.jsonl`

One JSON object per line, in this key order: `t_ns` (integer: the flight clock's time of
the event, ns), `event` (the kind), then the kind's fields as listed. A reader keeps a line
of a kind it does not know (a newer writer's), or one whose fields do not fit its kind, as
an `UnknownEvent` with its fields, and warns."""

SUMMARY_INTRO = """\
#### `flight.json`: the summary

`summary` is `null` until the flight ends; then a `FlightSummary` (`mkflight fly`, told by
its `end_reason` key) or a `HoverSummary` (`mkflight sim hover`, told by `end`). A summary
that fits neither is read as an `UnknownSummary` holding its keys as they are."""


def _text(doc: str) -> str:
    """A docstring on one line, RST literals and roles as Markdown code."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"``\1``", " ".join(doc.split()))
    return re.sub(r"``([^`]+)``", r"`\1`", text)


def _type(s: dict[str, Any]) -> str:
    """A JSON schema fragment as a short type: ``number | null``, ``array of number``."""
    if "$ref" in s:
        return f"`{s['$ref'].rsplit('/', 1)[-1]}`"
    if "anyOf" in s:
        return " \\| ".join(_type(t) for t in s["anyOf"])
    kind = s.get("type")
    if kind == "array":
        return f"array of {_type(s['items'])}"
    if kind == "object" and "additionalProperties" in s:
        return f"object of {_type(s['additionalProperties'])}"
    return str(kind)


def _table(s: dict[str, Any], skip: tuple[str, ...] = ()) -> list[str]:
    """A Struct's fields as a Markdown table: name, type, meaning."""
    rows = ["| field | type | meaning |", "|---|---|---|"]
    required = set(s.get("required", ()))
    for name, prop in s["properties"].items():
        if name in skip:
            continue
        meaning = _text(prop.get("description", ""))
        if name not in required and "default" not in prop:
            meaning = f"{meaning} (*may be absent*)" if meaning else "*may be absent*"
        rows.append(f"| `{name}` | {_type(prop)} | {meaning} |")
    return rows


def _block(title: str, s: dict[str, Any], skip: tuple[str, ...] = ()) -> list[str]:
    lines = ["", f"**{title}**: {_text(s.get('description', ''))}"]
    if any(k not in skip for k in s["properties"]):
        lines += ["", *_table(s, skip)]
    return lines


def render() -> str:
    """The section's Markdown (without the two marker lines)."""
    kinds = list(KINDS.values())
    _, components = msgspec.json.schema_components(
        [*kinds, *SUMMARY_PARTS], ref_template="#/{name}"
    )
    lines = INTRO.split("\n")
    for name, cls in KINDS.items():
        title = f"`{name}` (`{cls.__name__}`)"
        lines += _block(title, components[cls.__name__], skip=("event", "t_ns"))
    lines += ["", *SUMMARY_INTRO.split("\n")]
    for part in SUMMARY_PARTS:
        lines += _block(f"`{part.__name__}`", components[part.__name__])
    return "\n".join(lines) + "\n"


def section_of(readme: str) -> str:
    """The text between the two markers of ``readme`` (ValueError without them)."""
    start = readme.index(BEGIN + "\n") + len(BEGIN) + 1
    return readme[start : readme.index(END, start)]


def main(argv: Sequence[str] | None = None) -> int:
    """Print the section, or write it into a README between its markers."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", metavar="README", help="replace the section in this file")
    args = parser.parse_args(argv)
    text = render()
    if args.write is None:
        sys.stdout.write(text)
        return 0
    path = Path(args.write)
    readme = path.read_text(encoding="utf-8")
    old = section_of(readme)
    start = readme.index(BEGIN + "\n") + len(BEGIN) + 1
    path.write_text(readme[:start] + text + readme[start + len(old) :], encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
