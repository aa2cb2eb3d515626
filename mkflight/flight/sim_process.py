"""``fly --sim``: the simulated vehicle in its own process, on pseudo-terminals (SPEC §8).

The child is ``python -m mkflight sim --exit-on-eof`` with the flight's config: it prints
``mk PATH`` and ``laser PATH`` and serves both until it gets SIGTERM, or until its
standard input (a pipe from the daemon, never written) ends: a daemon killed with
SIGKILL leaves no simulator behind. The daemon then opens those
paths exactly as it opens real ports, so ``--sim`` flies the hardware code path; the child
writes the ground truth (``truth.txt``) into the flight folder.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys
from dataclasses import dataclass
from pathlib import Path

from mkflight.errors import FlightError

START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 5.0


@dataclass(slots=True)
class SimProcess:
    """A running ``mkflight sim`` child and its two device paths."""

    process: asyncio.subprocess.Process
    mk_port: str
    laser_port: str

    async def stop(self) -> int | None:
        """SIGTERM, then SIGKILL after :data:`STOP_TIMEOUT_S`; the exit code."""
        proc = self.process
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(proc.wait(), STOP_TIMEOUT_S)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()
        return proc.returncode


async def start_sim(
    *,
    config_path: str | None,
    overrides: list[str],
    truth: Path,
    seed: int | None = None,
    faults: list[str] | None = None,
) -> SimProcess:
    """Start ``mkflight sim`` and wait for its two paths.

    Raises:
        FlightError: the child exited or printed nothing usable within the timeout.
    """
    args = [sys.executable, "-m", "mkflight", "sim", "--truth", str(truth), "--exit-on-eof"]
    if config_path is not None:
        args += ["--config", config_path]
    for item in overrides:
        args += ["--set", item]
    if seed is not None:
        args += ["--seed", str(seed)]
    for fault in faults or []:
        args += ["--fault", fault]
    proc = await asyncio.create_subprocess_exec(
        *args,
        stdin=asyncio.subprocess.PIPE,  # never written: its end tells the child we are gone
        stdout=asyncio.subprocess.PIPE,
        start_new_session=True,  # a Ctrl-C on the terminal reaches the daemon, not the sim
    )
    assert proc.stdout is not None
    paths: dict[str, str] = {}
    try:
        async with asyncio.timeout(START_TIMEOUT_S):
            while len(paths) < 2:
                line = (await proc.stdout.readline()).decode("utf-8", "replace")
                if not line:
                    break
                key, _, value = line.strip().partition(" ")
                if key in ("mk", "laser") and value:
                    paths[key] = value
    except TimeoutError:
        pass
    except BaseException:  # cancelled while starting: the child must not outlive us
        await SimProcess(proc, "", "").stop()
        raise
    if len(paths) < 2:
        await SimProcess(proc, "", "").stop()
        msg = f"the simulator did not start (exit code {proc.returncode}); see its stderr above"
        raise FlightError(msg)
    return SimProcess(proc, paths["mk"], paths["laser"])
