"""UrgDriver start-up against a scripted sensor on the in-memory pair (scip2.md §6)."""

from __future__ import annotations

import asyncio
import contextlib

import pytest

from mkflight.config import LaserConfig
from mkflight.errors import LinkError, ProtocolError
from mkflight.io.stream import MemoryStream, memory_pair
from mkflight.urg.driver import UrgDriver

from .vectors import ALL_VECTORS, ExchangeVector

FAST = LaserConfig(drain_silence_s=0.02, drain_max_s=0.2, request_timeout_s=0.3)


def reply_of(vector_id: str) -> bytes:
    vector = ALL_VECTORS[vector_id]
    assert isinstance(vector, ExchangeVector)
    return vector.reply


class ScriptedUrg:
    """Answers each command line with a canned reply (recorded URG-04LX replies)."""

    def __init__(self, device: MemoryStream, replies: dict[bytes, bytes]) -> None:
        self.device = device
        self.replies = replies
        self.commands: list[bytes] = []

    async def run(self) -> None:
        buffer = b""
        with contextlib.suppress(LinkError):
            while True:
                buffer += await self.device.read()
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    self.commands.append(line)
                    reply = self.replies.get(line)
                    if reply is not None:
                        self.device.write(reply)


def script(**overrides: bytes) -> dict[bytes, bytes]:
    replies = {
        b"QT": b"QT\n00P\n\n",
        b"SCIP2.0": reply_of("SC-02"),
        b"RS": b"RS\n00P\n\n",
        b"VV": reply_of("SC-03"),
        b"PP": reply_of("SC-04"),
        b"II": reply_of("SC-05"),
    }
    replies.update({k.encode(): v for k, v in overrides.items()})
    return replies


async def start(replies: dict[bytes, bytes]) -> tuple[UrgDriver, ScriptedUrg, asyncio.Task[None]]:
    host, device = memory_pair("/dev/ttyACM9", "urg")
    urg = ScriptedUrg(device, replies)
    task = asyncio.create_task(urg.run())
    return UrgDriver(host, FAST), urg, task


async def test_startup_sequence_follows_scip2_section_6() -> None:
    driver, urg, task = await start(script())
    info = await driver.connect()
    assert urg.commands == [b"QT", b"SCIP2.0", b"RS", b"VV", b"PP", b"II"]
    assert info.version["SERI"] == "H0706400"
    assert info.params.afront_step == 384
    await driver.close()
    task.cancel()


async def test_a_vv_with_a_bad_sum_is_not_fatal() -> None:
    """Some URG-04LX firmware sends a wrong SERI sum (scip2.md §6 item 9)."""
    bad_vv = reply_of("SC-03").replace(b"SERI:H0706400;F", b"SERI:H0706400;G")
    driver, _, task = await start(script(VV=bad_vv))
    info = await driver.connect()
    assert info.version == {}
    assert info.params.amax_step == 725
    assert driver.stats.parser.sum_errors == 1
    await driver.close()
    task.cancel()


async def test_time_adjust_mode_is_left_with_tm2() -> None:
    replies = script(RS=b"RS\n0Ee\n\n")
    replies[b"TM2"] = b"TM2\n00P\n\n"
    driver, urg, task = await start(replies)
    with pytest.raises(ProtocolError, match=r"RS -> 0E"):  # the scripted RS never recovers
        await driver.connect()
    assert b"TM2" in urg.commands
    await driver.close()
    task.cancel()


async def test_missing_pp_key_is_a_protocol_error_naming_it() -> None:
    pp = reply_of("SC-04").replace(b"AFRT:384;6\n", b"")
    driver, _, task = await start(script(PP=pp))
    with pytest.raises(ProtocolError, match="PP reply lacks AFRT"):
        await driver.connect()
    await driver.close()
    task.cancel()
