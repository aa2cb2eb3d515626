"""The pure FlightCtrl model, stepped by hand (mk-serial.md §3-9); no event loop, no port."""

from __future__ import annotations

import itertools
import statistics

import pytest

from mkflight.config import SimFcConfig
from mkflight.errors import ConfigError
from mkflight.mk.codec import FrameParser, encode_frame
from mkflight.mk.messages import Confirm, DebugOut, Ppm, debug_request
from mkflight.sim.fc import TICK_NS, FcModel
from mkflight.sim.fc_answers import parse_version
from mkflight.sim.fc_control import FcCommand
from mkflight.sim.fc_uart import wire_ns
from tests.sim.fc_helpers import (
    D_WIRE_NS,
    MK04_WIRE_NS,
    MK07_VALUES,
    MK08_VALUES,
    MK16_CHANNELS,
    MK_01,
    MK_02,
    MK_03,
    MK_04,
    MK_05,
    MK_07,
    MK_08,
    MK_09,
    MK_11,
    MK_13,
    MK_14,
    MK_15,
    MK_16,
    MK_17,
    MK_18,
    MK_19,
    MS,
    T0,
    S,
    extern,
    frames,
    make,
    run,
    times_of,
)


def test_vector_literals_match_the_encoders() -> None:
    assert DebugOut.from_values(MK07_VALUES).encode() == MK_07
    assert DebugOut.from_values(MK08_VALUES).encode() == MK_08
    assert Ppm.from_channels(MK16_CHANNELS).encode() == MK_16
    assert Confirm(7).encode() == MK_13


@pytest.mark.parametrize(
    ("request_frame", "reply", "values", "channels"),
    [
        pytest.param(MK_01, MK_03, {}, {}, id="MK-01->MK-03"),
        pytest.param(MK_02, MK_03, {}, {}, id="MK-02->MK-03"),
        pytest.param(MK_04, MK_07, MK07_VALUES, {}, id="MK-04->MK-07"),
        pytest.param(MK_04, MK_08, MK08_VALUES, {}, id="MK-04->MK-08"),
        pytest.param(MK_09, MK_13, {}, {}, id="MK-09->MK-13"),
        pytest.param(MK_11, MK_14, {}, {}, id="MK-11->MK-14"),
        pytest.param(MK_15, MK_16, {}, MK16_CHANNELS, id="MK-15->MK-16"),
        pytest.param(MK_17, MK_18, {}, {}, id="MK-17->MK-18"),
    ],
)
def test_first_answer_is_byte_identical(
    request_frame: bytes, reply: bytes, values: dict[int, int], channels: dict[int, int]
) -> None:
    fc = make(values=values)
    fc.controls.set_ppm(channels)
    arrived_ns = fc.receive(request_frame, T0 + 3 * MS).end_ns
    assert arrived_ns == T0 + 3 * MS + wire_ns(len(request_frame))  # at wire speed (§1)
    chunks = run(fc, T0 + 100 * MS)
    assert chunks[0][1] == reply
    # Answered at the first tick after the request's last byte arrived, delivered when
    # the answer's last byte has left (§1, §7.5).
    assert 0 < chunks[0][0] - wire_ns(len(reply)) - arrived_ns <= TICK_NS


def test_mk3mag_frame_every_99_ticks_matches_mk19() -> None:
    fc = make(SimFcConfig(mk3mag_frames=True), {0: -123, 1: 45})
    chunks = run(fc, T0 + 1 * S)
    assert {c for _, c in chunks} == {MK_19}
    starts = [t - wire_ns(len(MK_19)) for t in times_of(chunks, "k")]
    assert {b - a for a, b in itertools.pairwise(starts)} == {99 * TICK_NS}
    assert len(starts) == 9


def test_forbidden_requests_are_counted_never_acted_on() -> None:
    fc = make()
    fc.receive(MK_09, T0 + 1 * MS)
    for i, cmd in enumerate("Rtqs"):
        fc.receive(encode_frame(1, cmd, b"\x0a"), T0 + (10 + 5 * i) * MS)
    chunks = run(fc, T0 + 100 * MS)
    assert [c for _, c in chunks] == [MK_13]
    assert fc.forbidden_requests == 4
    assert fc.reboots == 0
    assert fc.extern_active


