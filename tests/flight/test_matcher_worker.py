"""MatcherWorker: a spawned, niced worker gives the inline numbers; deaths raise, close ends."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import os
import signal
import time
from collections.abc import AsyncIterator

import pytest
import pytest_asyncio

from mkflight.config import Config
from mkflight.flight.laser_pipeline import LaserPipeline, LaserResult
from mkflight.flight.matcher_worker import WORKER_NICE, MatcherError, MatcherWorker
from mkflight.msgs import Scan
from mkflight.sim.urg_scene import ScenePose
from tests.flight.test_laser_pipeline import HEIGHT_M, room_scene, scan_at, take_scan

pytestmark = pytest.mark.asyncio(loop_scope="module")

CFG = Config()
#: Guard against a hang (the test fails instead of blocking CI); never waited for.
GUARD_S = 15.0


def hover_scans(n: int) -> list[tuple[Scan, float, float]]:
    """``n`` scans of a slow hover with tilt, and the attitude at each scan's time."""

    def hover(t_ns: int) -> ScenePose:
        t = t_ns * 1e-9
        return ScenePose(
            x_m=0.1 * math.sin(0.8 * t),
            y_m=0.08 * math.sin(0.6 * t),
            yaw_rad=0.05 * math.sin(0.5 * t),
            height_m=HEIGHT_M,
            pitch_rad=0.03 * math.sin(1.2 * t),
            roll_rad=0.02,
        )

    scene = room_scene(hover, seed=11)
    out = []
    for i in range(n):
        scan = take_scan(scene, i)
        truth = hover(scan.t_ns)
        out.append((scan, truth.pitch_rad, truth.roll_rad))
    return out


def without_timing(r: LaserResult) -> LaserResult:
    return dataclasses.replace(r, compute_s=0.0, elapsed_s=0.0)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def worker() -> AsyncIterator[MatcherWorker]:
    """One spawned worker for the module (spawning costs ~0.5-1 s); tests reset() it."""
    w = MatcherWorker(CFG)
    await asyncio.wait_for(w.start(), GUARD_S)
    yield w
    await asyncio.wait_for(w.close(), GUARD_S)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


async def test_worker_is_another_process_at_lower_priority(worker: MatcherWorker) -> None:
    pid = worker.worker_pid
    assert pid is not None
    assert pid != os.getpid()
    ours = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, pid) == min(19, ours + WORKER_NICE)
    assert 0.0 < worker.warmup_s < GUARD_S
    assert await worker.start() == worker.warmup_s  # a second start() is a no-op


async def test_process_mode_gives_the_inline_numbers(worker: MatcherWorker) -> None:
    await worker.reset()
    inline = MatcherWorker(CFG, mode="inline")
    await inline.start()
    assert inline.worker_pid is None
    for scan, pitch, roll in hover_scans(15):
        remote = await asyncio.wait_for(worker.process(scan, pitch, roll), GUARD_S)
        local = await inline.process(scan, pitch, roll)
        assert without_timing(remote) == without_timing(local)
        assert remote.pose is not None
        assert remote.compute_s > 0.0
        assert worker.last_round_trip_s >= remote.elapsed_s
    await inline.close()


async def test_inline_mode_is_the_pipeline(worker: MatcherWorker) -> None:
    inline = MatcherWorker(CFG, mode="inline")
    assert await inline.start() > 0.0
    pipeline = LaserPipeline(CFG)
    for scan, pitch, roll in hover_scans(3):
        got = await inline.process(scan, pitch, roll, motion_prior=(0.0, 0.0, 0.0))
        want = pipeline.process(scan, pitch, roll, motion_prior=(0.0, 0.0, 0.0))
        assert without_timing(got) == without_timing(want)
    await inline.reset()
    first = await inline.process(scan_at(ScenePose(x_m=0.2, height_m=HEIGHT_M), 9), 0.0, 0.0)
    assert first.pose is not None
    assert (first.pose.x_m, first.pose.y_m, first.pose.yaw_rad) == (0.0, 0.0, 0.0)
    await inline.close()
    with pytest.raises(MatcherError, match="closed"):
        await inline.process(scan, 0.0, 0.0)


async def test_reset_and_queued_calls_answer_in_order(worker: MatcherWorker) -> None:
    await worker.reset()
    scans = hover_scans(5)
    results = await asyncio.wait_for(
        asyncio.gather(*(worker.process(s, p, r) for s, p, r in scans)), GUARD_S
    )
    assert [r.seq for r in results] == [0, 1, 2, 3, 4]
    assert results[0].new_keyframe
    await worker.reset()
    again = await worker.process(*scans[3])
    assert again.pose is not None
    assert (again.pose.x_m, again.pose.y_m, again.pose.yaw_rad) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("mode", ["process", "inline"])
async def test_a_raising_pipeline_is_a_matcher_error_and_the_worker_goes_on(
    worker: MatcherWorker, mode: str
) -> None:
    w = worker if mode == "process" else MatcherWorker(CFG, mode="inline")
    await w.start()
    scan, pitch, roll = hover_scans(1)[0]
    with pytest.raises(MatcherError, match="failed on scan seq 0: TypeError") as info:
        await asyncio.wait_for(w.process(scan, "level", roll), GUARD_S)  # type: ignore[arg-type]
    assert isinstance(info.value.__cause__, TypeError)
    assert (await asyncio.wait_for(w.process(scan, pitch, roll), GUARD_S)).height_m is not None


async def test_not_started_and_closed_raise() -> None:
    fresh = MatcherWorker(CFG)
    scan, pitch, roll = hover_scans(1)[0]
    with pytest.raises(MatcherError, match="not started"):
        await fresh.process(scan, pitch, roll)
    await fresh.close()
    await fresh.close()  # idempotent
    with pytest.raises(MatcherError, match="closed"):
        await fresh.start()
    with pytest.raises(MatcherError, match="closed"):
        await fresh.reset()


async def test_killed_worker_raises_matcher_error_promptly() -> None:
    w = MatcherWorker(CFG, nice=0)
    await asyncio.wait_for(w.start(), GUARD_S)
    pid = w.worker_pid
    assert pid is not None
    scan, pitch, roll = hover_scans(1)[0]
    assert (await w.process(scan, pitch, roll)).pose is not None
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(MatcherError, match=r"scan matcher process died \(exit code -9\)"):
        await asyncio.wait_for(w.process(scan, pitch, roll), GUARD_S)  # no hang: the guard
    with pytest.raises(MatcherError, match="died"):  # and every call after it
        await asyncio.wait_for(w.process(scan, pitch, roll), GUARD_S)
    await asyncio.wait_for(w.close(), GUARD_S)
    await w.close()
    assert not alive(pid)


async def test_close_kills_a_stopped_worker_and_fails_its_pending_scan() -> None:
    w = MatcherWorker(CFG, close_timeout_s=0.2)
    await asyncio.wait_for(w.start(), GUARD_S)
    pid = w.worker_pid
    assert pid is not None
    scan, pitch, roll = hover_scans(1)[0]
    try:
        os.kill(pid, signal.SIGSTOP)  # a hung worker: SIGTERM alone would not end it
        t0 = time.perf_counter()
        # gather runs process() up to its await on the executor, then close().
        pending, closed = await asyncio.wait_for(
            asyncio.gather(w.process(scan, pitch, roll), w.close(), return_exceptions=True),
            GUARD_S,
        )
        assert time.perf_counter() - t0 < 3.0
        assert closed is None
        assert isinstance(pending, MatcherError)
        assert "closed while a scan was" in str(pending)  # queued, or being matched
        assert not alive(pid)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
