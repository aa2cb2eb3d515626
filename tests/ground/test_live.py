"""``fly --live``: a simulated flight watched by plain Foxglove WebSocket clients.

One flight (``fly --hover --sim --live``, flown in the background with its clients:
:mod:`tests.background`) serves two clients at once: one reads every message, the other
subscribes to everything and then never reads (a tiny receive buffer, a one-message
queue). What the first received is checked against the flight folder; the flight itself
against its own summary: the slow client must cost it nothing. The message builders, the
feed and the publisher are tested alone below.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
from websockets.asyncio.client import ClientConnection
from websockets.typing import Subprotocol

from mkflight.config import Config, LiveConfig
from mkflight.control.controller import Setpoint
from mkflight.control.phases import Phase, PhaseEvent
from mkflight.ground import live_messages as msg
from mkflight.ground import topics
from mkflight.ground.frames import MAP_TO_WORLD
from mkflight.ground.live import LiveChannels, LivePublisher, LiveView, start_live_view
from mkflight.ground.live_address import DEFAULT_LIVE, LiveAddress, parse_live_address
from mkflight.ground.live_client import (
    SUBPROTOCOL,
    Message,
    decode_laser_scan,
    decode_pose_in_frame,
    numbers,
    subscribe,
)
from mkflight.ground.live_feed import LiveFeed
from mkflight.logs.events import read_events
from mkflight.logs.schema import PhaseChange, Scan, Step
from mkflight.msgs import Command, Estimate, ImuSample
from mkflight.msgs import Scan as LaserScanRecord
from mkflight.urg.units import step_body_angle_rad
from tests.background import Background, job

pytestmark = pytest.mark.background("live-watched")

MKFLIGHT = [sys.executable, "-m", "mkflight"]
FLIGHT_S = 8.0


def free_port() -> int:
    """A TCP port nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Watched:
    """What the reading client saw, and the flight's folder and output."""

    folder: Path
    returncode: int
    stdout: str
    stderr: str
    channels: dict[str, dict[str, Any]]
    messages: list[Message]

    def on(self, topic: str) -> list[Message]:
        return [m for m in self.messages if m.topic == topic]


async def _connect(port: int, **kwargs: Any) -> ClientConnection:
    """Connect to a server that listens already (``start_live_view`` returned, or ``fly``
    printed its ``live view:`` line)."""
    return await websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(SUBPROTOCOL)], **kwargs
    )


async def _slow_client(port: int) -> ClientConnection:
    """Subscribe to everything, then never read: a 4 KiB receive buffer, a 1-frame queue."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
    ws = await websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(SUBPROTOCOL)], sock=sock, max_queue=1
    )
    await subscribe(ws)
    return ws


async def _listening(stderr: asyncio.StreamReader) -> bytes:
    """The daemon's stderr up to its ``live view: ws://...`` line: the server listens then."""
    seen = b""
    while b"live view: ws://" not in seen:
        line = await stderr.readline()
        assert line, f"fly ended before its live view listened: {seen.decode()}"
        seen += line
    return seen


