"""The suite's real-time flights (and mypy), run in the background while the other tests run.

A real-time flight (``mkflight sim`` and ``mkflight fly`` in their own processes, or
``fly --sim``) takes tens of seconds of wall time but little CPU (the daemon ~4 %, the
simulator ~10-15 % of a core). So the flights a session needs are not flown when their
fixture is first set up: each is a *job* (:func:`job`, a function of a fresh folder that
flies and returns what the tests read), and a test that reads one says so with the
``background`` marker (``@pytest.mark.background("key", ...)``, or a module's
``pytestmark``). When the session starts, ``tests/conftest.py`` starts the jobs of the
selected tests, :data:`AT_ONCE` at a time, in the order their tests will run, and moves the
modules of those tests after all others; the fixtures then wait for their job's result
(:meth:`Background.result`), by which time it is usually there. A long CPU-bound command
whose result a test reads (mypy) is a job too, run below the flights' priority.

The flights must not be starved by the CPU-bound tests beside them (a flight's late step
is a different flight: a harder touchdown, a replay that differs). The worker processes
that fly them are started before the main thread lowers its own priority
(:data:`MAIN_NICE`): on Linux a nice value is a thread's, and a process inherits the nice
value of the thread that forked it, so the flights run at the normal priority and the
tests, and the commands they run, below it. Tests that fly in this process (marked
``realtime``) run last, once the background flights have all ended.
"""

from __future__ import annotations

import multiprocessing
import os
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, Final, TypeVar

#: Flights flown side by side: ~0.7 of the 2 cores CI has, so the tests keep one.
AT_ONCE: Final = 4
#: The main thread's nice value once the flights are started: below the flights' 0,
#: not so low that a test's own real-time work stops when the flights start up
#: (``SCHED_IDLE`` shields the flights better, but then the emulators that tests run in
#: this process answer late: scans 0.1 s +- 10 ms apart, a stall restarted in time failed).
MAIN_NICE: Final = 10

T = TypeVar("T")
Job = Callable[[Path], Any]

#: Every job the test modules define, by key (filled as they are imported).
JOBS: dict[str, Job] = {}


def job(key: str) -> Callable[[Callable[[Path], T]], Callable[[Path], T]]:
    """Register the decorated function as the background job ``key``.

    It is called once a session, in a worker process, with a fresh empty folder of its
    own, and returns what the tests read (or raises: each test that reads it then errors
    with that exception).
    """

    def register(fn: Callable[[Path], T]) -> Callable[[Path], T]:
        if JOBS.setdefault(key, fn) is not fn:
            msg = f"two background jobs named {key!r}"
            raise ValueError(msg)
        return fn

    return register


class Background:
    """The session's background flights: :data:`AT_ONCE` worker processes and the jobs'
    futures, by key.

    Processes, not threads: a job's own timing (the signal it sends at a time counted
    from the hold, the moment it notes for it) must not wait for the interpreter lock of
    this process, whose main thread runs the CPU-bound tests below the flights' priority.
    A job is pickled by reference, so it is a module-level function (or a
    :func:`functools.partial` of one) of an importable module; what it returns is pickled
    back.
    """

    def __init__(self, base: Path, at_once: int = AT_ONCE) -> None:
        self.base = base
        self._pool = ProcessPoolExecutor(at_once, mp_context=multiprocessing.get_context("spawn"))
        self._futures: dict[str, Future[Any]] = {}

    def start(self, keys: Iterable[str]) -> None:
        """Queue the jobs ``keys``, in this order (those queued already stay where they are).

        The pool starts its worker processes as the first jobs come, in this thread: call
        it before :func:`lower_main_priority`.
        """
        for key in keys:
            if key not in JOBS:
                msg = f"no background job {key!r} (tests/background.py: job)"
                raise KeyError(msg)
            if key not in self._futures:
                folder = self.base / re.sub(r"[^\w.-]", "_", key)
                folder.mkdir()
                self._futures[key] = self._pool.submit(JOBS[key], folder)

    def result(self, key: str) -> Any:
        """The job ``key``'s result, once it has flown (or the exception it raised)."""
        if key not in self._futures:
            msg = f"background flight {key!r} read by a test not marked background({key!r})"
            raise KeyError(msg)
        return self._futures[key].result()

    def results(self, keys: Mapping[str, str]) -> Mapping[str, Any]:
        """A mapping of ``keys``' names to their jobs' results, each waited for when it is
        first read (a test waits for its own flight only)."""
        return _Results(self, keys)

    def wait_all(self) -> None:
        """Return when every job has ended (the CPU is then the tests' alone)."""
        wait(self._futures.values())

    def close(self) -> None:
        """Drop the jobs not started and wait for those flying (each has its own timeout)."""
        self._pool.shutdown(wait=True, cancel_futures=True)


class _Results(Mapping[str, Any]):
    """Names to background results, each read through :meth:`Background.result`."""

    def __init__(self, background: Background, keys: Mapping[str, str]) -> None:
        self._background = background
        self._keys = dict(keys)

    def __getitem__(self, name: str) -> Any:
        return self._background.result(self._keys[name])

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)


def lower_main_priority() -> None:
    """Lower the calling thread's priority to :data:`MAIN_NICE` (Linux: per thread; the
    threads and processes it starts from now on inherit it)."""
    current = os.getpriority(os.PRIO_PROCESS, 0)
    if current < MAIN_NICE:
        os.nice(MAIN_NICE - current)
