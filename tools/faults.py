"""Fly the whole fault campaign and print (or write into the README) its table of results.

    python tools/faults.py             # every fault (~3 min on 2 cores); the table on stdout
    python tools/faults.py --readme    # ... and replace the table in README.md
    python tools/faults.py -k sigkill  # some of them (pytest's -k)

It runs ``pytest tests/faults`` (the same flights CI flies) with
``MKFLIGHT_FAULTS_REPORT`` naming a file where each test writes its verdict; the table is
made from those verdicts, so it says what this run saw. Exit code: pytest's (non-zero if
any fault was not handled).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
BEGIN = "<!-- faults:begin (tools/faults.py --readme writes this table) -->"
END = "<!-- faults:end -->"


def _cell(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _short(message: str, limit: int = 90) -> str:
    return message if len(message) <= limit else message[: limit - 1] + "…"


def _touchdowns(row: dict[str, Any]) -> str:
    """Our landing's touchdowns; "drop" before those that came before it (out of our hands)."""
    drops = [f"drop {v:.2f}" for v in row.get("drops_mps", [])]
    ours = [f"{v:.2f}" for v in row.get("touchdowns_mps", [])]
    return ", ".join(drops + ours) or "-"


def _verdict(row: dict[str, Any]) -> str:
    """ok, or FAILED and why (and the daemon defect it is known for, if any)."""
    if row["ok"]:
        return "ok"
    known = f" (known daemon issue: {row['known_issue']})" if row.get("known_issue") else ""
    return "FAILED: " + "; ".join(row["problems"]) + known


def table(rows: list[dict[str, Any]]) -> str:
    """The markdown table of the verdicts, in campaign order."""
    lines = [
        "| fault | fired (after HOLD) | the daemon's record (after the fault) | outcome "
        "| touchdowns m/s | extern control ended by | exit | message "
        "| commands (max tilt / gas, counts) | logs | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cmds = "none"
        if r["commands"]:
            cmds = f"{r['commands']} ({r['max_tilt_counts']:g} / {r['max_gas']})"
        lines.append(
            "| "
            + " | ".join(
                _cell(x)
                for x in (
                    r["what"],
                    r.get("fired") or "-",
                    r.get("record") or "-",
                    r["end"],
                    _touchdowns(r),
                    r["released_by"] or "-",
                    r["code"],
                    _short(r["message"]) or "-",
                    cmds,
                    r["logs"],
                    _verdict(r),
                )
            )
            + " |"
        )
    return "\n".join(lines)


def update_readme(text: str, readme: Path) -> None:
    """Replace what is between the markers in ``readme`` with ``text``."""
    content = readme.read_text(encoding="utf-8")
    start, end = content.find(BEGIN), content.find(END)
    if start < 0 or end < start:
        msg = f"{readme}: no {BEGIN!r} ... {END!r} markers"
        raise SystemExit(msg)
    readme.write_text(
        content[: start + len(BEGIN)] + "\n" + text + "\n" + content[end:], encoding="utf-8"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--readme", action="store_true", help="write the table into README.md")
    parser.add_argument("-k", metavar="EXPR", help="only the tests pytest -k selects")
    parser.add_argument("--json", metavar="FILE", help="also write the verdicts as JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "verdicts.jsonl"
        env = os.environ | {"MKFLIGHT_FAULTS_REPORT": str(report)}
        cmd = [sys.executable, "-m", "pytest", "tests/faults", "-q", "-p", "no:cacheprovider"]
        if args.k:
            cmd += ["-k", args.k]
        code = subprocess.run(cmd, cwd=REPO, env=env, check=False).returncode
        lines = report.read_text().splitlines() if report.exists() else []
        rows = [json.loads(line) for line in lines]
    from tests.faults.scenarios import SCENARIOS

    order = {sc.name: i for i, sc in enumerate(SCENARIOS)}
    rows.sort(key=lambda r: (order.get(r["name"], len(order)), r["name"]))
    text = table(rows)
    print(text)
    failed = sum(1 for r in rows if not r["ok"])
    print(f"\n{len(rows)} faults judged, {failed} not handled; pytest exit {code}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1), encoding="utf-8")
    if args.readme:
        update_readme(text, REPO / "README.md")
    return code


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
