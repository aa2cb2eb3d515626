"""Fuzzing: seeded random streams through both parsers, the MK link and the URG driver.

Run: ``python tools/fuzz.py`` (``--frames N --scans N``, default 100000 each; ``--seed S``;
``--pty-frames N --pty-scans N`` for the pty passes, default 20000 and 5000; ``--json``).
Exit 0 only if every must-be-0 figure is 0; 1 otherwise; 2 on a usage error.

This file is the command: its arguments, the four passes in turn, the figures table and the
exit code. The passes and the stream builders live beside it (``tools/`` is not a package: run
as a script, this folder is on ``sys.path``; ``tests/fuzz/`` puts it there to load the tool):

* ``fuzz_pieces.py``: *pieces*, bytes whose effect on a parser is known exactly whatever comes
  before or after them, so a stream's expected counters are the sums of its pieces'; the
  counter check, random reads, a pass's figures, the pure passes' feed loop;
* ``fuzz_mk.py``: MK frame pieces (``mk-serial.md`` §3), their seeded random draws and the
  pure ``FrameParser`` pass;
* ``fuzz_urg.py``: SCIP reply pieces (``scip2.md`` §2, §6), their seeded random draws and the
  pure ``ReplyParser`` pass;
* ``fuzz_pty.py``: the passes through the real ``MkLink`` and ``UrgDriver`` on ptys.

The pure passes feed the streams in random reads of 1 byte to 4 KiB and check every counter
after each batch; the pty passes write units of pieces around one valid DebugOut /
current-stream scan and check that the consumer gets every one, unchanged, and that nothing
the link writes is out of limits. The builders ``tests/fuzz/`` uses are re-exported here.

Figures per pass: tried (frame or scan pieces; for SCIP, status/info/time replies are mixed
in besides and counted in valid and found), valid (embedded), found, missed, exceptions
escaped, counter mismatches (a counter that differs from its pieces' sum, a failed identity
``bytes_in = good bytes + discarded_bytes + buffered``, a frame found that was not
embedded), out-of-limit commands (MK link), seconds.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any, Final

from fuzz_mk import (
    frame_bytes,
    mk_corrupt,
    mk_frame,
    mk_garbage,
    mk_lookalike,
    mk_malformed,
    mk_message,
    mk_overflow,
    mk_truncated,
    run_mk_parser,
)
from fuzz_pieces import Advance, PassResult, Piece, Totals, check, join, split
from fuzz_pty import run_mk_link, run_urg_driver
from fuzz_urg import (
    Scip,
    run_urg_parser,
    scip1_switch,
    scip_after_garbage,
    scip_body,
    scip_corrupt,
    scip_garbage_block,
    scip_info,
    scip_malformed,
    scip_scan,
    scip_status,
    scip_time,
    scip_truncated,
)

from mkflight.commands.progress import tty_bar
from mkflight.eventlog import configure_events

__all__ = [  # the command, and the stream builders and passes tests/fuzz/ imports from here
    "MUST_BE_ZERO",
    "PassResult",
    "Piece",
    "Scip",
    "Totals",
    "check",
    "format_table",
    "frame_bytes",
    "join",
    "main",
    "mk_corrupt",
    "mk_frame",
    "mk_garbage",
    "mk_lookalike",
    "mk_malformed",
    "mk_message",
    "mk_overflow",
    "mk_truncated",
    "report",
    "run_mk_link",
    "run_urg_driver",
    "scip1_switch",
    "scip_after_garbage",
    "scip_body",
    "scip_corrupt",
    "scip_garbage_block",
    "scip_info",
    "scip_malformed",
    "scip_scan",
    "scip_status",
    "scip_time",
    "scip_truncated",
    "split",
]


# ================================================================= the command
MUST_BE_ZERO: Final = ("missed", "exceptions", "counter_mismatches", "out_of_limit_commands")


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        msg = f"{value} < 0"
        raise argparse.ArgumentTypeError(msg)
    return value


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument(
        "--frames", type=_count, default=100_000, help="MK frame pieces (pure pass)"
    )
    parser.add_argument(
        "--scans", type=_count, default=100_000, help="SCIP scan pieces (pure pass)"
    )
    parser.add_argument("--seed", type=int, default=1, help="seed of every random stream")
    parser.add_argument(
        "--pty-frames", type=_count, help="MK link pass (default min(frames, 20000))"
    )
    parser.add_argument(
        "--pty-scans", type=_count, help="URG driver pass (default min(scans, 5000))"
    )
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    if args.pty_frames is None:
        args.pty_frames = min(args.frames, 20_000)
    if args.pty_scans is None:
        args.pty_scans = min(args.scans, 5000)
    return args


def run(args: argparse.Namespace) -> list[PassResult]:
    """The four passes, each with its own stream of the seed."""
    total = args.frames + args.scans + args.pty_frames + args.pty_scans

    def rng(name: str) -> random.Random:
        return random.Random(f"{args.seed}:{name}")

    with tty_bar(total, "pieces") as bar:
        advance: Advance = bar.update if bar is not None else lambda k: None
        return [
            run_mk_parser(args.frames, rng("mk"), advance),
            run_urg_parser(args.scans, rng("urg"), advance),
            asyncio.run(run_mk_link(args.pty_frames, rng("mk-link"), advance)),
            asyncio.run(run_urg_driver(args.pty_scans, rng("urg-driver"), advance)),
        ]


def report(
    args: argparse.Namespace, results: Sequence[PassResult], seconds: float
) -> dict[str, Any]:
    passes = [r.as_dict() for r in results]
    return {
        "seed": args.seed,
        "frames": args.frames,
        "scans": args.scans,
        "pty_frames": args.pty_frames,
        "pty_scans": args.pty_scans,
        "passes": passes,
        "seconds": round(seconds, 1),
        "ok": not any(p[k] for p in passes for k in MUST_BE_ZERO),
    }


def format_table(rep: Mapping[str, Any]) -> str:
    head = (
        "pass",
        "tried",
        "valid",
        "found",
        "missed",
        "exceptions",
        "mismatches",
        "out-of-limit",
        "seconds",
    )
    rows = [head]
    for p in rep["passes"]:
        oof = p["out_of_limit_commands"]
        figures = (
            p["tried"],
            p["valid"],
            p["found"],
            p["missed"],
            p["exceptions"],
            p["counter_mismatches"],
        )
        rows.append(
            (p["pass"], *map(str, figures), "-" if oof is None else str(oof), f"{p['seconds']:.1f}")
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = [
        f"fuzz, seed {rep['seed']}: {rep['frames']} frames, {rep['scans']} scans; "
        f"through the link and the driver on ptys: {rep['pty_frames']} frames, "
        f"{rep['pty_scans']} scans",
        "",
    ]
    for r in rows:
        lines.append(
            "  ".join(
                [
                    r[0].ljust(widths[0]),
                    *(c.rjust(w) for c, w in zip(r[1:], widths[1:], strict=True)),
                ]
            )
        )
    lines.append("")
    for p in rep["passes"]:
        notes = ", ".join(f"{k} {v}" for k, v in p["notes"].items())
        lines.append(f"{p['pass']}: {notes}")
        lines.extend(f"  ! {problem}" for problem in p["problems"])
    verdict = (
        "OK: every must-be-0 figure is 0" if rep["ok"] else "FAILED: a must-be-0 figure is not 0"
    )
    lines.append(f"{verdict} ({rep['seconds']:.1f} s)")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    configure_events("warning")
    started = time.perf_counter()
    rep = report(args, run(args), time.perf_counter() - started)
    print(json.dumps(rep, indent=1) if args.json else format_table(rep))
    return 0 if rep["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
