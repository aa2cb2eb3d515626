"""A scripted FlightCtrl for the link tests over the in-memory byte pair."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable

import pytest

from mkflight.config import Config, MkConfig, SafetyConfig
from mkflight.errors import LinkError
from mkflight.io.stream import MemoryStream, memory_pair
from mkflight.mk.codec import Frame, FrameParser
from mkflight.mk.link import LinkSettings, MkLink
from mkflight.mk.messages import Confirm, DebugOut, ExternControl, VersionInfo
from mkflight.mk.units import DEFAULT_CALIBRATION

MK08 = DebugOut.from_values(
    {0: -12, 1: 31, 2: -13, 3: 33, 4: -3, 5: 14, 6: -2, 7: 480, 9: 118, 10: 200, 11: 271}
)


def link_settings(mk: MkConfig | None = None, safety: SafetyConfig | None = None) -> LinkSettings:
    """The link's settings of a config with these ``mk`` and ``safety`` sections."""
    return LinkSettings.from_config(Config(mk=mk or MkConfig(), safety=safety or SafetyConfig()))


FAST = link_settings(
    MkConfig(
        answer_timeout_s=0.3,
        version_retry_s=0.1,
        release_interval_s=0.005,
        min_frame_gap_s=0.003,
    ),
    SafetyConfig(mk_stale_s=0.05),
)


class FakeFc:
    """Answers 'v' with 0.84a, 'b' with confirms, 'd' with one DebugOut; records frames."""

    def __init__(self, device: MemoryStream, *, answer: bool = True) -> None:
        self.device = device
        self.answer = answer
        self.frames: list[Frame] = []
        self.parser = FrameParser()
        self.received = asyncio.Event()

    async def run(self) -> None:
        with contextlib.suppress(LinkError):
            while True:
                data = await self.device.read()
                for frame in self.parser.feed(data):
                    self.frames.append(frame)
                    self.received.set()
                    if self.answer:
                        self.respond(frame)

    def respond(self, frame: Frame) -> None:
        if frame.cmd == "v":
            self.device.write(VersionInfo(0, 84, 11, 0, 0).encode())
        elif frame.cmd == "d" and frame.payload[0] > 0:
            self.device.write(MK08.encode())
        elif frame.cmd == "b" and frame.payload[9]:
            self.device.write(Confirm(frame.payload[9]).encode())

    def commands(self) -> list[ExternControl]:
        return [ExternControl.decode(f) for f in self.frames if f.cmd == "b"]

    def count(self, cmd: str) -> int:
        return sum(1 for f in self.frames if f.cmd == cmd)


@pytest.fixture
async def pair() -> AsyncIterator[tuple[MkLink, FakeFc]]:
    """A link on the host end of a memory pair, and a FakeFc on the device end."""
    host, device = memory_pair("host", "fc")
    fc = FakeFc(device)
    task = asyncio.create_task(fc.run())
    link = MkLink(host, FAST, DEFAULT_CALIBRATION)
    yield link, fc
    await link.close(release=False)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


async def _until(predicate: Callable[[], bool], fc: FakeFc) -> None:
    """Wait until ``predicate`` holds, re-checking each time the fake FC receives a frame."""
    while not predicate():
        fc.received.clear()
        await fc.received.wait()
