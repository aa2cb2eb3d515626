"""The determinism check: two ExternControl streams, frame by frame (SPEC §6).

Replaying a flight with the configuration it flew must reproduce every ExternControl
frame byte for byte; :func:`compare_commands` finds the first frame that differs (its
number, both times and both frames) and, for a "what if" replay (``--set``), says how the
commands differ: how many frames, and per channel the mean and largest difference in MK
counts. Pure: the frames come in as ``(t_ns, wire bytes)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mkflight.mk.codec import FrameParser
from mkflight.mk.messages import ExternControl

CHANNELS = ("nick", "roll", "yaw", "gas", "config")


@dataclass(frozen=True, slots=True)
class FirstDifference:
    """The first frame that is not the same in both streams."""

    index: int
    t_original_ns: int | None
    t_replayed_ns: int | None
    original: bytes | None
    replayed: bytes | None


@dataclass(frozen=True, slots=True)
class ChannelDiff:
    """How one channel differs over the frames both streams have (MK counts)."""

    name: str
    frames_differing: int
    mean_abs: float
    max_abs: int
    mean_original: float
    mean_replayed: float


@dataclass(frozen=True, slots=True)
class CommandComparison:
    """The result of :func:`compare_commands`."""

    n_original: int
    n_replayed: int
    n_identical: int
    first: FirstDifference | None
    channels: tuple[ChannelDiff, ...]
    #: replayed frames sent after the recording ended (a killed flight): not compared
    n_after_end: int = 0

    @property
    def identical(self) -> bool:
        """Every frame is the same, and there are as many."""
        return self.first is None


def decode_frames(frames: list[tuple[int, bytes]]) -> np.ndarray:
    """(N, 5) int array of ``nick roll yaw gas config`` of each frame's wire bytes."""
    out = np.zeros((len(frames), len(CHANNELS)), dtype=np.int64)
    parser = FrameParser()
    for i, (_, wire) in enumerate(frames):
        decoded = [ExternControl.decode(f) for f in parser.feed(wire) if f.cmd == "b"]
        if decoded:
            c = decoded[-1]
            out[i] = (c.nick, c.roll, c.yaw, c.gas, c.config)
    return out


#: How long before the end of a recording a replayed frame may answer a read whose
#: original answer came after the end (one 50 ms step and its margin).
LAST_STEP_NS = 60_000_000


def compare_commands(
    original: list[tuple[int, bytes]],
    replayed: list[tuple[int, bytes]],
    *,
    end_ns: int | None = None,
) -> CommandComparison:
    """Compare two ExternControl streams (see the module docstring).

    ``end_ns``: when the original recording ended (a killed flight) or stops being whole
    (a raw file cut short); frames of either sent later are not compared (the replayed
    ones are counted in ``n_after_end``).
    """
    after = 0
    if end_ns is not None:
        kept = [f for f in replayed if f[0] <= end_ns]
        original = [f for f in original if f[0] <= end_ns]
        # The original wrote each frame a little after the read that caused it (the
        # step's CPU time), the replay at that read's time: a frame answering the last
        # reads before the end is in the replay but may be cut from the original.
        while len(kept) > len(original) and kept[-1][0] > end_ns - LAST_STEP_NS:
            kept.pop()
        after, replayed = len(replayed) - len(kept), kept
    n = min(len(original), len(replayed))
    first: FirstDifference | None = None
    identical = 0
    for i in range(n):
        if original[i][1] == replayed[i][1]:
            identical += 1
        elif first is None:
            first = FirstDifference(
                i, original[i][0], replayed[i][0], original[i][1], replayed[i][1]
            )
    if first is None and len(original) != len(replayed):
        o = original[n] if n < len(original) else None
        r = replayed[n] if n < len(replayed) else None
        first = FirstDifference(
            n,
            None if o is None else o[0],
            None if r is None else r[0],
            None if o is None else o[1],
            None if r is None else r[1],
        )
    a = decode_frames(original[:n])
    b = decode_frames(replayed[:n])
    channels = []
    for j, name in enumerate(CHANNELS):
        d = np.abs(a[:, j] - b[:, j]) if n else np.zeros(0, dtype=np.int64)
        channels.append(
            ChannelDiff(
                name=name,
                frames_differing=int(np.count_nonzero(d)),
                mean_abs=float(d.mean()) if n else 0.0,
                max_abs=int(d.max()) if n else 0,
                mean_original=float(a[:, j].mean()) if n else 0.0,
                mean_replayed=float(b[:, j].mean()) if n else 0.0,
            )
        )
    return CommandComparison(
        len(original), len(replayed), identical, first, tuple(channels), n_after_end=after
    )
