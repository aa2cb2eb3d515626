"""The scan matcher off the control loop: a low-priority worker process (SPEC §9).

A PL-ICP match takes 1-3 ms of CPU. Run on the asyncio loop that turns each DebugOut into an
ExternControl, it would delay that command by as much (SPEC §9: DebugOut -> ExternControl
median <= 1 ms, p99 <= 5 ms *with ICP running*), and a thread would not help: the GIL
serialises the numpy glue. :class:`MatcherWorker` therefore runs
:class:`~mkflight.flight.laser_pipeline.LaserPipeline` in one worker process of a
``ProcessPoolExecutor``:

* the **spawn** start method (not fork: the parent has an event loop and threads, whose
  locks a forked child would inherit mid-use);
* the initializer builds the pipeline from the :class:`~mkflight.config.Config` (a frozen
  msgspec Struct: it pickles) and lowers the worker's priority by ``nice`` (default 5),
  so the control process wins the CPU when both want it;
* the pipeline's state (keyframes, velocity) lives in the worker; per scan the loop thread
  only queues the call, and the executor's manager and feeder threads pickle the ~5.6 kB
  scan, do the pipe I/O and unpickle the small result. Those threads share the GIL with the
  loop: queuing a call holds the loop 0.14 ms median, 0.7 ms p99 on a 2-vCPU development
  VM, against the 1.3-2.4 ms a match holds it inline;
* :meth:`MatcherWorker.start` warms the worker up (imports, a two-scan dummy match on a
  throw-away pipeline), so the first real scan is not slow, and reports how long it took;
* a worker that dies (killed, crashed) turns the next :meth:`MatcherWorker.process` into a
  :class:`MatcherError` naming the exit code -- the daemon treats it as "no pose" and
  fails safe; there is no silent restart (a new worker would start a new world frame);
* :meth:`MatcherWorker.close` never hangs: a worker that does not exit within
  ``close_timeout_s`` is terminated, then killed.

``mode="inline"`` runs the same pipeline synchronously on the caller's thread: for replay
(determinism, no process) and tests. Both modes give identical numbers for the same scans.
"""

from __future__ import annotations

import asyncio
import math
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Literal

import numpy as np

from mkflight.config import Config
from mkflight.flight.laser_pipeline import LaserPipeline, LaserResult
from mkflight.msgs import Scan
from mkflight.scanmatch.geometry import FloatArray, Pose
from mkflight.urg.replies import BlockDecoder

if TYPE_CHECKING:
    from multiprocessing.process import BaseProcess

#: Default priority decrease of the worker (``os.nice`` increment).
WORKER_NICE = 5
#: Default time a worker gets to exit on :meth:`MatcherWorker.close` before it is killed.
CLOSE_TIMEOUT_S = 2.0
#: Time to reap a dead worker for its exit code before reporting it unknown.
_REAP_TIMEOUT_S = 1.0

_pipeline: LaserPipeline | None = None  # the worker process's pipeline (see _init_worker)


class MatcherError(RuntimeError):
    """The scan matcher cannot answer: its process died, or the matcher was closed/not started."""


PARENT_POLL_S = 1.0
"""How often the worker checks that the daemon still exists."""


def _watch_parent(parent_pid: int) -> None:
    """Exit when the daemon is gone (killed with SIGKILL: nobody will shut us down)."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


def _init_worker(cfg: Config, nice: int, parent_pid: int) -> None:
    """Worker initializer: lower the priority, build the pipeline (runs in the worker).

    A Ctrl-C on the terminal reaches the whole process group, and a dropped ssh session
    sends SIGHUP: the worker ignores both, so the daemon's soft landing keeps its poses
    (the daemon ends the worker itself when it has landed).
    """
    global _pipeline  # the worker process's one pipeline
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()
    if nice > 0:
        os.nice(nice)
    _pipeline = LaserPipeline(cfg)


def _run(scan: Scan, pitch_rad: float, roll_rad: float, motion_prior: Pose | None) -> LaserResult:
    """One scan through the worker's pipeline (runs in the worker)."""
    if _pipeline is None:
        msg = "scan matcher worker has no pipeline (initializer did not run)"
        raise MatcherError(msg)
    return _pipeline.process(scan, pitch_rad, roll_rad, motion_prior)


def _reset() -> None:
    """Forget the worker pipeline's keyframes (runs in the worker)."""
    if _pipeline is not None:
        _pipeline.reset()


