"""MK raw DebugOut values <-> SI (SPEC §1 table, ``mk-serial.md`` §6.2, TABLE I/II).

The tables are those of the 2011 QUT CyPhy MikroKopter documentation.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mkflight.config import MkConfig
from mkflight.mk.messages import (
    ANALOG_ACC_NICK,
    ANALOG_ACC_ROLL,
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_GYRO_COMPASS,
    ANALOG_VOLTAGE,
    DebugOut,
)
from mkflight.mk.units import (
    DEFAULT_CALIBRATION,
    INT16_MAX,
    INT16_MIN,
    MkCalibration,
    analog_from_si,
    imu_from_debug,
)
from mkflight.msgs import ImuSample

from .vectors import MK_08

CAL = DEFAULT_CALIBRATION
G = 9.81
#: The documentation TABLE I/II are transcribed from, relative to the shared folder.
SEED = "seed/mikrokopter-documentation.txt"

# One count's worth of each SI quantity under the default calibration.
ANGLE_RES_RAD = math.radians(0.1)
FX_RES = G / 606.3
FY_RES = G / 603.44
FZ_RES = 1 / 15.5


def imu_of(values: dict[int, int]) -> ImuSample:
    """Convert a DebugOut holding ``values`` (others 0) with the default calibration."""
    return imu_from_debug(DebugOut.from_values(values), t_ns=123, cal=CAL)


def si_to_counts(imu: ImuSample, cal: MkCalibration = CAL) -> dict[int, int]:
    """analog_from_si applied to every SI field of ``imu``."""
    return analog_from_si(
        pitch_rad=imu.pitch_rad,
        roll_rad=imu.roll_rad,
        yaw_rad=imu.yaw_rad,
        acc_x_mps2=imu.acc_x_mps2,
        acc_y_mps2=imu.acc_y_mps2,
        acc_z_mps2=imu.acc_z_mps2,
        battery_v=imu.battery_v,
        cal=cal,
    )


# --- constants ---------------------------------------------------------------------------


def test_default_calibration_is_spec_table() -> None:
    assert CAL.angle_unit_rad == pytest.approx(0.1 * math.pi / 180, rel=1e-15)
    assert CAL.acc_nick_counts_per_g == 606.3
    assert CAL.acc_roll_counts_per_g == 603.44
    assert CAL.acc_z_counts_per_mps2 == 15.5
    assert CAL.acc_z_offset_mps2 == 9.8
    assert CAL.voltage_unit_v == 0.1
    assert CAL.g_mps2 == G


def test_calibration_follows_config() -> None:
    cal = MkCalibration.from_config(MkConfig(angle_unit_deg=0.2, g_mps2=9.8))
    imu = imu_from_debug(DebugOut.from_values({0: -10, 2: -606}), 0, cal)
    assert imu.pitch_rad == pytest.approx(math.radians(2.0), abs=1e-12)
    assert imu.acc_x_mps2 == pytest.approx(606 * 9.8 / 606.3, abs=1e-12)


# --- worked example (mk-serial.md §6.2, vector MK-08) ------------------------------------


def test_worked_example_mk08() -> None:
    imu = imu_from_debug(DebugOut.from_values(MK_08.analog, MK_08.status), 42, CAL)
    assert imu.t_ns == 42
    assert imu.pitch_rad == pytest.approx(+0.020944, abs=1e-6)
    assert imu.roll_rad == pytest.approx(-0.054105, abs=1e-6)
    assert imu.acc_x_mps2 == pytest.approx(+0.210341, abs=1e-6)
    assert imu.acc_y_mps2 == pytest.approx(+0.536474, abs=1e-6)
    assert imu.acc_z_mps2 == pytest.approx(-9.670968, abs=1e-6)
    assert imu.yaw_rad == pytest.approx(-1.553343, abs=1e-6)
    assert imu.yaw_rad == pytest.approx(math.radians(-89), abs=1e-12)
    assert imu.battery_v == pytest.approx(11.8, abs=1e-9)
    assert imu.gas_counts == 120
    assert imu.receiver_level == 200


@pytest.mark.parametrize(
    ("compass_deg", "yaw_deg"),
    [(0, 0), (1, 1), (90, 90), (179, 179), (180, 180), (181, -179), (271, -89), (359, -1)],
)
def test_yaw_wraps_to_half_open_range(compass_deg: int, yaw_deg: int) -> None:
    yaw = imu_of({ANALOG_GYRO_COMPASS: compass_deg}).yaw_rad
    assert -math.pi < yaw <= math.pi
    assert yaw == pytest.approx(math.radians(yaw_deg), abs=1e-12)


def test_yaw_180_is_plus_pi() -> None:
    assert imu_of({ANALOG_GYRO_COMPASS: 180}).yaw_rad == math.pi


@pytest.mark.parametrize(
    ("index", "value", "field", "expected"),
    [
        (ANALOG_ANGLE_NICK, 100, "pitch_rad", -math.radians(10)),  # + nick = nose down
        (ANALOG_ANGLE_ROLL, 100, "roll_rad", -math.radians(10)),  # + roll = left side down
        (ANALOG_ACC_NICK, -606, "acc_x_mps2", 606 * G / 606.3),
        (ANALOG_ACC_ROLL, 603, "acc_y_mps2", 603 * G / 603.44),
        (ANALOG_ACC_Z, 0, "acc_z_mps2", -9.8),
        (ANALOG_ACC_Z, 155, "acc_z_mps2", -19.8),
        (ANALOG_VOLTAGE, 126, "battery_v", 12.6),
    ],
)
def test_sign_conventions(index: int, value: int, field: str, expected: float) -> None:
    assert getattr(imu_of({index: value}), field) == pytest.approx(expected, abs=1e-12)


# --- round trips -------------------------------------------------------------------------

physical_counts = st.fixed_dictionaries(
    {
        ANALOG_ANGLE_NICK: st.integers(-900, 900),
        ANALOG_ANGLE_ROLL: st.integers(-900, 900),
        ANALOG_ACC_NICK: st.integers(-1300, 1300),
        ANALOG_ACC_ROLL: st.integers(-1300, 1300),
        ANALOG_ACC_Z: st.integers(-400, 400),
        ANALOG_GYRO_COMPASS: st.integers(0, 359),
        ANALOG_VOLTAGE: st.integers(0, 170),
    }
)


@given(physical_counts)
def test_counts_si_counts_round_trip(counts: dict[int, int]) -> None:
    back = si_to_counts(imu_of(counts))
    assert set(back) == set(counts)
    for index, value in counts.items():
        assert abs(back[index] - value) <= 1, (index, value, back[index])


@given(
    st.floats(-math.pi / 2, math.pi / 2),
    st.floats(-math.pi / 2, math.pi / 2),
    st.floats(-math.pi, math.pi),
    st.tuples(*[st.floats(-2 * G, 2 * G)] * 3),
    st.floats(0, 17),
)
def test_si_counts_si_within_one_count(
    pitch: float, roll: float, yaw: float, acc: tuple[float, float, float], volts: float
) -> None:
    imu = ImuSample(0, pitch, roll, yaw, *acc, battery_v=volts)
    back = imu_of(si_to_counts(imu))
    assert abs(back.pitch_rad - pitch) <= ANGLE_RES_RAD
    assert abs(back.roll_rad - roll) <= ANGLE_RES_RAD
    assert abs(math.remainder(back.yaw_rad - yaw, 2 * math.pi)) <= math.radians(1)
    assert abs(back.acc_x_mps2 - acc[0]) <= FX_RES
    assert abs(back.acc_y_mps2 - acc[1]) <= FY_RES
    assert abs(back.acc_z_mps2 - acc[2]) <= FZ_RES
    assert abs(back.battery_v - volts) <= 0.1


def test_analog_from_si_saturates_and_ignores_non_finite() -> None:
    counts = analog_from_si(
        pitch_rad=1e9,
        roll_rad=-1e9,
        yaw_rad=math.nan,
        acc_x_mps2=math.inf,
        acc_y_mps2=1e12,
        acc_z_mps2=-1e12,
        battery_v=math.nan,
        cal=CAL,
    )
    assert counts[ANALOG_ANGLE_NICK] == INT16_MIN
    assert counts[ANALOG_ANGLE_ROLL] == INT16_MAX
    assert counts[ANALOG_GYRO_COMPASS] == 0
    assert counts[ANALOG_ACC_NICK] == 0
    assert counts[ANALOG_ACC_ROLL] == INT16_MAX
    assert counts[ANALOG_ACC_Z] == INT16_MAX
    assert counts[ANALOG_VOLTAGE] == 0
    DebugOut.from_values(counts).encode()  # every value fits on the wire


# --- physics: a static vehicle at tilt (SPEC §1) -----------------------------------------


@given(st.floats(-1.4, 1.4), st.floats(-1.4, 1.4))
def test_static_tilt_reads_gravity(pitch: float, roll: float) -> None:
    f = (
        G * math.sin(pitch),
        -G * math.sin(roll) * math.cos(pitch),
        -G * math.cos(roll) * math.cos(pitch),
    )
    counts = analog_from_si(
        pitch_rad=pitch,
        roll_rad=roll,
        yaw_rad=0.0,
        acc_x_mps2=f[0],
        acc_y_mps2=f[1],
        acc_z_mps2=f[2],
        battery_v=12.0,
        cal=CAL,
    )
    # The documentation's model (eq 7, TABLE I/II): counts = -k sin(angle), in the MK's own counts.
    assert abs(counts[ANALOG_ACC_NICK] - (-606.3 * math.sin(pitch))) <= 0.5 + 1e-9
    assert abs(counts[ANALOG_ACC_ROLL] - (-603.44 * math.sin(roll) * math.cos(pitch))) <= 0.5 + 1e-9
    assert abs(counts[ANALOG_ANGLE_NICK] - (-math.degrees(pitch) * 10)) <= 0.5 + 1e-9
    back = imu_of(counts)
    assert abs(back.pitch_rad - pitch) <= ANGLE_RES_RAD
    assert abs(back.roll_rad - roll) <= ANGLE_RES_RAD
    assert abs(back.acc_x_mps2 - f[0]) <= FX_RES
    assert abs(back.acc_y_mps2 - f[1]) <= FY_RES
    assert abs(back.acc_z_mps2 - f[2]) <= FZ_RES
    # ... and the recovered specific force is gravity seen at the recovered attitude.
    expected = (
        G * math.sin(back.pitch_rad),
        -G * math.sin(back.roll_rad) * math.cos(back.pitch_rad),
        -G * math.cos(back.roll_rad) * math.cos(back.pitch_rad),
    )
    for got, want, res in zip(
        (back.acc_x_mps2, back.acc_y_mps2, back.acc_z_mps2),
        expected,
        (FX_RES, FY_RES, FZ_RES),
        strict=True,
    ):
        assert abs(got - want) <= res + G * ANGLE_RES_RAD


# --- TABLE I / II: k by least squares ----------------------------------------------------

TABLE_ANGLES_DEG = (-90, -60, -50, -45, -15, 0, 15, 45, 50, 60, 90)

# Source: ``../shared/seed/mikrokopter-documentation.txt`` (Inkyu Sa, "MikroKopter
# documentation", CyPhy Laboratory, 31 October 2011), section "D. MK acceleration scale factor
# measurement": TABLE I and TABLE II, copied cell for cell; the same section gives the fits
# k = 606.3 (pitch) and k = 603.44 (roll) units/g. ``test_table_literals_match_seed`` compares
# these literals with the document when ``../shared`` is there (deselected otherwise).
#
# TABLE I: MK AccNick vs pitch (rows 1st, 2nd, 3rd, Mean).
TABLE_I: dict[str, tuple[float, ...]] = {
    "1st": (602, 522, 458, 428, 152, 0, -122, -431, -457, -531, -617),
    "2nd": (602, 525, 468, 432, 154, 0, -123, -433, -462, -532, -618),
    "3rd": (602, 523, 470, 422, 153, 0, -122, -432, -463, -532, -617),
    "Mean": (602, 523.3, 465.3, 427.3, 153, 0, -122.3, -432, -460.6, -531.6, -617.3),
}
# TABLE II: MK AccRoll vs roll.
TABLE_II: dict[str, tuple[float, ...]] = {
    "1st": (612, 522, 458, 436, 162, 0, -167, -430, -462, -522, -587),
    "2nd": (611, 521, 456, 443, 161, 0, -162, -432, -463, -515, -588),
    "3rd": (613, 523, 457, 439, 160, 0, -165, -431, -463, -517, -588),
    "Mean": (612, 522, 457, 439.3, 161, 0, -164.6, -431, -462.6, -518, -587.6),
}


def fit_k(rows: list[tuple[float, ...]]) -> float:
    """Least squares of ``counts = -k sin(angle)`` over every cell: k = -Σ c·s / Σ s²."""
    num = 0.0
    den = 0.0
    for row in rows:
        for angle_deg, c in zip(TABLE_ANGLES_DEG, row, strict=True):
            s = math.sin(math.radians(angle_deg))
            num += c * s
            den += s * s
    return -num / den


def _seed_table(text: str, header: str) -> dict[str, tuple[float, ...]]:
    """Read one table (the header row starting with ``header`` and the 4 rows after it)."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header + "\t"))
    table: dict[str, tuple[float, ...]] = {}
    for line in lines[start + 1 : start + 5]:
        name, *cells = line.split("\t")
        table[name] = tuple(float(c) for c in cells)
    return table