async def _watch(port: int, folder: Path) -> Watched:
    """Fly with ``--live``; one client reads everything, one never reads."""
    proc = await asyncio.create_subprocess_exec(
        *MKFLIGHT,
        "fly",
        "--hover",
        "--sim",
        "--duration",
        str(FLIGHT_S),
        "--log-dir",
        str(folder),
        "--live",
        f"127.0.0.1:{port}",
        "--json",
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None
    assert proc.stderr is not None
    head = await _listening(proc.stderr)
    outputs = asyncio.gather(proc.stdout.read(), proc.stderr.read(), proc.wait())
    ws = await _connect(port)
    subs = await subscribe(ws)
    slow = await _slow_client(port)
    messages: list[Message] = []
    with contextlib.suppress(websockets.ConnectionClosed):
        async for frame in ws:  # until the server stops at the flight's end
            if isinstance(frame, bytes) and (m := subs.message(frame)) is not None:
                messages.append(m)
    out, tail, _ = await outputs
    err = head + tail
    await slow.close()
    return Watched(
        folder,
        proc.returncode or 0,
        out.decode(),
        err.decode(),
        subs.channels,
        messages,
    )


@job("live-watched")
def _watched(base: Path) -> Watched:
    """The flight and its two clients, in a background worker process's event loop."""
    return asyncio.run(asyncio.wait_for(_watch(free_port(), base / "flight"), timeout=120))


@pytest.fixture(scope="module")
def watched(background: Background) -> Watched:
    result: Watched = background.result("live-watched")
    return result


def _events(folder: Path) -> list[Any]:
    return list(read_events(folder / "events.jsonl").events)


def _hold_ns(folder: Path) -> tuple[int, int]:
    """HOLD's start and end on the flight clock."""
    changes = [e for e in _events(folder) if isinstance(e, PhaseChange)]
    i = next(i for i, e in enumerate(changes) if e.to == "HOLD")
    return changes[i].t_ns, changes[i + 1].t_ns


def _steps(folder: Path) -> dict[int, Step]:
    return {e.t_ns: e for e in _events(folder) if isinstance(e, Step)}


def _pose(payload: bytes) -> tuple[str, tuple[float, ...], tuple[float, ...]]:
    """A ``foxglove.PoseInFrame``: frame id, position, orientation (x, y, z, w)."""
    p = decode_pose_in_frame(payload)
    return p.frame_id, p.position, p.orientation


# ----- the flight with two clients ---------------------------------------------------------


def test_the_flight_with_a_never_reading_client_is_a_normal_flight(watched: Watched) -> None:
    assert watched.returncode == 0, watched.stderr
    assert "live view: ws://127.0.0.1:" in watched.stderr
    summary = json.loads(watched.stdout)
    assert summary["failsafes"] == ["LAND:stop_duration"] or all(
        "stop_" in f for f in summary["failsafes"]
    ), summary["failsafes"]
    t = summary["timing"]
    assert t["missed_steps"] == 0
    assert t["latency_p99_ms"] < 10.0  # a blocked step would be 50 ms and more


def test_every_topic_is_advertised_with_its_schema(watched: Watched) -> None:
    ch = watched.channels
    assert ch[topics.SCAN]["schemaName"] == "foxglove.LaserScan"
    assert ch[topics.POSE]["schemaName"] == "foxglove.PoseInFrame"
    assert ch[topics.SETPOINT]["schemaName"] == "foxglove.PoseInFrame"
    assert ch[topics.TF]["schemaName"] == "foxglove.FrameTransforms"
    for topic in msg.SCHEMAS:
        assert ch[topic]["encoding"] == "json"
        assert json.loads(ch[topic]["schema"]) == msg.SCHEMAS[topic]


def test_scans_and_poses_arrive_during_hold_at_their_rates(watched: Watched) -> None:
    start, end = _hold_ns(watched.folder)
    hold_s = (end - start) / 1e9
    assert hold_s > 2.0
    in_hold = [m for m in watched.messages if start <= m.log_time_ns < end]
    scans = [m for m in in_hold if m.topic == topics.SCAN]
    poses = [m for m in in_hold if m.topic == topics.POSE]
    steps = [t for t in _steps(watched.folder) if start <= t < end]
    assert len(poses) >= 0.95 * len(steps)  # every step's pose, but a late wake-up's
    assert len(scans) >= 0.8 * hold_s * 10  # the URG's 10 Hz


def test_the_pose_is_the_flights_estimate_in_w_and_near_the_setpoint(watched: Watched) -> None:
    steps = _steps(watched.folder)
    start, end = _hold_ns(watched.folder)
    poses = watched.on(topics.POSE)
    assert poses
    for m in poses:
        frame, (x, y, z), q = _pose(m.payload)
        step = steps[m.log_time_ns]  # each pose carries its DebugOut's time
        assert frame == topics.WORLD_FRAME
        assert x == pytest.approx(step.x_m, abs=1e-4)  # the event rounds to 0.1 mm
        assert y == pytest.approx(step.y_m, abs=1e-4)
        assert -z == pytest.approx(step.height_m, abs=1e-4)  # W is z down
        assert math.fsum(c * c for c in q) == pytest.approx(1.0)
    for m in watched.on(topics.SETPOINT):
        frame, (x, y, z), _ = _pose(m.payload)
        step = steps[m.log_time_ns]
        assert (x, y, -z) == pytest.approx((step.sp_x_m, step.sp_y_m, step.sp_height_m), abs=1e-4)
        if start <= m.log_time_ns < end:  # hovering: within a few cm of the set-point
            _, (px, py, pz), _ = _pose(
                next(p for p in poses if p.log_time_ns == m.log_time_ns).payload
            )
            assert math.hypot(px - x, py - y) < 0.1
            assert abs(pz - z) < 0.1


def test_a_scan_is_the_wall_beams_in_the_vehicle_frame(watched: Watched) -> None:
    cfg = Config()
    first, last = cfg.laser.scan_steps
    scan_times = {e.t_ns for e in _events(watched.folder) if isinstance(e, Scan)}
    scans = watched.on(topics.SCAN)
    assert scans
    for m in scans:
        s = decode_laser_scan(m.payload)
        assert s.frame_id == topics.VEHICLE_FRAME
        assert len(s.ranges) == last - first + 1
        assert s.start_angle == pytest.approx(step_body_angle_rad(last))
        assert s.end_angle == pytest.approx(step_body_angle_rad(first))
        assert s.stamp_ns == m.log_time_ns
        finite = [r for r in s.ranges if math.isfinite(r)]
        assert len(finite) > len(s.ranges) // 2
        assert cfg.laser.min_range_m <= min(finite)
        assert max(finite) <= cfg.laser.max_range_m
    matched = [m for m in scans if m.log_time_ns in scan_times]
    assert len(matched) >= len(scans) - 2  # each is a scan the matcher had (the last may not be)


def test_the_json_topics_are_the_flights_values(watched: Watched) -> None:
    steps = _steps(watched.folder)
    heights = watched.on(topics.HEIGHT)
    assert heights
    for m in heights:
        step, value = steps[m.log_time_ns], m.json()
        assert value["height_m"] == pytest.approx(step.height_m, abs=1e-4)
        assert value["vz_up_mps"] == pytest.approx(step.vz_up_mps, abs=1e-4)
    for m in watched.on(topics.BATTERY):
        assert m.json()["battery_v"] == pytest.approx(steps[m.log_time_ns].battery_v)
    for m in watched.on(topics.COMMAND):
        assert m.json()["gas_counts"] == steps[m.log_time_ns].gas_counts
    for m in watched.on(topics.PHASE):
        if not m.json()["change"]:
            assert m.json()["phase"] == steps[m.log_time_ns].phase
    seen = min(m.log_time_ns for m in watched.messages)
    changes = [
        (e.t_ns, e.to, e.reason)
        for e in _events(watched.folder)
        if isinstance(e, PhaseChange) and e.t_ns >= seen and e.to != "RELEASED"
    ]
    told = [
        (m.log_time_ns, m.json()["phase"], m.json()["reason"])
        for m in watched.on(topics.PHASE)
        if m.json()["change"]
    ]
    assert changes
    assert told[: len(changes)] == changes  # every phase change, with its reason
    failsafes = [m.json() for m in watched.on(topics.FAILSAFE)]
    assert {"action": "LAND", "cause": "stop_duration"}.items() <= failsafes[0].items()


# ----- usage and start-up errors -----------------------------------------------------------


@pytest.mark.parametrize("value", ["nope", "host:", ":8765", "127.0.0.1:65536", "::1:8765"])
def test_a_bad_live_value_is_a_usage_error(value: str, tmp_path: Path) -> None:
    proc = subprocess.run(
        [*MKFLIGHT, "fly", "--hover", "--sim", "--log-dir", str(tmp_path / "f"), "--live", value],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: argument --live: ")
    assert proc.stderr.count("\n") == 1
    assert not (tmp_path / "f").exists()


def test_a_port_in_use_is_one_clear_error_before_anything_flies(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = subprocess.run(
            [
                *MKFLIGHT,
                "fly",
                "--hover",
                "--sim",
                "--log-dir",
                str(tmp_path / "f"),
                "--live",
                f"127.0.0.1:{port}",
            ],
            capture_output=True,
            text=True,
            check=False,
            timeout=60,
        )
    assert proc.returncode == 2
    config_line, error_line = proc.stderr.splitlines()  # the config: line, then one error
    assert config_line == "config: built-in defaults"
    assert error_line.startswith(f"error: --live 127.0.0.1:{port}: cannot listen: ")
    assert "in use" in error_line
    assert not (tmp_path / "f").exists()  # the simulator never started


def test_without_the_foxglove_sdk_live_is_one_clear_error(tmp_path: Path) -> None:
    code = (
        "import sys; sys.modules['foxglove'] = None; from mkflight.cli import main; "
        f"sys.exit(main(['fly', '--hover', '--sim', '--log-dir', {str(tmp_path / 'f')!r}, "
        "'--live']))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=60
    )
    assert proc.returncode == 2
    assert proc.stderr == (
        "config: built-in defaults\n"
        "error: --live needs the Foxglove SDK (foxglove): pip install 'mkflight[live]'\n"
    )


def test_a_flight_without_live_never_imports_the_sdk() -> None:
    code = (
        "import sys; import mkflight.flight.app, mkflight.commands.fly, mkflight.ground.live_feed;"
        " print(sorted(m for m in sys.modules if m.split('.')[0] in ('foxglove', 'websockets')))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"


def test_parse_live_address() -> None:
    assert parse_live_address("8765") == LiveAddress("127.0.0.1", 8765)
    assert parse_live_address("0.0.0.0:9000") == LiveAddress("0.0.0.0", 9000)
    assert parse_live_address("[::1]:0") == LiveAddress("::1", 0)
    assert parse_live_address("[::1]:8765").url() == "ws://[::1]:8765"
    assert DEFAULT_LIVE.url() == "ws://127.0.0.1:8765"


# ----- the messages, alone -----------------------------------------------------------------


def _rotate(q: tuple[float, ...], v: tuple[float, float, float]) -> Any:
    x, y, z, w = q
    u = np.array([x, y, z])
    vv = np.array(v)
    return vv + 2 * w * np.cross(u, vv) + 2 * np.cross(u, np.cross(u, vv))


def _q(q: Any) -> tuple[float, ...]:
    return numbers(q.encode(), 4)


def test_a_clockwise_yaw_turns_the_nose_to_the_right_in_frd() -> None:
    q = _q(msg.quaternion(math.pi / 2))
    assert q == pytest.approx((0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)))
    assert _rotate(q, (1, 0, 0)) == pytest.approx([0, 1, 0], abs=1e-12)  # y is right
    up = _rotate(_q(msg.quaternion(0.0, 0.2, 0.0)), (1, 0, 0))  # pitch: nose up = -z
    assert up == pytest.approx([math.cos(0.2), 0, -math.sin(0.2)])
    right_down = _rotate(_q(msg.quaternion(0.0, 0.0, 0.3)), (0, 1, 0))  # roll: right side down
    assert right_down == pytest.approx([0, math.cos(0.3), math.sin(0.3)])
    assert _q(msg.quaternion(math.nan, math.nan, math.nan)) == pytest.approx((0, 0, 0, 1))
    # map -> world: a half turn about x makes W's down map's up, W's right map's left
    assert _rotate(MAP_TO_WORLD, (0, 0, 1)) == pytest.approx([0, 0, -1])
    assert _rotate(MAP_TO_WORLD, (0, 1, 0)) == pytest.approx([0, -1, 0])


def test_scan_message_keeps_the_scan_steps_in_rising_bearing() -> None:
    ranges = np.arange(44, 726, dtype=np.float64) / 100  # step s reads s / 100 m
    ranges[400 - 44] = np.nan
    scan = LaserScanRecord(t_ns=12_345_678_901, ranges_m=ranges, first_step=44, seq=3)
    s = decode_laser_scan(msg.scan_message(scan, (150, 725)).encode())  # type: ignore[union-attr]
    assert len(s.ranges) == 576
    assert s.ranges[0] == 7.25
    assert s.ranges[-1] == 1.50
    assert math.isnan(s.ranges[725 - 400])
    assert s.start_angle == pytest.approx(step_body_angle_rad(725))  # left: negative
    assert s.start_angle < 0 < s.end_angle
    assert s.stamp_ns == 12_345_678_901
    assert s.frame_id == "vehicle"
    short = LaserScanRecord(t_ns=1, ranges_m=ranges[:50], first_step=44)
    assert msg.scan_message(short, (150, 725)) is None


def test_json_payloads_have_no_nan_and_fit_their_schemas() -> None:
    est = Estimate(1, 0.1, -0.2, 0.3, math.nan, 0.01, 0.02, math.inf, height_valid=False)
    assert msg.height_json(est) == {"height_m": None, "vz_up_mps": None, "valid": False}
    assert msg.velocity_json(est)["vx_mps"] == 0.01
    cmd = Command(1, -3, 4, 0, 101)
    assert msg.command_json(cmd)["gas_counts"] == 101
    sample = ImuSample(1, 0.01, -0.02, 1.0, 0, 0, -9.81, 12.3)
    assert msg.attitude_json(sample) == {"pitch_rad": 0.01, "roll_rad": -0.02, "yaw_rad": 1.0}
    assert msg.battery_json(sample) == {"battery_v": 12.3}
    change = PhaseEvent(5, Phase.TAKEOFF, Phase.HOLD, "at height")
    assert msg.phase_change_json(change) == {"phase": "HOLD", "change": True, "reason": "at height"}
    for topic, payload in (
        (topics.HEIGHT, msg.height_json(est)),
        (topics.COMMAND, msg.command_json(cmd)),
        (topics.PHASE, msg.phase_json("HOLD")),
    ):
        json.dumps(payload, allow_nan=False)
        assert set(payload) == set(msg.SCHEMAS[topic]["properties"])


# ----- the feed and the publisher, alone ---------------------------------------------------


class FakeChannel:
    """Records what is logged; ``fail`` makes ``log`` raise."""

    def __init__(self, fail: bool = False) -> None:
        self.logged: list[tuple[int | None, Any]] = []
        self.fail = fail

    def has_sinks(self) -> bool:
        return True

    def log(self, message: Any, *, log_time: int | None = None) -> None:
        if self.fail:
            raise RuntimeError("the client went away badly")
        self.logged.append((log_time, message))


def _fake_channels(fail: bool = False) -> LiveChannels:
    ch = LiveChannels.__new__(LiveChannels)
    for name in [
        "scan",
        "pose",
        "setpoint",
        "tf",
        "height",
        "attitude",
        "velocity",
        "command",
        "battery",
        "phase",
        "failsafe",
    ]:
        setattr(ch, name, FakeChannel(fail))
    return ch


def _step(feed: LiveFeed, t_ns: int, events: tuple[PhaseEvent, ...] = ()) -> None:
    """Tell ``feed`` of a step at ``t_ns`` (a HOLD step with a command)."""
    from types import SimpleNamespace

    out = SimpleNamespace(
        estimate=Estimate(t_ns, 0.1, 0.2, 0.0, 0.5, 0.0, 0.0, 0.0),
        command=Command(t_ns, 0, 0, 0, 100),
        phase=Phase.HOLD,
        phase_events=events,
        failsafe_events=(),
    )
    sample = ImuSample(t_ns, 0.0, 0.0, 0.0, 0, 0, -9.81, 12.0)
    feed.on_step(sample, out, Setpoint(0.0, 0.0, 0.0, 0.6))  # type: ignore[arg-type]


async def test_the_publisher_publishes_the_newest_at_the_configured_rates() -> None:
    feed, ch = LiveFeed(), _fake_channels()
    pub = LivePublisher(feed, ch, LiveConfig(state_rate_hz=10, scan_rate_hz=5), (150, 725))
    ranges = np.full(682, 2.0)
    change = PhaseEvent(0, Phase.TAKEOFF, Phase.HOLD, "at height")
    for k in range(20):  # 1 s of 50 ms steps; a scan every 100 ms
        t = k * 50_000_000
        if k % 2 == 0:
            feed.on_scan(LaserScanRecord(t_ns=t, ranges_m=ranges, first_step=44, seq=k))
        _step(feed, t, (change,) if k == 0 else ())
        await pub.publish_newest()
    assert [t for t, _ in ch.pose.logged] == [k * 100_000_000 for k in range(10)]  # type: ignore[attr-defined]
    assert len(ch.scan.logged) == 5  # type: ignore[attr-defined]
    changes = [m for _, m in ch.phase.logged if m["change"]]  # type: ignore[attr-defined]
    assert changes == [{"phase": "HOLD", "change": True, "reason": "at height"}]


async def test_at_their_own_rate_every_value_is_published_however_it_jitters() -> None:
    feed, ch = LiveFeed(), _fake_channels()
    pub = LivePublisher(feed, ch, LiveConfig(), (150, 725))
    times = [t * 1_000_000 for t in (0, 61, 100, 138, 200, 237)]  # DebugOut jitter
    for t in times:
        _step(feed, t)
        await pub.publish_newest()
        await pub.publish_newest()  # a second wake-up with nothing new publishes nothing
    assert [t for t, _ in ch.pose.logged] == times  # type: ignore[attr-defined]


async def test_a_publisher_that_fell_behind_publishes_only_the_newest_and_every_event() -> None:
    feed, ch = LiveFeed(), _fake_channels()
    pub = LivePublisher(feed, ch, LiveConfig(), (150, 725))
    for k in range(5):  # five steps before the publisher runs once
        _step(feed, k * 50_000_000, (PhaseEvent(k, Phase.TAKEOFF, Phase.HOLD, str(k)),))
    await pub.publish_newest()
    assert [t for t, _ in ch.pose.logged] == [4 * 50_000_000]  # type: ignore[attr-defined]
    assert [m["reason"] for _, m in ch.phase.logged if m["change"]] == list("01234")  # type: ignore[attr-defined]


async def test_a_publishing_fault_stops_the_view_never_the_flight(
    caplog: pytest.LogCaptureFixture,
) -> None:
    feed = LiveFeed()
    pub = LivePublisher(feed, _fake_channels(fail=True), LiveConfig(), (150, 725))
    view = LiveView(None, None, pub, DEFAULT_LIVE)

    async def flight() -> str:
        for k in range(10):  # the steps go on after the view failed
            _step(feed, k * 50_000_000)
            await asyncio.sleep(0)  # one loop turn: the publisher runs between steps
        return "landed"

    assert await view.during(flight()) == "landed"
    assert isinstance(pub.error, RuntimeError)
    assert not feed.on
    assert feed.sample is None
    _step(feed, 10**9)
    assert feed.sample is None
    assert not feed.wake.is_set()


def test_the_feed_keeps_references_and_queues_only_eventful_steps() -> None:
    feed = LiveFeed()
    _step(feed, 1)
    assert feed.steps == 1
    assert feed.wake.is_set()
    assert not feed.events
    _step(feed, 2, (PhaseEvent(2, Phase.TAKEOFF, Phase.HOLD, ""),))
    assert len(feed.events) == 1
    assert feed.sample is not None
    assert feed.sample.t_ns == 2


async def test_the_server_listens_on_loopback_and_says_which_port() -> None:
    view = start_live_view(Config(), LiveAddress("127.0.0.1", 0))
    try:
        assert view.address.port > 0
        ws = await _connect(view.address.port)
        subs = await subscribe(ws, [topics.SCAN, topics.POSE])
        assert set(subs.topic_of.values()) == {topics.SCAN, topics.POSE}
        await ws.close()
    finally:
        view.close()


# ----- a publishing fault in a real flight -------------------------------------------------


class FailsInHold(FakeChannel):
    """Logs until the flight has been in HOLD for a while, then raises."""

    def __init__(self, feed: LiveFeed) -> None:
        super().__init__()
        self.feed = feed
        self.hold_logs = 0

    def log(self, message: Any, *, log_time: int | None = None) -> None:
        out = self.feed.out
        if out is not None and out.phase is Phase.HOLD:
            self.hold_logs += 1
            if self.hold_logs > 20:
                raise RuntimeError("injected fault in the live view")
        super().log(message, log_time=log_time)


@pytest.mark.realtime  # in this process: once the background flights have ended
async def test_a_view_that_fails_in_hold_leaves_the_flight_as_it_was(tmp_path: Path) -> None:
    from mkflight.flight.app import FlightApp, FlightOptions
    from mkflight.sim.live import LiveSim

    cfg = Config()
    folder = tmp_path / "flight"
    folder.mkdir()
    feed = LiveFeed()
    ch = _fake_channels()
    ch.pose = pose = FailsInHold(feed)
    publisher = LivePublisher(feed, ch, cfg.live, cfg.laser.scan_steps)
    view = LiveView(None, None, publisher, DEFAULT_LIVE)
    sim = LiveSim(cfg, seed=3)
    mk, laser = await sim.start()
    try:
        app = FlightApp(
            cfg,
            FlightOptions(mk_port=mk, laser_port=laser, log_dir=folder, duration_s=8.0),
            observer=feed,
        )
        report = await view.during(app.fly())
    finally:
        await sim.stop()
    assert isinstance(publisher.error, RuntimeError)  # the view failed in HOLD ...
    assert not feed.on
    assert report.exit_code == 0, report.reason  # ... and the flight flew on and landed
    assert report.reason == "--duration 8 s"
    assert report.summary.final_phase == "RELEASED"
    events = _events(folder)
    fault_t = max(t for t, _ in pose.logged if t is not None)
    steps_after = [e for e in events if isinstance(e, Step) and e.t_ns > fault_t]
    assert len(steps_after) > 40  # two seconds and more of steps after the fault
    assert [e.to for e in events if isinstance(e, PhaseChange)][-1] == "RELEASED"