def _room_ranges(half_x_m: float, half_y_m: float, angles_rad: FloatArray) -> FloatArray:
    """Ranges from the centre of a box room ``half_x_m`` by ``half_y_m`` (math-frame angles)."""
    with np.errstate(divide="ignore"):
        to_x = half_x_m / np.abs(np.cos(angles_rad))
        to_y = half_y_m / np.abs(np.sin(angles_rad))
    out: FloatArray = np.minimum(to_x, to_y)
    return out


def warm_up(cfg: Config) -> int:
    """Two synthetic scans through a throw-away pipeline: load every code path once.

    The first call of the matcher's kernel loads (or, the first time on a machine,
    compiles) its machine code, and numpy's first calls pay for imports and caches; doing
    it here keeps it off the first real scan. A
    throw-away pipeline, so the real one's state is untouched. Returns the process id.
    """
    pipeline = LaserPipeline(cfg)
    steps = np.arange(44, 726, dtype=np.float64)
    angles = (steps - 384.0) * (2.0 * math.pi / 1024.0)  # sensor frame, counter-clockwise
    ranges = _room_ranges(2.5, 1.7, angles)
    ranges[steps < 128] = 0.65  # the hat sees a floor 0.6 m below
    for i, shift in enumerate((0.0, 0.01)):
        scan = Scan(t_ns=i * 100_000_000, ranges_m=ranges - shift, first_step=44, seq=i)
        pipeline.process(scan, 0.0, 0.0)
    return os.getpid()