def test_debug_stream_every_52_ticks_with_one_immediate_frame() -> None:
    fc = make()
    fc.receive(MK_04, T0 + 10 * MS)
    chunks = run(fc, T0 + 2 * S)
    d = times_of(chunks, "D")
    assert d[0] - (T0 + 10 * MS) <= MK04_WIRE_NS + TICK_NS + D_WIRE_NS  # answered at once
    assert {b - a for a, b in itertools.pairwise(d)} == {52 * TICK_NS}  # ≈ 53.2 ms
    # A renewal mid-period: one DebugOut at once, then the period restarts from it.
    renew_ns = d[-1] + 20 * MS
    fc.receive(MK_04, renew_ns)
    d2 = times_of(run(fc, renew_ns + 200 * MS), "D")
    assert d2[0] - renew_ns <= MK04_WIRE_NS + TICK_NS + D_WIRE_NS
    assert d2[1] - d2[0] == 52 * TICK_NS


def test_debug_period_with_mk3mag_frames_is_52_to_53_ticks() -> None:
    fc = make(SimFcConfig())
    fc.receive(MK_04, T0 + 10 * MS)
    d = times_of(run(fc, T0 + 3 * S), "D")
    gaps = [(b - a) / TICK_NS for a, b in itertools.pairwise(d)]
    assert 52 <= statistics.median(gaps) <= 53
    assert all(52 <= g <= 56 for g in gaps)  # the '#dk' frame goes first (§7.5)


def test_subscription_expires_4000_ticks_after_the_last_d_and_b_does_not_renew() -> None:
    fc = make()
    t_d = T0 + 10 * MS
    inputs = [(t_d, MK_04)]
    inputs += [(t_d + i * 50 * MS, extern(gas=0)) for i in range(1, 120)]  # 'b' at 20 Hz
    d = times_of(run(fc, t_d + 7 * S, inputs), "D")
    assert t_d + 4000 * TICK_NS - 60 * MS < d[-1] <= t_d + 4002 * TICK_NS + D_WIRE_NS
    assert len(d) in (77, 78)


def test_renewing_d_keeps_the_stream_and_d0_stops_it() -> None:
    fc = make()
    for i in range(4):  # 'd' every 2 s
        fc.receive(MK_04, T0 + i * 2 * S)
    d = times_of(run(fc, T0 + 10 * S), "D")
    assert d[-1] > T0 + 9 * S
    fc.receive(MK_05, T0 + 10 * S)
    late = times_of(run(fc, T0 + 11 * S), "D")
    assert all(t <= T0 + 10 * S + D_WIRE_NS for t in late)  # at most the one on the wire


def test_extern_control_applied_and_gas_capped() -> None:
    fc = make()
    fc.controls.set_sticks(nick=10, roll=-5, yaw=7)
    fc.receive(extern(nick=-20, roll=15, yaw=3, gas=100, frame=0, config=1), T0 + 1 * MS)
    fc.receive(MK_04, T0 + 10 * MS)
    chunks = run(fc, T0 + 50 * MS)
    assert fc.extern_active
    cmd = fc.effective_command()
    assert (cmd.nick, cmd.roll, cmd.yaw, cmd.gas) == (-10, 10, -4, 100)  # added; min(200, 100)
    debug = DebugOut.decode(frames(chunks)[0])
    assert debug.analog[7] == 400  # Gas x4 shows the cap (§7.4)
    assert debug.analog[9] == 124  # settings.battery_v
    assert debug.analog[10] == 200  # settings.receiver_level
    fc.receive(extern(gas=250, frame=0, config=1), T0 + 60 * MS)
    run(fc, T0 + 70 * MS)
    assert fc.effective_command().gas == 200  # extern gas can only lower it


@pytest.mark.parametrize(
    ("setting", "config"), [(200, 0), (128, 1), (0, 1)], ids=["config0", "setting128", "off"]
)
def test_extern_control_ignored_but_confirmed(setting: int, config: int) -> None:
    fc = make(SimFcConfig(mk3mag_frames=False, external_control=setting))
    fc.receive(extern(nick=50, gas=10, frame=9, config=config), T0 + 1 * MS)
    assert [c for _, c in run(fc, T0 + 50 * MS)] == [MK_14]
    assert not fc.extern_active
    assert fc.last_extern is not None
    assert fc.effective_command() == FcCommand(nick=0, roll=0, yaw=0, gas=200)


