"""The pure URG-04LX model on a manual clock (``protocols/scip2.md`` §3-7)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mkflight.sim.room import box_room, room_caster
from mkflight.sim.urg import UrgModel
from mkflight.sim.urg_scene import FixedRanges, HatGeometry, RoomScene, ScenePose
from mkflight.urg.codec import gd_command, md_command, scip2_command, simple_command, tm_command
from mkflight.urg.replies import InfoReply, Reply, ReplyParser, ScanReply
from mkflight.urg.units import URG_04LX, ranges_m
from tests.urg.vectors import ALL_VECTORS, EXCHANGES, ExchangeVector

MS = 1_000_000
T0 = 1_000_000_000_000  # any start time: the model only uses differences
WRAP = 1 << 24


def model_for(vector: ExchangeVector) -> UrgModel:
    return UrgModel(
        FixedRanges(vector.ranges),
        t_ns=T0,
        timer_ms=vector.timer_ms,
        scip1=vector.scip1,
        laser_on=vector.laser_on,
    )


def run(model: UrgModel, until_ns: int) -> list[tuple[int, bytes]]:
    """Step the model event by event up to ``until_ns``: (delivery time, chunk)."""
    out: list[tuple[int, bytes]] = []
    while (t := model.next_event_ns()) is not None and t <= until_ns:
        out += [(t, chunk) for chunk in model.poll(t)]
    out += [(until_ns, chunk) for chunk in model.poll(until_ns)]
    return out


def parse(chunks: list[tuple[int, bytes]]) -> list[Reply]:
    parser = ReplyParser()
    return [r for _, chunk in chunks for r in parser.feed(chunk)]


def exchange(model: UrgModel, command: bytes, t_ns: int, wait_ns: int = 0) -> list[Reply]:
    model.receive(command, t_ns)
    return parse(run(model, t_ns + wait_ns))


@pytest.mark.parametrize("vector", EXCHANGES, ids=lambda v: v.id)
def test_every_exchange_is_byte_identical(vector: ExchangeVector) -> None:
    model = model_for(vector)
    t = T0 + vector.at_ms * MS
    model.receive(vector.command, t)
    assert b"".join(model.poll(t + vector.wait_ms * MS)) == vector.reply


def test_corrupted_reply_is_dropped_by_the_client() -> None:
    vector = ALL_VECTORS["SC-11"]
    assert isinstance(vector, ExchangeVector)
    model = model_for(vector)
    model.corrupt_next(1)
    model.receive(vector.command, T0)
    parser = ReplyParser()
    assert parser.feed(b"".join(model.poll(T0 + 100 * MS))) == []
    assert parser.stats.sum_errors == 1
    assert model.tx_corrupted == 1


def test_gd_reply_leaves_when_the_end_step_is_measured() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, laser_on=True)
    model.receive(gd_command(44, 725), T0 + 30 * MS)  # mid-scan: served from the next one
    ready = T0 + 100 * MS + URG_04LX.step_offset_ns(725)
    assert model.next_event_ns() == ready
    assert model.poll(ready - 1) == []
    (reply,) = parse([(ready, c) for c in model.poll(ready)])
    assert isinstance(reply, ScanReply)
    assert reply.timestamp_ms == 100
    assert reply.values == (1000,) * 682
    assert model.next_event_ns() is None


def test_md_stream_every_100_ms_with_increasing_timestamps() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, timer_ms=5000, scip1=False)
    model.receive(md_command(44, 725), T0 + 10 * MS)
    chunks = run(model, T0 + 1080 * MS)
    ack, *scans = parse(chunks)
    assert ack == Reply("MD0044072501000", "00")
    assert len(scans) == 10
    stamps = [s.timestamp_ms for s in scans if isinstance(s, ScanReply)]
    assert stamps == [5100 + 100 * k for k in range(10)]
    arrivals = [t for t, _ in chunks[1:]]
    assert [b - a for a, b in itertools.pairwise(arrivals)] == [100 * MS] * 9
    assert arrivals[0] - (T0 + 100 * MS) == URG_04LX.step_offset_ns(725)  # ~70.8 ms
    assert all(s.remaining == 0 for s in scans if isinstance(s, ScanReply))
    assert model.laser_on
    assert model.streaming


def test_md_count_counts_down_and_switches_the_laser_off() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    replies = exchange(model, md_command(44, 725, 1, 1, 3), T0, 2000 * MS)
    scans = [r for r in replies if isinstance(r, ScanReply)]
    assert [s.remaining for s in scans] == [2, 1, 0]
    assert [s.timestamp_ms for s in scans] == [0, 200, 400]  # interval 1: every 2nd scan
    assert not model.laser_on
    assert not model.streaming


def test_timer_wraps_after_24_bits() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, timer_ms=WRAP - 150, scip1=False)
    replies = exchange(model, md_command(384, 386, 1, 0, 4), T0, 500 * MS)
    stamps = [r.timestamp_ms for r in replies if isinstance(r, ScanReply)]
    assert stamps == [WRAP - 150, WRAP - 50, 50, 150]


def test_rs_resets_the_timer_and_stops_everything() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, timer_ms=123456, scip1=False)
    exchange(model, md_command(44, 725), T0, 150 * MS)
    assert exchange(model, simple_command("RS"), T0 + 250 * MS)[-1] == Reply("RS", "00")
    assert not model.streaming
    assert not model.laser_on
    assert run(model, T0 + 1000 * MS) == []
    (info,) = exchange(model, simple_command("II"), T0 + 1300 * MS)
    assert isinstance(info, InfoReply)
    assert info.info["TIME"] == f"{1050:06X}"
    assert info.info["LASR"] == "OFF"
    replies = exchange(model, md_command(44, 725, 1, 0, 1), T0 + 1300 * MS, 200 * MS)
    assert [r.timestamp_ms for r in replies if isinstance(r, ScanReply)] == [1050]


def test_qt_stops_a_stream() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    exchange(model, md_command(44, 725), T0, 250 * MS)
    assert exchange(model, simple_command("QT"), T0 + 260 * MS) == [Reply("QT", "00")]
    assert not model.laser_on
    assert model.next_event_ns() is None
    assert run(model, T0 + 2000 * MS) == []


def test_scans_sent_before_qt_arrive_ahead_of_its_answer() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, delivery_delay_ns=30 * MS)
    model.receive(md_command(44, 725), T0)
    model.receive(simple_command("QT"), T0 + 80 * MS)  # scan 0 left at 70.8 ms
    replies = parse(run(model, T0 + 500 * MS))
    assert [r.status for r in replies] == ["00", "99", "00"]
    assert replies[-1].echo == "QT"


def test_new_md_replaces_the_running_stream() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    exchange(model, md_command(44, 725, tag="a"), T0, 150 * MS)
    replies = exchange(model, md_command(44, 725, tag="b"), T0 + 150 * MS, 500 * MS)
    assert {r.tag for r in replies} == {"b"}


def test_cluster_partial_group_and_all_error_group() -> None:
    ranges = {380: 7, 381: 3, 382: 19, 383: 500, 384: 400}
    model = UrgModel(FixedRanges(ranges), t_ns=T0, scip1=False, laser_on=True)
    (reply,) = exchange(model, gd_command(380, 384, 3), T0, 100 * MS)
    assert isinstance(reply, ScanReply)
    assert reply.values == (3, 400)  # all codes -> the smallest; partial group kept


def test_dead_zone_steps_read_19() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, laser_on=True)
    (reply,) = exchange(model, gd_command(40, 46), T0, 100 * MS)
    assert isinstance(reply, ScanReply)
    assert reply.values == (19, 19, 19, 19, 1000, 1000, 1000)


@pytest.mark.parametrize(
    ("command", "status"),
    [
        (b"GD00440725\n", "0C"),
        (b"GD004407250100\n", "0D"),
        (b"GDx044072501\n", "01"),
        (b"GD0044x72501\n", "02"),
        (b"GD004407250x\n", "03"),
        (b"MD0044072501x00\n", "06"),
        (b"MD0044072501000;" + b"x" * 17 + b"\n", "0G"),
        (b"MD0044072501000;a/b\n", "0H"),
        (b"VVV\n", "0E"),
        (b"TM2\n", "03"),
        (b"TM1\n", "04"),
        (b"TM9\n", "01"),
    ],
)
def test_error_statuses(command: bytes, status: str) -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, laser_on=True)
    (reply,) = exchange(model, command, T0)
    assert reply.status == status
    assert reply.answers(command)


def test_second_gd_while_one_is_pending_is_refused() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, laser_on=True)
    model.receive(gd_command(44, 725), T0 + MS)
    assert exchange(model, gd_command(44, 725), T0 + 2 * MS) == [Reply("GD0044072501", "0B")]
    assert [r.status for r in parse(run(model, T0 + 200 * MS))] == ["00"]


def test_time_adjust_mode_refuses_other_commands_until_tm2() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, timer_ms=77, scip1=False)
    assert exchange(model, tm_command(0), T0)[0].status == "00"
    assert exchange(model, simple_command("QT"), T0)[0].status == "0E"
    (time_reply,) = exchange(model, tm_command(1), T0 + 5 * MS)
    assert getattr(time_reply, "timestamp_ms", None) == 82
    assert exchange(model, tm_command(2), T0)[0].status == "00"
    assert exchange(model, simple_command("QT"), T0)[0].status == "00"


def test_scip1_sensor_refuses_until_switched() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=True)
    model.receive(simple_command("VV"), T0)
    assert model.poll(T0) == [b"VV\nE\n\n"]
    assert exchange(model, scip2_command(), T0) == [Reply("SCIP2.0", "0")]
    assert exchange(model, scip2_command(), T0) == [Reply("SCIP2.0", "0E")]


def test_cr_and_crlf_terminators_and_split_commands() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    model.receive(b"B", T0)
    model.receive(b"M\r\nQT\r", T0)
    assert parse(run(model, T0)) == [Reply("BM", "00"), Reply("QT", "00")]


def test_delivery_delay_keeps_order() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False, delivery_delay_ns=30 * MS)
    model.receive(simple_command("BM"), T0)
    assert model.poll(T0 + 29 * MS) == []
    assert model.next_event_ns() == T0 + 30 * MS
    assert model.poll(T0 + 30 * MS) == [b"BM\n00P\n\n"]


def test_stall_loses_scans_and_the_stream_resumes() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    exchange(model, md_command(44, 725), T0)
    model.stall(T0 + 450 * MS)
    replies = parse(run(model, T0 + 1000 * MS))
    stamps = [r.timestamp_ms for r in replies if isinstance(r, ScanReply)]
    assert stamps == [400, 500, 600, 700, 800, 900]
    assert model.scans_stalled == 4  # scans 0-3 left before 450 ms


def test_garbage_goes_out_before_the_next_reply() -> None:
    model = UrgModel(FixedRanges(), t_ns=T0, scip1=False)
    model.inject_garbage(b"\x00junk\n")
    model.receive(simple_command("BM"), T0)
    parser = ReplyParser()
    assert parser.feed(b"".join(model.poll(T0))) == [Reply("BM", "00")]
    assert parser.stats.garbage_lines == 1


# --- the room scene ------------------------------------------------------------------------


def scene_scan(scene: RoomScene, steps: range) -> list[float]:
    return ranges_m(scene.ranges_mm(0, np.arange(steps.start, steps.stop)).tolist())


def test_scene_in_a_box_room_with_yaw_and_position() -> None:
    # 8 m along x, 4 m along the room's y (left); the vehicle faces +x.
    scene = RoomScene(room_caster(box_room(8, 4)), noise_m=0.0, error_fraction=0.0)
    front, left = 384, 640  # body angle 0 and -90 deg (to the left)
    assert scene_scan(scene, range(front, front + 1)) == [4.0]
    assert scene_scan(scene, range(left, left + 1)) == pytest.approx([2.0], abs=0.002)
    scene.pose = ScenePose(x_m=1.0, y_m=1.0)  # 1 m forward, 1 m to the right
    assert scene_scan(scene, range(front, front + 1)) == [3.0]
    assert scene_scan(scene, range(left, left + 1)) == pytest.approx([3.0], abs=0.002)
    scene.pose = ScenePose(yaw_rad=np.pi / 2)  # nose to the right (clockwise)
    assert scene_scan(scene, range(front, front + 1)) == pytest.approx([2.0], abs=0.001)
    assert scene_scan(scene, range(left, left + 1)) == pytest.approx([4.0], abs=0.003)


def test_scene_hat_edge_and_noise() -> None:
    pose = ScenePose(height_m=0.6, roll_rad=0.1, pitch_rad=-0.2)
    scene = RoomScene(room_caster(box_room(8, 4)), pose=pose, seed=3)
    raw = scene.ranges_mm(0, np.arange(44, 726))
    hat = raw[: 127 - 44 + 1] / 1000.0
    expected = (0.6 + 0.05) / (np.cos(0.1) * np.cos(0.2))
    assert abs(float(np.mean(hat)) - expected) < 0.004
    assert 0.005 < float(np.std(hat)) < 0.015
    edge = raw[128 - 44 : 150 - 44]
    assert all(v == 0 or 30 <= v <= 80 for v in edge)
    again = RoomScene(room_caster(box_room(8, 4)), pose=pose, seed=3)
    assert np.array_equal(again.ranges_mm(0, np.arange(44, 726)), raw)


def test_scene_tilt_stretches_wall_ranges_and_far_walls_read_0() -> None:
    level = RoomScene(room_caster(box_room(20, 4)), noise_m=0.0, error_fraction=0.0)
    assert level.ranges_mm(0, np.array([384]))[0] == 0  # 10 m > DMAX
    pitched = RoomScene(
        room_caster(box_room(20, 4)),
        pose=ScenePose(height_m=1.0, pitch_rad=0.1),
        noise_m=0.0,
        error_fraction=0.0,
    )
    left = pitched.ranges_mm(0, np.array([640]))[0] / 1000.0
    assert left == pytest.approx(2.0, abs=0.002)  # a side beam is not tilted by pitch
    rolled = RoomScene(
        room_caster(box_room(20, 4)),
        pose=ScenePose(height_m=1.0, roll_rad=-0.1),  # left side down
        noise_m=0.0,
        error_fraction=0.0,
    )
    left = rolled.ranges_mm(0, np.array([640]))[0] / 1000.0
    assert left == pytest.approx(2.0 / np.cos(0.1), abs=0.002)


def test_scene_errors_and_motion_during_the_sweep() -> None:
    hat = HatGeometry(hat_steps=(44, 60), mirror_edge_last_step=60, hat_offset_m=0.05)
    scene = RoomScene(room_caster(box_room(8, 8)), hat=hat, error_fraction=0.05, seed=1)
    raw = scene.ranges_mm(0, np.arange(61, 726))
    codes = raw[(raw > 0) & (raw < 20)]
    assert 10 < codes.size < 70
    assert set(codes.tolist()) <= {1, 2, 7}
    moving = RoomScene(
        room_caster(box_room(8, 8)),
        pose=lambda t_ns: ScenePose(x_m=t_ns / 1e8),  # 1 m per 100 ms, forward
        noise_m=0.0,
        error_fraction=0.0,
    )
    back, front = moving.ranges_mm(0, np.array([150, 384, 384 + 300]))[[0, 1]]
    assert front / 1000.0 < 4.0  # the front step is measured 37.5 ms in: 0.375 m closer
    assert back > 0