@pytest.mark.shared(SEED)
def test_table_literals_match_seed(shared_dir: Path) -> None:
    text = (shared_dir / SEED).read_text(encoding="utf-8")
    assert _seed_table(text, "Pitch") == TABLE_I
    assert _seed_table(text, "Roll") == TABLE_II
    assert "k = 606.3" in text
    assert "k = 603.44" in text


def test_fit_pitch_all_rows_is_606_3() -> None:
    k = fit_k(list(TABLE_I.values()))
    assert round(k, 1) == 606.3, f"TABLE I (all 4 rows) fits k = {k:.4f}"


def test_fit_roll_all_rows_is_603_43_because_the_means_are_truncated() -> None:
    """SPEC §1 says all rows fit 603.44; with the printed (truncated) Mean row they give
    603.4322. The documentation's 603.44 is the fit of its measurements (exact means): see below.
    """
    k = fit_k(list(TABLE_II.values()))
    assert round(k, 2) == 603.43, f"TABLE II (all 4 rows) fits k = {k:.4f}"


def test_fit_measurement_rows_only() -> None:
    """The three measurement rows alone (without the printed, truncated Mean row)."""
    k_pitch = fit_k([TABLE_I[r] for r in ("1st", "2nd", "3rd")])
    k_roll = fit_k([TABLE_II[r] for r in ("1st", "2nd", "3rd")])
    assert round(k_pitch, 1) == 606.3, k_pitch
    assert round(k_roll, 2) == 603.44, k_roll


def test_table_means_are_truncated_means_of_the_rows() -> None:
    """The printed Mean rows are the row means cut (not rounded) to one decimal."""
    for table in (TABLE_I, TABLE_II):
        for i in range(len(TABLE_ANGLES_DEG)):
            mean = sum(table[r][i] for r in ("1st", "2nd", "3rd")) / 3
            assert table["Mean"][i] == math.trunc(mean * 10) / 10, (i, mean)
