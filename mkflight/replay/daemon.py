"""The daemon as a replay runs it: :class:`FlightApp` unchanged, watched and pinned.

:class:`ReplayApp` is the flight daemon (the same pre-flight, links, driver, tasks and
step) run with a :class:`ReplayPolicy` and a :class:`RecordedMatcher`, whose additions
change nothing it computes:

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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mkflight.config import Config
from mkflight.conversions import NS_PER_S
from mkflight.flight.app import FlightApp, FlightOptions, FlightReport
from mkflight.flight.flight_logs import FlightLogs
from mkflight.flight.laser_pipeline import LaserResult
from mkflight.flight.matcher_worker import MatcherWorker
from mkflight.flight.policy import FlightPolicy
from mkflight.flight.sdnotify import Notifier
from mkflight.flight.step import ImuStepOutput
from mkflight.io.stream import ByteStream
from mkflight.logs import table3, table4
from mkflight.msgs import Pose2D, Scan
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
        self,
        cfg: Config,
        scans: dict[int, RecordedScan],
        got_ns: dict[int, int] | None = None,
        *,
        now_ns: Callable[[], int],
    ) -> None:
        """``got_ns``: when each scan's result came back in flight (on ``now_ns``'s clock)."""
        super().__init__(cfg, mode="inline")
        self._scans = scans
        self._got_ns = got_ns or {}
        self._now_ns = now_ns
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


def replay_options(feeder: Feeder, out: Path) -> FlightOptions:
    """The replayed daemon's options: the feeder's ports, ``out``, logs not fsynced."""
    return FlightOptions(
        mk_port=feeder.path("mk"),
        laser_port=feeder.path("laser"),
        log_dir=out,
        durable_logs=False,
    )


class ReplayPolicy(FlightPolicy):
    """What a replay pins and watches in the flight shell (see the module docstring)."""

    def __init__(
        self,
        *,
        clock: VirtualClock,
        feeder: Feeder,
        scans: dict[int, RecordedScan],
        ready_ns: int | None = None,
        subscribe_ns: int | None = None,
        step_stops: list[tuple[int, StopRequest, str]] | None = None,
        intact_end_ns: int | None = None,
    ) -> None:
        self._clock = clock
        self._feeder = feeder
        self._ready_ns = ready_ns
        self._subscribe_ns = subscribe_ns
        self._step_stops = sorted(step_stops or [], key=lambda s: s[0])
        self._steps = {seq: s.step for seq, s in scans.items() if s.step is not None}
        self._intact_end_ns = intact_end_ns
        #: each table's last row index written by the intact end (a recording cut short)
        self.rows_at_intact_end: dict[str, int] = {}

    async def open_port(self, path: str, baudrate: int) -> ByteStream:
        """A memory port when the feeder plays from memory, else the real (pty) open."""
        if self._feeder.memory:
            return self._feeder.open_memory(path)
        return await super().open_port(path, baudrate)

    def on_bytes(self, port: str, direction: str, n_bytes: int) -> None:
        """Tell the feeder what the daemon consumed and sent."""
        if direction == "r":
            self._feeder.on_read(port, n_bytes)
        elif direction == "w":
            self._feeder.on_wrote(port, n_bytes)

    def on_mark(self, port: str, kind: str) -> None:
        """Tell the feeder the port is open or given up."""
        if kind == "o":
            self._feeder.on_open(port)
        elif kind == "c":
            self._feeder.on_lost(port)

    async def _until(self, t_ns: int | None) -> None:
        """Sleep on the lock-step clock until ``t_ns`` (None: return at once)."""
        if t_ns is not None:
            wait_ns = t_ns - self._clock.now_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / NS_PER_S)

    async def before_ready(self) -> None:
        """Wait (on the lock-step clock) until the original flight's READY."""
        await self._until(self._ready_ns)

    async def before_subscribe(self) -> None:
        """The MK task's first 'd' goes out when it went out in flight.

        The task started some ms after READY there; a DebugOut sent at once in answer can
        find the wire still busy with the 'd' and queue, so that the next command replaces
        it: the frame numbers depend on that time.
        """
        await self._until(self._subscribe_ns)

    def stops_due(self, steps: int) -> Sequence[tuple[StopRequest, str]]:
        """The recorded operator stops that the original's next step saw first."""
        due: list[tuple[StopRequest, str]] = []
        while self._step_stops and self._step_stops[0][0] <= steps:
            _, request, reason = self._step_stops.pop(0)
            due.append((request, reason))
        return due

    def after_step(self, logs: FlightLogs) -> None:
        """Note the tables' last rows while the recording was intact."""
        if self._intact_end_ns is not None and self._clock.now_ns() <= self._intact_end_ns:
            for name, writer in ((table4.FILE_NAME, logs.t4), (table3.FILE_NAME, logs.t3)):
                if writer.last_index is not None:
                    self.rows_at_intact_end[name] = writer.last_index

    def on_signal(self, name: str) -> None:
        """SIGINT/SIGTERM/SIGHUP end the replay (there is no vehicle to land)."""
        raise KeyboardInterrupt(name)

    def scan_wanted(self, seq: int) -> bool:
        """A scan the original flight applied (the others it skipped: its matcher was busy)."""
        return not self._steps or seq in self._steps

    def laser_result_due(self, result: LaserResult, step: int) -> bool:
        """A recorded scan enters at its recorded step; others at once."""
        return step >= self._steps.get(result.seq, 0)


class ReplayApp:
    """The flight daemon on replayed ports: :class:`FlightApp` with a :class:`ReplayPolicy`.

    ``matcher``: the scan matcher (default: :class:`RecordedMatcher` on ``scans``, their
    recorded results if ``use_recorded_poses``); ``on_step`` sees every step's output.
    """

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
        matcher: MatcherWorker | None = None,
        on_step: Callable[[ImuStepOutput], None] | None = None,
    ) -> None:
        self.policy = ReplayPolicy(
            clock=clock,
            feeder=feeder,
            scans=scans,
            ready_ns=ready_ns,
            subscribe_ns=subscribe_ns,
            step_stops=step_stops,
            intact_end_ns=intact_end_ns,
        )
        got = {seq: t for seq, s in scans.items() if (t := s.back_ns) is not None}
        self.recorded = RecordedMatcher(
            cfg, scans if use_recorded_poses else {}, got, now_ns=clock.now_ns
        )
        self.flight = FlightApp(
            cfg,
            opts,
            clock=clock,
            notifier=Notifier(None),
            policy=self.policy,
            worker=matcher or self.recorded,
            on_step=on_step,
        )
        ports = self.flight.ports
        feeder.closed["mk"] = lambda: ports.link is not None and ports.link.closed
        feeder.closed["laser"] = lambda: ports.driver is not None and ports.driver.closed

    async def fly(self) -> FlightReport:
        """Fly the replayed flight (:meth:`FlightApp.fly`)."""
        return await self.flight.fly()

    def request_stop(self, request: StopRequest, reason: str) -> None:
        """Ask the replayed daemon for its soft landing (:meth:`FlightApp.request_stop`)."""
        self.flight.request_stop(request, reason)

    @property
    def rows_at_intact_end(self) -> dict[str, int]:
        """Each table's last row index written by the intact end (a recording cut short)."""
        return self.policy.rows_at_intact_end

    def replay_stats(self) -> dict[str, Any]:
        """How the scans were matched."""
        return {
            "recorded_poses": self.recorded.recorded_used,
            "matched": self.recorded.matched,
            "stamp_differs": self.recorded.stamp_differs,
        }
