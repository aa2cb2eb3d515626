"""The daemon as a replay runs it: :class:`FlightApp` unchanged, watched and pinned.

:class:`ReplayApp` is the flight daemon (the same pre-flight, links, driver, tasks and
step) with replay-only additions, none of which changes what it computes:

* an operator's stop (SIGINT, SIGTERM, ``--duration``) comes before the step that first
  saw it in flight;
* READY comes at the recorded time (the pre-flight's length was the original machine's:
  spawning the matcher process), so the first step takes the same DebugOut;
* it tells the :class:`~mkflight.replay.feeder.Feeder` how many bytes it read per port
  and when it (re)opened one, so the lock-step clock moves only after each recorded
  chunk was seen;
* the scans the original skipped are skipped (the driver hands out the newest scan only,
  so a busy matcher process skipped one now and then): only the scans the ``scan``
  events name are matched;
* a scan's pose enters at the step the original flight applied it (the ``scan`` event's
  ``step``): in flight the matcher ran in another process, so that step depended on the
  process's timing, which a replay cannot re-create; it is an input of the recording;
* the scan matcher is :class:`RecordedMatcher`: the recorded results (``--fast``, and
  whenever the matcher's inputs and settings are the recorded ones), else the real
  matcher run in-process on the replayed scans (``--rematch``).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from mkflight.config import Config
from mkflight.conversions import NS_PER_S
from mkflight.flight.app import FlightApp, FlightOptions
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.matcher_worker import MatcherWorker
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.step import ImuStepOutput
from mkflight.io.stream import ByteStream
from mkflight.logs import table3, table4
from mkflight.msgs import ImuSample, Pose2D, Scan
from mkflight.replay.feeder import Feeder
from mkflight.replay.inputs import RecordedScan
from mkflight.replay.vloop import VirtualClock
from mkflight.safety.failsafe import StopRequest
from mkflight.scanmatch.geometry import Pose


class RecordedMatcher(MatcherWorker):
    """The in-process matcher that answers a recorded scan with its recorded result.

    Scans are known by their sequence number (a stamp that differs from the recorded
    one - the driver's time sync after a replayed replug - is counted); the others -
    the pre-flight's scans, which the original did not log - are matched for real.
    """

    def __init__(
        self, cfg: Config, scans: dict[int, RecordedScan], got_ns: dict[int, int] | None = None
    ) -> None:
        super().__init__(cfg, mode="inline")
        self._scans = scans
        self._got_ns = got_ns or {}
        #: the replay's clock (set by :class:`ReplayApp`)
        self._now_ns: Callable[[], int] = lambda: 0
        self.recorded_used = 0
        self.matched = 0
        self.stamp_differs = 0

    async def process(
        self,
        scan: Scan,
        pitch_rad: float,
        roll_rad: float,
        motion_prior: Pose | None = None,
    ) -> LaserResult:
        """The recorded result of ``scan`` if there is one, else a real match.

        Either way the answer comes when it came in flight (``got_ns``, on the lock-step
        clock): the matcher process took real time, and what the laser task saw next -
        a newer scan already there, or none yet and a stale stream to restart - depends on
        what arrived meanwhile.
        """
        got = self._got_ns.get(scan.seq)
        if got is not None:
            wait_ns = got - self._now_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / NS_PER_S)
        rec = self._scans.get(scan.seq)
        if rec is None:
            self.matched += 1
            return await super().process(scan, pitch_rad, roll_rad, motion_prior)
        self.recorded_used += 1
        if rec.t_ns != scan.t_ns:
            self.stamp_differs += 1
        pose = rec.pose
        if pose is not None:
            pose = Pose2D(scan.t_ns, pose.x_m, pose.y_m, pose.yaw_rad)
        return LaserResult(
            scan_t_ns=scan.t_ns,
            seq=scan.seq,
            pose=pose,
            pose_reason="" if rec.pose is not None else "recorded: no pose",
            height_m=rec.height_m,
            height_reason="" if rec.height_m is not None else "recorded: no height",
            degenerate=rec.degenerate,
            match_valid=rec.pose is not None,
            matched_fraction=float("nan"),
            new_keyframe=False,
            n_points=0,
            compute_s=0.0,
            elapsed_s=0.0,
        )


class ReplayApp(FlightApp):
    """:class:`FlightApp` on replayed ports (see the module docstring)."""

    def __init__(
        self,
        cfg: Config,
        opts: FlightOptions,
        *,
        clock: VirtualClock,
        feeder: Feeder,
        scans: dict[int, RecordedScan],
        use_recorded_poses: bool,
        ready_ns: int | None = None,
        subscribe_ns: int | None = None,
        step_stops: list[tuple[int, StopRequest, str]] | None = None,
        intact_end_ns: int | None = None,
    ) -> None:
        super().__init__(cfg, opts, clock=clock, notifier=Notifier(None))
        self._intact_end_ns = intact_end_ns
        #: each table's last row index written by the intact end (a recording cut short)
        self.rows_at_intact_end: dict[str, int] = {}
        self.feeder = feeder
        self._ready_ns = ready_ns
        self._subscribe_ns = subscribe_ns
        self._step_stops = sorted(step_stops or [], key=lambda s: s[0])
        self._steps = {seq: s.step for seq, s in scans.items() if s.step is not None}
        got = {seq: t for seq, s in scans.items() if (t := s.back_ns) is not None}
        self.recorded = RecordedMatcher(cfg, scans if use_recorded_poses else {}, got)
        self.recorded._now_ns = clock.now_ns
        self.worker = self.recorded
        feeder.closed["mk"] = lambda: self.link is not None and self.link.closed
        feeder.closed["laser"] = lambda: self.driver is not None and self.driver.closed

    async def open_port(self, path: str, baudrate: int) -> ByteStream:
        """A memory port when the feeder plays from memory, else the real (pty) open."""
        if self.feeder.memory:
            return self.feeder.open_memory(path)
        return await super().open_port(path, baudrate)

    def _mk_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        super()._mk_tap(direction, t_ns, data)
        if direction == "r":
            self.feeder.on_read("mk", len(data))
        elif direction == "w":
            self.feeder.on_wrote("mk", len(data))

    def _laser_tap(self, direction: str, t_ns: int, data: bytes) -> None:
        super()._laser_tap(direction, t_ns, data)
        if direction == "r":
            self.feeder.on_read("laser", len(data))
        elif direction == "w":
            self.feeder.on_wrote("laser", len(data))

    def mark(self, which: str, kind: str, text: str) -> None:
        """Record the mark, and tell the feeder the port is open or given up."""
        super().mark(which, kind, text)
        if kind == "o":
            self.feeder.on_open(which)
        elif kind == "c":
            self.feeder.on_lost(which)

    async def before_ready(self) -> None:
        """Wait (on the lock-step clock) until the original flight's READY."""
        if self._ready_ns is not None:
            wait_ns = self._ready_ns - self.clock.now_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / NS_PER_S)

    async def before_subscribe(self) -> None:
        """The MK task's first 'd' goes out when it went out in flight.

        The task started some ms after READY there; a DebugOut sent at once in answer can
        find the wire still busy with the 'd' and queue, so that the next command replaces
        it: the frame numbers depend on that time.
        """
        if self._subscribe_ns is not None:
            wait_ns = self._subscribe_ns - self.clock.now_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / NS_PER_S)

    def step(self, sample: ImuSample) -> ImuStepOutput:
        """A recorded operator stop first, if the original's next step saw one; the step."""
        while self._step_stops and self._step_stops[0][0] <= self.core.counters.imu_steps:
            _, request, reason = self._step_stops.pop(0)
            self.request_stop(request, reason)
        out = super().step(sample)
        if (
            self._intact_end_ns is not None
            and self.clock.now_ns() <= self._intact_end_ns
            and self.logs is not None
        ):
            for name, writer in (
                (table4.FILE_NAME, self.logs.t4),
                (table3.FILE_NAME, self.logs.t3),
            ):
                if writer.last_index is not None:
                    self.rows_at_intact_end[name] = writer.last_index
        return out

    def _on_signal(self, request: StopRequest, name: str) -> None:
        """SIGINT/SIGTERM/SIGHUP end the replay (there is no vehicle to land)."""
        raise KeyboardInterrupt(name)

    def scan_wanted(self, seq: int) -> bool:
        """A scan the original flight applied (the others it skipped: its matcher was busy)."""
        return not self._steps or seq in self._steps

    def laser_result_due(self, result: LaserResult, step: int) -> bool:
        """A recorded scan enters at its recorded step; others at once."""
        return step >= self._steps.get(result.seq, 0)

    def replay_stats(self) -> dict[str, Any]:
        """How the scans were matched."""
        return {
            "recorded_poses": self.recorded.recorded_used,
            "matched": self.recorded.matched,
            "stamp_differs": self.recorded.stamp_differs,
        }
