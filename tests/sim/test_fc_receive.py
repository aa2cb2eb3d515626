r"""How the FC model receives (mk-serial.md §1, §3): rules applied at wire speed.

What the host writes arrives byte by byte at 57600 Bd (10 bits a byte), each chunk after
the previous one; a '#' starts a frame only when the receiver is idle and the last good
frame has been handled, which the model does at the first tick after its '\r' arrived.
"""

from __future__ import annotations

import pytest

from mkflight.mk.codec import encode_frame
from mkflight.mk.messages import Confirm
from mkflight.sim.fc import TICK_NS, FcModel
from mkflight.sim.fc_uart import bytes_sent, wire_ns
from tests.sim.fc_helpers import (
    B_WIRE_NS,
    MK04_WIRE_NS,
    MK_01,
    MK_03,
    MK_04,
    MK_15,
    MK_23,
    MS,
    T0,
    extern,
    make,
    run,
    times_of,
)

PHASES = range(0, TICK_NS, TICK_NS // 16)  # write times spread over one FC tick


def handled_ns(fc: FcModel, end_ns: int) -> int:
    r"""When the model handles a frame whose '\r' arrived at ``end_ns``: the next tick."""
    return fc.boot_ns + ((end_ns - fc.boot_ns) // TICK_NS + 1) * TICK_NS


def test_one_byte_time_is_10_bits_at_57600_bd() -> None:
    assert wire_ns(1) == 173_612  # 10 / 57600 s, rounded up
    assert (wire_ns(22), wire_ns(94)) == (3_819_445, 16_319_445)  # §1: 3.8 ms, 16.3 ms
    assert [bytes_sent(wire_ns(n)) for n in (1, 22, 94)] == [1, 22, 94]
    assert bytes_sent(wire_ns(22) - 1) == 21


def test_a_94_byte_chunk_arrives_16_3_ms_after_it_was_written() -> None:
    fc = make()
    t_write = T0 + 10 * MS
    request = encode_frame(1, "v", bytes(66))  # a request as long as a DebugOut
    assert len(request) == 94
    chunk = fc.receive(request, t_write)
    assert (chunk.start_ns, chunk.end_ns) == (t_write, t_write + wire_ns(94))
    assert 16.3 < (chunk.end_ns - t_write) / MS < 16.33
    assert fc.next_event_ns() == chunk.end_ns  # wake when the '\r' arrives
    fc.poll(chunk.end_ns - 1)
    assert not fc.rx.pending
    fc.poll(chunk.end_ns)
    assert fc.rx.pending
    assert fc.rx_frames == 0  # complete, not handled yet
    assert fc.next_event_ns() == handled_ns(fc, chunk.end_ns)
    fc.poll(handled_ns(fc, chunk.end_ns))
    assert fc.rx_by_cmd["v"] == 1


def test_noise_is_counted_byte_by_byte_as_it_arrives() -> None:
    fc = make()
    t_write = T0 + 1 * MS
    fc.receive(bytes(range(64, 64 + 94)), t_write)  # no '#', no '\r'
    for n in (1, 2, 47, 93, 94):
        fc.poll(t_write + wire_ns(n) - 1)
        assert fc.rx_ignored_bytes == n - 1
        fc.poll(t_write + wire_ns(n))
        assert fc.rx_ignored_bytes == n


def test_a_chunk_written_while_another_is_on_the_wire_follows_it() -> None:
    fc = make()
    first = fc.receive(extern(frame=1), T0 + 1 * MS)
    second = fc.receive(MK_04, T0 + 2 * MS)
    assert second.start_ns == first.end_ns
    assert second.end_ns == first.end_ns + MK04_WIRE_NS
    later = fc.receive(MK_01, second.end_ns + 5 * MS)
    assert later.start_ns == second.end_ns + 5 * MS  # the line was idle: no wait


@pytest.mark.parametrize("phase_ns", PHASES)
def test_d_written_3_ms_after_a_b_is_lost(phase_ns: int) -> None:
    fc = make()
    t_b = T0 + 20 * MS + phase_ns
    b_end = fc.receive(extern(gas=50, frame=9, config=1), t_b).end_ns
    d = fc.receive(MK_04, t_b + 3 * MS)
    assert d.start_ns == b_end  # the 'b' is still on the wire: the 'd' follows it
    d_hash_ns = d.start_ns + wire_ns(1)  # when the 'd' frame's '#' has arrived
    chunks = run(fc, t_b + 200 * MS)
    assert fc.rx_by_cmd["b"] == 1
    assert fc.extern_active
    assert chunks[0][1] == Confirm(9).encode()
    if handled_ns(fc, b_end) <= d_hash_ns:
        # Only when the FC's main loop happens to run within one byte time after the
        # 'b' arrived does the 'd' get through.
        assert fc.rx_by_cmd["d"] == 1
        return
    assert fc.rx_by_cmd["d"] == 0
    assert times_of(chunks, "D") == []
    assert fc.rx_lost_frames == 1
    assert fc.rx_ignored_bytes == len(MK_04)


def test_d_3_ms_after_a_b_is_lost_in_most_phases() -> None:
    lost = 0
    for phase_ns in PHASES:
        fc = make()
        t_b = T0 + 20 * MS + phase_ns
        fc.receive(extern(frame=9), t_b)
        fc.receive(MK_04, t_b + 3 * MS)
        fc.poll(t_b + 10 * MS)
        lost += fc.rx_lost_frames
    assert lost == 14  # of 16: it gets through only if a tick falls in a 174 µs window


@pytest.mark.parametrize("gap_ns", [B_WIRE_NS + 3 * MS, 7 * MS, 50 * MS])
@pytest.mark.parametrize("phase_ns", PHASES)
def test_d_written_wire_time_plus_3_ms_after_a_b_is_received(phase_ns: int, gap_ns: int) -> None:
    fc = make()
    t_b = T0 + 20 * MS + phase_ns
    fc.receive(extern(gas=50, frame=9, config=1), t_b)
    fc.receive(MK_04, t_b + gap_ns)
    chunks = run(fc, t_b + 200 * MS)
    assert (fc.rx_by_cmd["b"], fc.rx_by_cmd["d"]) == (1, 1)
    assert (fc.rx_lost_frames, fc.rx_ignored_bytes) == (0, 0)
    assert len(times_of(chunks, "D")) >= 1


def test_two_frames_in_one_write_lose_the_second_unless_a_tick_falls_between() -> None:
    fc = make()
    t_write = fc.boot_ns + 10 * TICK_NS + 1 - wire_ns(len(MK_01))  # '\r' just after a tick
    fc.receive(MK_01 + MK_15, t_write)  # two frames in one write (§3: don't)
    assert [c for _, c in run(fc, T0 + 100 * MS)] == [MK_03]
    assert fc.rx_frames == 1
    assert fc.rx_ignored_bytes == len(MK_15)
    assert fc.rx_lost_frames == 1
    # If the main loop runs between the first '\r' and the next '#', both get through.
    fc = make()
    t_write = fc.boot_ns + 10 * TICK_NS - wire_ns(len(MK_01)) - 1000
    fc.receive(MK_01 + MK_15, t_write)
    run(fc, T0 + 100 * MS)
    assert fc.rx_frames == 2


def test_truncated_frame_swallows_the_next_one_mk23() -> None:
    fc = make()
    fc.receive(MK_23, T0 + 1 * MS)
    assert run(fc, T0 + 100 * MS) == []
    assert (fc.rx_frames, fc.rx_crc_errors) == (0, 1)
    fc.receive(MK_01, T0 + 200 * MS)  # the frame after that is received normally
    assert [c for _, c in run(fc, T0 + 300 * MS)] == [MK_03]


def test_receiver_rules_overflow_bad_crc_unknown() -> None:
    fc = make()
    long = fc.receive(b"#bv" + b"=" * 200, T0 + 1 * MS)  # no '\r' within 170 bytes
    assert long.end_ns - long.start_ns == wire_ns(203)  # ≈ 35 ms: the rest queue behind
    fc.receive(b"#bv@y\r", T0 + 5 * MS)  # bad checksum: dropped silently
    fc.receive(encode_frame(1, "z"), T0 + 10 * MS)  # unknown command: ignored
    fc.receive(b"\x00\xffAT\r", T0 + 15 * MS)  # noise outside a frame
    assert run(fc, T0 + 100 * MS) == []
    assert (fc.rx_overflows, fc.rx_crc_errors, fc.rx_unknown) == (1, 1, 1)
    assert fc.rx_ignored_bytes == 203 - 170 + 5
    fc.receive(MK_01, T0 + 120 * MS)
    assert [c for _, c in run(fc, T0 + 200 * MS)] == [MK_03]


def test_bytes_arriving_while_the_fc_boots_are_not_heard() -> None:
    fc = make()
    t_reboot = T0 + 100 * MS
    fc.reboot(t_reboot, boot_ns=10 * MS)
    fc.receive(MK_01, t_reboot + 9 * MS)  # 5 bytes arrive while booting, the '\r' after
    assert run(fc, t_reboot + 50 * MS) == []
    assert (fc.rx_ignored_bytes, fc.rx_frames) == (1, 0)
    fc.receive(MK_01, t_reboot + 60 * MS)
    assert [c for _, c in run(fc, t_reboot + 100 * MS)] == [MK_03]
