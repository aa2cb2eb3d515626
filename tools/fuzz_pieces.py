"""Fuzzing's shared core: pieces and their sums, random reads, a pass's figures, the feed loop.

Streams are built from *pieces* whose effect on a parser is known exactly, whatever comes
before or after them, so a stream's expected counters are the sums of its pieces'
(:func:`check`). The pure passes (:func:`feed_pass`) feed the streams in random reads of 1 byte
to 4 KiB and check every counter after each batch. The MK pieces are in ``fuzz_mk.py``, the
SCIP ones in ``fuzz_urg.py``, the pty passes in ``fuzz_pty.py``, the command in ``fuzz.py``
(all beside this file; ``tools/`` is not a package, so they import each other by bare name).
"""

from __future__ import annotations

import dataclasses
import itertools
import random
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Generic, TypeVar

from mkflight.mk.codec import FrameParser
from mkflight.mk.codec import ParserStats as MkStats
from mkflight.urg.replies import ParserStats as UrgStats
from mkflight.urg.replies import ReplyParser

T = TypeVar("T")
Advance = Callable[[int], None]


# ================================================================= pieces and their sums
@dataclass(frozen=True, slots=True)
class Piece(Generic[T]):
    """Bytes, the ``valid`` frames/replies in them (``sizes``: their bytes on the wire) and
    the exact increments of the parser's other ``counts``; every other byte is discarded.
    The parser is idle before and after a piece."""

    data: bytes
    valid: tuple[T, ...] = ()
    sizes: tuple[int, ...] = ()
    counts: tuple[tuple[str, int], ...] = ()


def join(pieces: Iterable[Piece[T]]) -> Piece[T]:
    """One piece of several, in order."""
    items = list(pieces)
    counts: Counter[str] = Counter()
    for p in items:
        counts.update(dict(p.counts))
    return Piece(
        b"".join(p.data for p in items),
        tuple(v for p in items for v in p.valid),
        tuple(s for p in items for s in p.sizes),
        tuple(sorted(counts.items())),
    )


@dataclass(slots=True)
class Totals:
    """Sums over the pieces fed: what the parser's counters must read."""

    fed: int = 0
    valid: int = 0
    valid_bytes: int = 0
    counts: Counter[str] = field(default_factory=Counter)

    def add(self, piece: Piece[Any]) -> None:
        self.fed += len(piece.data)
        self.valid += len(piece.valid)
        self.valid_bytes += sum(piece.sizes)
        self.counts.update(dict(piece.counts))


MK_COUNTS: Final = ("crc_errors", "malformed", "overflows")
URG_COUNTS: Final = ("sum_errors", "malformed", "garbage_lines", "overflows")


def check(
    stats: MkStats | UrgStats,
    totals: Totals,
    found_bytes: int,
    buffered: int = 0,
    base: MkStats | UrgStats | None = None,
) -> list[str]:
    """A parser's counters (minus those of ``base``) against the pieces' sums; empty if they
    add up. ``found_bytes``: the wire bytes of the good frames/replies it returned;
    ``buffered``: the bytes it holds (pieces end with the parser idle: 0)."""
    got = dataclasses.asdict(stats)
    if base is not None:
        got = {k: v - dataclasses.asdict(base)[k] for k, v in got.items()}
    mk = isinstance(stats, MkStats)
    want = {
        "bytes_in": totals.fed,
        "frames" if mk else "replies": totals.valid,
        **{k: totals.counts[k] for k in (MK_COUNTS if mk else URG_COUNTS)},
        "discarded_bytes": totals.fed - totals.valid_bytes - buffered,
    }
    out = [f"{k} = {got[k]}, want {v}" for k, v in want.items() if got[k] != v]
    if found_bytes + got["discarded_bytes"] + buffered != got["bytes_in"]:
        out.append(
            f"{got['bytes_in']} bytes in != {found_bytes} good + "
            f"{got['discarded_bytes']} discarded + {buffered} buffered"
        )
    return out


def split(data: bytes, cuts: Iterable[int]) -> list[bytes]:
    """``data`` cut at the given offsets (taken modulo its length)."""
    points = sorted({c % len(data) for c in cuts} - {0}) if data else []
    return [data[a:b] for a, b in itertools.pairwise([0, *points, len(data)])]


# ================================================================= random lengths and reads
def random_length(rng: random.Random, mean: int) -> int:
    """A length around ``mean``: exponential, at most 40 means."""
    return min(int(rng.expovariate(1 / mean)), 40 * mean)


