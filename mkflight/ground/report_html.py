"""The HTML pieces of the flight report: escaped text, tables, sections, the page.

Every piece of text goes through :func:`html.escape` here, so a value read from a flight
folder (an error message, a config path, an unknown event's fields) is shown, never run.
The page carries its style inline and refers to no other resource: it opens offline, from
a mail attachment as well as from the flight folder.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape
from typing import Final

#: The page's whole style (no font, sheet or script is fetched).
CSS: Final = """
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1100px;
       padding: 1em 1.5em 3em; color: #222222; background: #ffffff; line-height: 1.4; }
h1 { font-size: 1.6em; margin: 0.2em 0; }
h2 { font-size: 1.25em; border-bottom: 2px solid #1f77b4; padding-bottom: 0.15em;
     margin-top: 1.6em; }
h3 { font-size: 1.0em; margin: 0.8em 0 0.3em; }
.sub { color: #555555; margin: 0 0 1em; }
.verdict { display: inline-block; padding: 0.25em 0.8em; border-radius: 4px;
           font-weight: bold; color: #ffffff; }
.verdict.ok { background: #2ca02c; }
.verdict.bad { background: #d62728; }
.verdict.warn { background: #e6820e; }
.verdict.unknown { background: #7f7f7f; }
table { border-collapse: collapse; margin: 0.3em 0 0.8em; font-size: 0.92em; }
th, td { border: 1px solid #d0d0d0; padding: 0.2em 0.6em; text-align: left;
         vertical-align: top; }
th { background: #f0f4f8; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.mine td { background: #eaf4ea; font-weight: 600; }
tr.alarm td, td.alarm { background: #fde0e0; }
.grid { display: flex; flex-wrap: wrap; gap: 0 2em; align-items: flex-start; }
.notes { border-left: 4px solid #ff7f0e; background: #fff5e8; padding: 0.4em 1em;
         margin: 0.8em 0; }
.notes li { margin: 0.1em 0; }
.missing { color: #8a5a00; font-style: italic; }
svg.bars { width: 100%; max-width: 900px; height: auto; }
svg.timeline { width: 100%; height: auto; border: 1px solid #e0e0e0; background: #fcfcfc; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #e0e0e0; }
figcaption { color: #555555; font-size: 0.9em; }
footer { margin-top: 3em; color: #777777; font-size: 0.85em; }
"""

NOT_KNOWN: Final = "n/a"


@dataclass(frozen=True, slots=True)
class Cell:
    """A table cell: its text and how it is shown (``num``: right-aligned; ``alarm``: red)."""

    text: str
    num: bool = False
    alarm: bool = False

    def html(self, tag: str = "td") -> str:
        """The cell, escaped."""
        classes = " ".join(c for c, on in (("num", self.num), ("alarm", self.alarm)) if on)
        attr = f' class="{classes}"' if classes else ""
        return f"<{tag}{attr}>{escape(self.text)}</{tag}>"


CellLike = Cell | str


def fmt(value: float | int | None, spec: str = "", unit: str = "") -> str:
    """A number as text with its unit; :data:`NOT_KNOWN` for None or non-finite."""
    if value is None or isinstance(value, bool):
        return NOT_KNOWN if value is None else ("yes" if value else "no")
    if isinstance(value, float) and not math.isfinite(value):
        return NOT_KNOWN
    text = format(value, spec)
    if text.startswith("-") and float(text) == 0.0:  # -0.0000: a small negative, rounded
        text = text[1:]
    return f"{text} {unit}" if unit else text


def num(value: float | int | None, spec: str = "", unit: str = "", *, alarm: bool = False) -> Cell:
    """A right-aligned number cell (:func:`fmt`)."""
    return Cell(fmt(value, spec, unit), num=True, alarm=alarm)


def _cell(c: CellLike) -> Cell:
    return c if isinstance(c, Cell) else Cell(c)


def table(
    head: Sequence[str],
    rows: Sequence[Sequence[CellLike]],
    *,
    row_classes: Sequence[str] = (),
    caption: str = "",
) -> str:
    """A table with a header row; ``row_classes[i]`` is row i's class (``mine``, ``alarm``)."""
    out = ["<table>"]
    if caption:
        out.append(f"<caption>{escape(caption)}</caption>")
    if head:
        out.append("<tr>" + "".join(Cell(h).html("th") for h in head) + "</tr>")
    for i, row in enumerate(rows):
        cls = row_classes[i] if i < len(row_classes) else ""
        attr = f' class="{escape(cls)}"' if cls else ""
        out.append(f"<tr{attr}>" + "".join(_cell(c).html() for c in row) + "</tr>")
    out.append("</table>")
    return "".join(out)


def kv_table(rows: Sequence[tuple[str, CellLike]], title: str = "") -> str:
    """A two-column table of names and values, under an ``<h3>`` when ``title`` is given."""
    body = table((), [(Cell(k), v) for k, v in rows])
    return f"<div><h3>{escape(title)}</h3>{body}</div>" if title else body


def para(text: str, cls: str = "") -> str:
    """A paragraph of escaped text."""
    attr = f' class="{escape(cls)}"' if cls else ""
    return f"<p{attr}>{escape(text)}</p>"


def missing(text: str) -> str:
    """A paragraph saying what the folder lacks for this section."""
    return para(text, "missing")


def section(anchor: str, title: str, body: Sequence[str]) -> str:
    """``<section>`` with its ``<h2>``; ``body`` is HTML already escaped."""
    return f'<section id="{escape(anchor)}"><h2>{escape(title)}</h2>{"".join(body)}</section>'


def bullet_list(items: Sequence[str], cls: str = "") -> str:
    """An unordered list of escaped items."""
    attr = f' class="{escape(cls)}"' if cls else ""
    return f"<ul{attr}>" + "".join(f"<li>{escape(i)}</li>" for i in items) + "</ul>"


def png_figure(name: str, png: bytes, caption: str) -> str:
    """A PNG inline as a ``data:`` URI, with its caption."""
    data = base64.b64encode(png).decode("ascii")
    return (
        f'<figure><img alt="{escape(name)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{escape(caption)}</figcaption></figure>"
    )


def page(title: str, body: Sequence[str]) -> str:
    """The whole document: UTF-8, the inline style, ``body`` (HTML already escaped)."""
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head>"
        f"<body>{''.join(body)}</body></html>\n"
    )
