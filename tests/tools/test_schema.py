"""tools/schema.py: the README's schema section is the Structs' own, generated."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BEGIN, END = "<!-- schema:begin -->", "<!-- schema:end -->"


def _tool(*args: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "schema.py"), *args],
        capture_output=True,
        text=True,
        check=True,
        env=env,
        timeout=60,
    )
    return done.stdout


def test_the_readme_section_is_what_the_tool_prints() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert readme.count(BEGIN) == readme.count(END) == 1
    section = readme.split(BEGIN + "\n", 1)[1].split(END, 1)[0]
    assert section == _tool(), (
        "README's schema section is stale: python tools/schema.py --write README.md"
    )


def test_every_kind_and_summary_part_is_in_it() -> None:
    from mkflight.logs.schema import KINDS

    text = _tool()
    for name, cls in KINDS.items():
        assert f"**`{name}` (`{cls.__name__}`)**" in text
    for part in ("FlightSummary", "HoverSummary", "Timing", "Learned", "MkLinkStats"):
        assert f"**`{part}`**" in text
    assert "| `x_m` | number \\| null | matched position x (W) (*may be absent*) |" in text


def test_write_replaces_only_the_section(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(f"# before\n{BEGIN}\nstale\n{END}\nafter\n", encoding="utf-8")
    _tool("--write", str(readme))
    assert readme.read_text(encoding="utf-8") == f"# before\n{BEGIN}\n{_tool()}{END}\nafter\n"