def test_extern_control_from_a_poti_channel() -> None:
    fc = make(SimFcConfig(mk3mag_frames=False, external_control=255))  # poti 1 = channel 5
    fc.receive(extern(gas=10, config=1), T0 + 1 * MS)
    run(fc, T0 + 10 * MS)
    fc.controls.set_ppm({5: -100})
    assert not fc.extern_active
    fc.controls.set_ppm({5: 100})  # the pilot flips the switch
    assert fc.extern_active


def test_hold_ends_extern_control_after_5_2_s_and_any_d_refreshes_it() -> None:
    fc = make()
    assert fc.hold_counts == 100  # at boot
    t_b = T0 + 10 * MS
    fc.receive(extern(gas=80, config=1), t_b)
    fc.poll(t_b + 5190 * MS)
    assert fc.extern_active
    fc.poll(t_b + 5230 * MS)
    assert not fc.extern_active
    assert fc.last_extern is not None
    assert fc.last_extern.config == 0
    assert fc.effective_command().gas == 200
    # Again, but a 'd' (not a 'b') 3 s later reloads the hold counter.
    t_b += 6 * S
    fc.receive(extern(gas=80, config=1), t_b)
    fc.receive(MK_04, t_b + 3 * S)
    fc.poll(t_b + 8190 * MS)
    assert fc.extern_active
    fc.poll(t_b + 8230 * MS)
    assert not fc.extern_active


def test_requests_are_flags_not_a_queue() -> None:
    fc = make()
    fc.receive(MK_04, T0 + 1 * MS)
    d0 = times_of(run(fc, T0 + 2 * MS), "D")
    assert d0 == []  # the first DebugOut is on the wire until ≈ 19.4 ms
    # Spaced by a frame's wire time + >= 1 tick, so none is lost on the way in (§3).
    fc.receive(extern(frame=7), T0 + 4 * MS)
    fc.receive(extern(frame=8), T0 + 9 * MS)
    fc.receive(MK_01, T0 + 14 * MS)
    fc.receive(MK_01, T0 + 16 * MS)
    found = frames(run(fc, T0 + 50 * MS))
    assert fc.rx_by_cmd == {"d": 1, "b": 2, "v": 2}
    assert [f.cmd for f in found] == ["D", "V", "B"]
    assert Confirm.decode(found[2]).frame == 8  # the last Frame number
    fc.receive(MK_04, T0 + 57 * MS)  # keeps the line busy
    fc.receive(extern(frame=7), T0 + 60 * MS)  # lost: a newer 'b' with Frame 0 (§5.3)
    fc.receive(extern(frame=0), T0 + 66 * MS)
    assert fc.tx.free_ns > T0 + 72 * MS  # the line was busy all along
    assert "B" not in [f.cmd for f in frames(run(fc, T0 + 100 * MS))]


def test_answers_leave_by_priority_v_d_a_b_p() -> None:
    fc = make()
    fc.receive(MK_04, T0 + 1 * MS)
    # All handled while the first DebugOut is on the wire (until ≈ 19.4 ms).
    requests = [(4, MK_15), (6, encode_frame(1, "a", b"\x03")), (9, MK_01), (12, extern(frame=5))]
    for t_ms, request in requests:
        fc.receive(request, T0 + t_ms * MS)
    found = frames(run(fc, T0 + 80 * MS))
    assert [f.cmd for f in found] == ["D", "V", "A", "B", "P", "D"]
    assert found[2].payload[0] == 3


def test_label_and_ppm_edge_cases() -> None:
    fc = make()
    fc.receive(encode_frame(1, "a", b"\x20"), T0 + 1 * MS)  # index 32: no such value
    fc.receive(encode_frame(0, "p"), T0 + 5 * MS)  # 'p' to address 0: not answered
    assert run(fc, T0 + 50 * MS) == []
    assert fc.rx_malformed == 1
    with pytest.raises(ValueError, match="PPM channel 26"):
        fc.controls.set_ppm({26: 0})


def test_version_from_settings() -> None:
    info = parse_version("0.90j")
    assert (info.sw_major, info.sw_minor, info.sw_patch, info.proto_major) == (0, 90, 9, 11)
    assert info.text == "0.90j"
    with pytest.raises(ConfigError, match=r"sim\.fc\.version"):
        make(SimFcConfig(version="latest"))