class MatcherWorker:
    """The laser pipeline in a worker process ("process") or on the caller's thread ("inline").

    Use: ``await start()`` once, then ``await process(scan, pitch, roll)`` per scan, one
    at a time (concurrent calls queue in order), and ``await close()`` at the end.

    Args:
        cfg: the configuration the pipeline is built from.
        mode: "process" (default: a spawned worker at lower priority) or "inline".
        nice: priority decrease of the worker process (0 = none).
        close_timeout_s: how long :meth:`close` waits for the worker to exit before it
            terminates it.
    """

    def __init__(
        self,
        cfg: Config,
        mode: Literal["process", "inline"] = "process",
        *,
        nice: int = WORKER_NICE,
        close_timeout_s: float = CLOSE_TIMEOUT_S,
    ) -> None:
        self.cfg = cfg
        self.mode = mode
        self.nice = nice
        self.close_timeout_s = close_timeout_s
        #: seconds :meth:`start` took (spawn, imports, dummy match); NaN before.
        self.warmup_s = math.nan
        #: round trip of the last :meth:`process` call as the caller saw it (s); NaN before.
        self.last_round_trip_s = math.nan
        self._executor: ProcessPoolExecutor | None = None
        self._process: BaseProcess | None = None
        self._pipeline: LaserPipeline | None = None
        self._pid: int | None = None
        self._closed = False

    @property
    def worker_pid(self) -> int | None:
        """The worker process's id (None inline, or before :meth:`start`)."""
        return self._pid

    async def start(self) -> float:
        """Start and warm up the matcher; returns the seconds it took (also :attr:`warmup_s`).

        Raises:
            MatcherError: closed already, or the worker died while starting.
        """
        if self._closed:
            msg = "scan matcher is closed"
            raise MatcherError(msg)
        if self._pipeline is not None or self._executor is not None:
            return self.warmup_s
        t0 = time.perf_counter()
        if self.mode == "inline":
            warm_up(self.cfg)
            self._pipeline = LaserPipeline(self.cfg)
        else:
            self._executor = ProcessPoolExecutor(
                max_workers=1,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=(self.cfg, self.nice, os.getpid()),
            )
            loop = asyncio.get_running_loop()
            try:
                future = loop.run_in_executor(self._executor, warm_up, self.cfg)
                # The pool spawns its one worker on the first submit: keep its handle (a
                # private attribute of the pool) so a death can be reported with the exit
                # code; without it the code is reported unknown.
                self._process = next(iter(getattr(self._executor, "_processes", {}).values()), None)
                self._pid = await future
            except BrokenProcessPool as err:
                raise await self._died(err) from err
        self.warmup_s = time.perf_counter() - t0
        return self.warmup_s

    async def process(
        self,
        scan: Scan,
        pitch_rad: float,
        roll_rad: float,
        motion_prior: Pose | None = None,
    ) -> LaserResult:
        """Pose, height and degeneracy of one scan (see :meth:`LaserPipeline.process`).

        Raises:
            MatcherError: not started, closed, the worker process died, or the pipeline
                raised (a bug: the pipeline never raises on bad data); the worker stays
                usable after the last.
        """
        if self._pipeline is not None:
            return self.process_now(scan, pitch_rad, roll_rad, motion_prior)
        t0 = time.perf_counter()
        try:
            result = await self._submit_run(scan, pitch_rad, roll_rad, motion_prior)
        except MatcherError:
            raise
        except Exception as err:  # a bug or an unpicklable input: this scan has no pose
            msg = f"scan matcher failed on scan seq {getattr(scan, 'seq', '?')}: {err!r}"
            raise MatcherError(msg) from err
        self.last_round_trip_s = time.perf_counter() - t0
        return result

    @property
    def runs_now(self) -> bool:
        """:meth:`process_now` may stand for :meth:`process`: it would not suspend.

        The pipeline runs on the caller's thread (``inline``, started), and
        :meth:`process` is this class's own (a subclass that changes it is awaited).
        """
        return self._pipeline is not None and type(self).process is MatcherWorker.process

    @property
    def scan_blocks(self) -> BlockDecoder | None:
        """The compiled decoder of a scan's SCIP blocks, when the pipeline runs here with one.

        (:mod:`mkflight.urg.kernel_numba`, loaded with the matcher's kernel: the URG
        driver of the same process may decode with it.)
        """
        return None if self._pipeline is None else self._pipeline.kernel.scan_blocks

    def process_now(
        self,
        scan: Scan,
        pitch_rad: float,
        roll_rad: float,
        motion_prior: Pose | None = None,
    ) -> LaserResult:
        """:meth:`process` inline, without a coroutine: for a caller in a port's callback.

        Raises:
            MatcherError: not started inline, closed, or the pipeline raised (a bug).
        """
        pipeline = self._pipeline
        if pipeline is None:
            msg = "scan matcher does not run inline (or is closed)"
            raise MatcherError(msg)
        t0 = time.perf_counter()
        try:
            result = pipeline.process(scan, pitch_rad, roll_rad, motion_prior)
        except Exception as err:  # a bug: this scan has no pose
            msg = f"scan matcher failed on scan seq {getattr(scan, 'seq', '?')}: {err!r}"
            raise MatcherError(msg) from err
        self.last_round_trip_s = time.perf_counter() - t0
        return result

    async def _submit_run(
        self, scan: Scan, pitch_rad: float, roll_rad: float, motion_prior: Pose | None
    ) -> LaserResult:
        executor = self._usable_executor()
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(
                executor, _run, scan, pitch_rad, roll_rad, motion_prior
            )
        except BrokenProcessPool as err:
            raise await self._died(err) from err
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if self._closed and (task is None or task.cancelling() == 0):
                msg = "scan matcher closed while a scan was queued"
                raise MatcherError(msg) from None
            raise

    async def reset(self) -> None:
        """Forget every keyframe: the next valid scan defines a new world frame (a new flight).

        Raises:
            MatcherError: not started, closed, or the worker process died.
        """
        if self._pipeline is not None:
            self._pipeline.reset()
            return
        executor = self._usable_executor()
        try:
            await asyncio.get_running_loop().run_in_executor(executor, _reset)
        except BrokenProcessPool as err:
            raise await self._died(err) from err

    def _usable_executor(self) -> ProcessPoolExecutor:
        if self._closed:
            msg = "scan matcher is closed"
            raise MatcherError(msg)
        if self._executor is None:
            msg = "scan matcher not started: await start() first"
            raise MatcherError(msg)
        return self._executor

    async def _died(self, err: BaseException) -> MatcherError:
        """The error for a broken pool, naming the worker's exit code when it can be had."""
        if self._closed:
            return MatcherError("scan matcher closed while a scan was being matched")
        code: int | None = None
        proc = self._process
        if proc is not None:
            # The pool fails the futures before it reaps the worker: wait for the exit code.
            await asyncio.to_thread(proc.join, _REAP_TIMEOUT_S)
            code = proc.exitcode
        what = "unknown" if code is None else str(code)
        return MatcherError(f"scan matcher process died (exit code {what}): {err}")

    async def close(self) -> None:
        """Stop the worker (pending scans are cancelled); idempotent, never hangs.

        The worker finishes the scan it is matching and exits; if it has not within
        :attr:`close_timeout_s` (hung, stopped), it is terminated, then killed.
        """
        if self._closed:
            return
        self._closed = True
        self._pipeline = None
        executor, self._executor = self._executor, None
        if executor is None:
            return
        executor.shutdown(wait=False, cancel_futures=True)
        proc = self._process
        if proc is None:
            return
        await asyncio.to_thread(proc.join, self.close_timeout_s)
        if proc.exitcode is None:
            proc.terminate()
            await asyncio.to_thread(proc.join, 0.5)
        if proc.exitcode is None:
            proc.kill()  # SIGTERM waits on a stopped process; SIGKILL does not
            await asyncio.to_thread(proc.join, 1.0)