def random_chunks(rng: random.Random, data: bytes, most: int = 4096) -> Iterator[bytes]:
    """``data`` in reads of 1 byte to ``most`` bytes (mostly small, like a serial port's)."""
    pos = 0
    while pos < len(data):
        r = rng.random()
        n = (
            rng.randint(1, 8)
            if r < 0.1
            else rng.randint(1, 128)
            if r < 0.8
            else rng.randint(129, most)
        )
        yield data[pos : pos + n]
        pos += n


# ================================================================= results
@dataclass(slots=True)
class PassResult:
    """The figures of one pass."""

    name: str
    tried: int = 0
    valid: int = 0
    found: int = 0
    missed: int = 0
    exceptions: int = 0
    mismatches: int = 0
    out_of_limit: int | None = None
    seconds: float = 0.0
    notes: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        return bool(self.missed or self.exceptions or self.mismatches or self.out_of_limit)

    def mismatch(self, where: str, what: Sequence[str]) -> None:
        self.mismatches += len(what)
        self.problems.extend(f"{where}: {w}" for w in what[: max(0, 10 - len(self.problems))])

    def exception(self, err: BaseException, data: bytes) -> None:
        self.exceptions += 1
        if len(self.problems) < 10:
            self.problems.append(f"{err!r} escaped, fed {data[:120]!r}")

    def as_dict(self) -> dict[str, Any]:
        return {
            "pass": self.name,
            "tried": self.tried,
            "valid": self.valid,
            "found": self.found,
            "missed": self.missed,
            "exceptions": self.exceptions,
            "counter_mismatches": self.mismatches,
            "out_of_limit_commands": self.out_of_limit,
            "seconds": round(self.seconds, 2),
            "notes": self.notes,
            "problems": self.problems,
        }


class Matcher(Generic[T]):
    """Found items against the expected ones, in order: found, missed, unexpected."""

    def __init__(self, window: int = 64) -> None:
        self._expected: deque[tuple[T, int]] = deque()
        self._window = window
        self.found = self.missed = self.unexpected = self.found_bytes = 0

    def expect(self, piece: Piece[T]) -> None:
        self._expected.extend(zip(piece.valid, piece.sizes, strict=True))

    def saw(self, item: T) -> None:
        for j, (want, size) in enumerate(itertools.islice(self._expected, self._window)):
            if want == item:
                self.missed += j
                for _ in range(j + 1):
                    self._expected.popleft()
                self.found += 1
                self.found_bytes += size
                return
        self.unexpected += 1

    def finish(self) -> None:
        self.missed += len(self._expected)
        self._expected.clear()


# ================================================================= the pure feed loop
def feed_pass(
    name: str,
    parser: FrameParser | ReplyParser,
    batches: Iterator[tuple[Piece[Any], int]],
    rng: random.Random,
    advance: Advance,
) -> PassResult:
    """Feed each batch in random reads; match what comes out; check the counters per batch."""
    result = PassResult(name)
    started = time.perf_counter()
    match: Matcher[Any] = Matcher()
    totals = Totals()
    kinds: Counter[str] = Counter()
    for piece, tried in batches:
        kinds.update(f"valid {type(v).__name__}" for v in piece.valid)
        before = dataclasses.replace(parser.stats)
        bytes_before, batch = match.found_bytes, Totals()
        batch.add(piece)
        totals.add(piece)
        match.expect(piece)
        for chunk in random_chunks(rng, piece.data):
            try:
                out: Sequence[Any] = parser.feed(chunk)
            except Exception as err:  # the figure this pass is for
                result.exception(err, chunk)
                continue
            for item in out:
                match.saw(item)
        found_bytes = match.found_bytes - bytes_before
        result.mismatch(name, check(parser.stats, batch, found_bytes, parser.buffered, before))
        result.tried += tried
        advance(tried)
    match.finish()
    if match.unexpected:
        result.mismatch(name, [f"{match.unexpected} found that were not embedded"])
    result.mismatch(name, check(parser.stats, totals, match.found_bytes, parser.buffered))
    result.valid, result.found, result.missed = totals.valid, match.found, match.missed
    result.notes = {k: v for k, v in dataclasses.asdict(parser.stats).items() if v}
    if len(kinds) > 1:
        result.notes.update(sorted(kinds.items()))
    result.seconds = time.perf_counter() - started
    return result