def test_next_event_drive_equals_polling_every_100_us() -> None:
    inputs = [(T0 + 3 * MS, MK_04)]
    inputs += [(T0 + 3 * MS + i * 50 * MS, extern(gas=90, frame=i, config=1)) for i in range(1, 20)]
    end_ns = T0 + 1100 * MS

    def drive(fc: FcModel, poll_times: list[int]) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        todo = list(inputs)
        for t in poll_times:
            while todo and todo[0][0] <= t:
                t_in, data = todo.pop(0)
                out += [(t_in, c) for c in fc.poll(t_in)]
                fc.receive(data, t_in)
            out += [(t, c) for c in fc.poll(t)]
        return out

    by_event = run(make(SimFcConfig(), {0: 5, 1: -5}), end_ns, inputs)
    by_grid = drive(make(SimFcConfig(), {0: 5, 1: -5}), list(range(T0, end_ns + 1, 100_000)))
    assert [c for _, c in by_event] == [c for _, c in by_grid]
    assert len(by_event) > 40
    # Event-driven polling sees each chunk exactly when its last byte leaves: never later
    # than polling on a 100 µs grid does.
    assert all(0 <= tg - te < 100_000 for (te, _), (tg, _) in zip(by_event, by_grid, strict=True))


# ----------------------------------------------------------------- faults
def test_garbage_goes_out_before_the_next_frame() -> None:
    fc = make()
    fc.inject_garbage(b"\x00\xffAT\r")
    fc.receive(MK_01, T0 + 1 * MS)
    chunks = run(fc, T0 + 50 * MS)
    assert [c for _, c in chunks] == [b"\x00\xffAT\r" + MK_03]
    parser = FrameParser()
    assert frames(chunks, parser)[0].cmd == "V"
    assert parser.stats.discarded_bytes == 5


def test_corrupt_next_frames() -> None:
    fc = make()
    fc.corrupt_next(2)
    fc.receive(MK_04, T0 + 1 * MS)
    parser = FrameParser()
    found = frames(run(fc, T0 + 200 * MS), parser)
    assert parser.stats.crc_errors == 2
    assert len(found) == 2
    assert fc.tx_corrupted == 2


def test_silence_loses_frames_but_the_fc_runs_on() -> None:
    fc = make()
    fc.silence(T0 + 300 * MS)
    fc.receive(MK_04, T0 + 1 * MS)
    fc.receive(MK_09, T0 + 100 * MS)  # still received and acted on
    chunks = run(fc, T0 + 600 * MS)
    assert min(t for t, _ in chunks) >= T0 + 300 * MS
    assert fc.tx_dropped == 7  # 6 DebugOut and the confirm went onto a dead line
    assert fc.extern_active


def test_reboot_cuts_the_frame_and_forgets_everything() -> None:
    fc = make()
    fc.receive(MK_04, T0 + 1 * MS)
    fc.receive(MK_09, T0 + 40 * MS)
    d = times_of(run(fc, T0 + 100 * MS), "D")
    assert fc.extern_active
    assert fc.rx_frames == 2
    t_reboot = d[-1] + 52 * TICK_NS - D_WIRE_NS // 2  # half-way through the next DebugOut
    fc.reboot(t_reboot, boot_ns=500 * MS)
    cut = fc.poll(t_reboot)
    assert len(cut) == 1
    assert 40 < len(cut[0]) < 94
    assert cut[0].startswith(b"#bD")
    assert fc.booting
    assert fc.reboots == 1
    fc.receive(MK_01, t_reboot + 100 * MS)  # deaf while booting
    assert run(fc, t_reboot + 499 * MS) == []
    assert run(fc, t_reboot + 2600 * MS) == []  # no subscription, no answer to the lost 'v'
    assert not fc.booting
    assert fc.last_extern is None
    assert not fc.extern_active
    assert fc.hold_counts == 0  # 100 at boot (2.1 s ago), one count every 20 ticks
    assert (fc.rx_frames, fc.rx_crc_errors, sum(fc.tx_by_cmd.values())) == (0, 0, 0)
    fc.receive(MK_01, t_reboot + 3 * S)
    assert [c for _, c in run(fc, t_reboot + 3100 * MS)] == [MK_03]


def test_reboot_hold_counter_starts_at_100() -> None:
    fc = make()
    fc.reboot(T0 + 1 * S, boot_ns=100 * MS)
    fc.poll(T0 + 1100 * MS)
    assert fc.hold_counts == 100
    fc.receive(debug_request(0), T0 + 1200 * MS)
    fc.poll(T0 + 1210 * MS)
    assert fc.hold_counts >= 254  # reloaded to 255; the free-running grid may have stepped
