"""The simulated side of ``sim hover``: DebugOut instants, laser timing, scans."""

from __future__ import annotations

import itertools
import statistics
from pathlib import Path

import numpy as np
import pytest

from mkflight.config import Config, SimConfig, SimVehicleConfig
from mkflight.sim.fc_timing import TICK_NS
from mkflight.sim.hover import scan_from_raw
from mkflight.sim.lockstep import (
    IMU_PERIOD_NS,
    LASER_DELAY_NS,
    SCAN_PERIOD_NS,
    LockstepVehicle,
    PoseFix,
    RawScan,
)
from mkflight.sim.truth import TruthLog
from mkflight.sim.urg_server import USB_DELAY_S
from mkflight.sim.vehicle import Sticks, VehicleParams
from mkflight.urg.units import URG_04LX

MS = 1_000_000
S = 1_000_000_000
CALM = SimConfig(vehicle=SimVehicleConfig(gusts=False))
END_NS = URG_04LX.step_offset_ns(725)
FRONT_NS = URG_04LX.step_offset_ns(384)


def arrivals(v: LockstepVehicle, until_ns: int) -> list[tuple[int, PoseFix | RawScan]]:
    """Every laser delivery up to ``until_ns``, polled at the DebugOut instants."""
    out: list[tuple[int, PoseFix | RawScan]] = []
    while (t := v.next_debug_ns()) <= until_ns:
        v.advance_to(t, Sticks())
        out += [(t, d) for d in v.laser_arrivals(t)]
    return out


def test_debug_instants_are_52_ticks_without_jitter() -> None:
    v = LockstepVehicle(CALM, seed=1)
    times = [v.next_debug_ns() for _ in range(100)]
    assert {b - a for a, b in itertools.pairwise(times)} == {IMU_PERIOD_NS}


def test_debug_instants_carry_the_airframes_jitter_and_late_frames() -> None:
    params = VehicleParams.from_config(
        SimVehicleConfig(debug_jitter_ticks=2, debug_late_fraction=0.05)
    )
    v = LockstepVehicle(CALM, seed=1, params=params)
    times = [v.next_debug_ns() for _ in range(3000)]
    gaps = [(b - a) / TICK_NS for a, b in itertools.pairwise(times)]
    assert min(gaps) == 52
    assert {g for g in gaps if g <= 54} == {52, 53, 54}
    late_gaps = [g for g in gaps if g > 54]
    assert 0.03 * len(gaps) < len(late_gaps) < 0.07 * len(gaps)
    assert v.debug_jitter.late_frames == pytest.approx(len(late_gaps), abs=1)
    assert statistics.mean(gaps) == pytest.approx(52 + 1 + 0.05 * 14.65, abs=0.25)


def test_poses_are_stamped_extra_late_and_delivered_100_ms_plus_extra_plus_jitter() -> None:
    params = VehicleParams.from_config(
        SimVehicleConfig(laser_extra_delay_s=0.02, laser_jitter_s=0.005)
    )
    v = LockstepVehicle(CALM, seed=2, params=params)
    got = arrivals(v, 5 * S)
    assert len(got) >= 45
    stamps = []
    for t, data in got:
        assert isinstance(data, PoseFix)
        taken = data.pose.t_ns - 20 * MS  # stamped 20 ms later than it was taken
        assert taken % SCAN_PERIOD_NS == 0
        assert t >= taken + LASER_DELAY_NS + 20 * MS  # 100 ms + extra (+ jitter) ...
        assert t < taken + LASER_DELAY_NS + 20 * MS + 5 * MS + IMU_PERIOD_NS  # ... at a step
        stamps.append(data.pose.t_ns)
    assert stamps == sorted(stamps)  # in order


def test_scans_are_the_urgs_values_stamped_and_delivered_like_the_emulator() -> None:
    params = VehicleParams.from_config(SimVehicleConfig(laser_extra_delay_s=0.01))
    v = LockstepVehicle(CALM, seed=3, scans=True, scan_steps=(44, 725), params=params)
    got = arrivals(v, 2 * S)
    assert len(got) >= 17
    for t, data in got:
        assert isinstance(data, RawScan)
        assert data.start_ns == data.seq * SCAN_PERIOD_NS
        assert data.stamp_ns == data.start_ns + FRONT_NS + 10 * MS  # the driver's belief
        deliver = data.start_ns + END_NS + round(USB_DELAY_S * 1e9) + 10 * MS
        assert deliver <= t < deliver + IMU_PERIOD_NS
        assert data.first_step == 44
        assert data.values_mm.shape == (725 - 44 + 1,)
        scan = scan_from_raw(data)
        hat = scan.ranges_m[: 127 - 44 + 1]
        assert float(np.nanmedian(hat)) == pytest.approx(0.05, abs=0.02)  # on the floor
        front = scan.ranges_m[384 - 44 - 3 : 384 - 44 + 4]
        assert float(np.nanmedian(front)) == pytest.approx(2.4, abs=0.05)  # default_room
        assert scan.t_ns == data.stamp_ns


def test_scan_from_raw_turns_codes_and_no_echo_into_nan() -> None:
    raw = RawScan(0, 0, 5, 100, np.array([0, 7, 19, 20, 1234, 5600, 5601], dtype=np.int64))
    scan = scan_from_raw(raw)
    assert scan.first_step == 100
    assert scan.t_ns == 5
    assert np.isnan(scan.ranges_m[:3]).all()
    assert scan.ranges_m[3:6].tolist() == [0.02, 1.234, 5.6]
    assert np.isnan(scan.ranges_m[6])


def test_touchdowns_go_into_the_truth_log_before_a_row(tmp_path: Path) -> None:
    truth = TruthLog(tmp_path / "truth.txt", origin_ns=0)
    v = LockstepVehicle(CALM, seed=4, truth=truth)
    t = 0
    while t < 3 * S:  # climb for 0.6 s, then the motors stop
        t = v.next_debug_ns()
        v.advance_to(t, Sticks(gas_counts=130 if t < 600 * MS else 0))
    truth.close()
    assert len(v.touchdowns) >= 1
    assert v.touchdowns[0][1] > 1.0  # fell with the motors off
    lines = (tmp_path / "truth.txt").read_text().splitlines()
    marks = [i for i, line in enumerate(lines) if line.startswith("# touchdown ")]
    assert len(marks) == len(v.touchdowns)
    assert all(not lines[i + 1].startswith("#") for i in marks)


def test_the_same_seed_flies_the_same_and_the_laser_form_leaves_the_vehicle_alone() -> None:
    def fly(seed: int, scans: bool) -> tuple[object, dict[int, int]]:
        v = LockstepVehicle(SimConfig(), seed=seed, scans=scans)
        t = 0
        while t < 1 * S:
            t = v.next_debug_ns()
            v.advance_to(t, Sticks(nick_counts=5, gas_counts=140))
        return v.state.pos_w_m, v.debug_values()

    assert fly(1, False) == fly(1, False)
    assert fly(1, False) != fly(2, False)
    # Scans step the vehicle in 10 ms chunks (a history for the beams): the same flight
    # within the integration's sub-step differences (same errors, same gusts).
    assert fly(1, False)[0] == pytest.approx(fly(1, True)[0], abs=2e-3)


def test_only_the_sim_section_is_read() -> None:
    cfg = Config()
    v = LockstepVehicle(cfg.sim, seed=1)
    assert v.params.hover_gas_counts == cfg.sim.vehicle.hover_gas  # 104, not control's 100
    assert v.params.hover_gas_counts != cfg.control.hover_gas
