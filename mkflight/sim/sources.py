"""Where the emulated FlightCtrl's DebugOut values come from (``mk-serial.md`` §6).

Each class here satisfies :class:`mkflight.sim.fc.AnalogSource`: the FC model asks it for
raw s16 values by index whenever it builds a DebugOut or an MK3MAG frame. The flying
vehicle of the simulator is :class:`mkflight.sim.world.SimWorld`; these two cover the
protocol tests (a fixed table, e.g. the values of vectors MK-07/MK-08) and a vehicle
standing still (``mk info --sim``). Counts come from the simulator's own encoder
(:func:`mkflight.sim.mk_units.encode_analog`), never the flight's calibration.
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from typing import TYPE_CHECKING, Final

from mkflight.mk.messages import (
    ANALOG_ACC_NICK,
    ANALOG_ACC_ROLL,
    ANALOG_ACC_Z,
    ANALOG_ANGLE_NICK,
    ANALOG_ANGLE_ROLL,
    ANALOG_COUNT,
    ANALOG_GYRO_COMPASS,
)
from mkflight.mk.units import INT16_MAX, INT16_MIN
from mkflight.sim.mk_units import encode_analog
from mkflight.sim.vehicle import VehicleParams
from mkflight.sim.vehicle_sensors import ImuSi

if TYPE_CHECKING:
    from mkflight.sim.fc import FcModel

ACC_NOISE_COUNTS: Final = 2  # ± uniform noise on AccNick, AccRoll, AccZ
ANGLE_NOISE_COUNTS: Final = 1  # ± uniform noise on AngleNick, AngleRoll, Gyro Compass
_ACC_INDEXES: Final = (ANALOG_ACC_NICK, ANALOG_ACC_ROLL, ANALOG_ACC_Z)
_ANGLE_INDEXES: Final = (ANALOG_ANGLE_NICK, ANALOG_ANGLE_ROLL)


def _check_values(values: Mapping[int, int]) -> dict[int, int]:
    """Copy ``values``, checking each index (0..31) and each value (int16)."""
    out: dict[int, int] = {}
    for index, value in values.items():
        if not 0 <= index < ANALOG_COUNT:
            msg = f"analog index {index} outside 0..{ANALOG_COUNT - 1}"
            raise ValueError(msg)
        if not INT16_MIN <= value <= INT16_MAX:
            msg = f"analog[{index}] = {value} does not fit a signed 16-bit value"
            raise ValueError(msg)
        out[index] = value
    return out


class FixedSource:
    """The same raw values at every sample (unspecified indexes read 0)."""

    def __init__(self, values: Mapping[int, int]) -> None:
        """Keep a checked copy of ``{index: raw value}``.

        Raises:
            ValueError: an index outside 0..31 or a value outside int16.
        """
        self.values = _check_values(values)

    def analog(self, t_ns: int, fc: FcModel) -> Mapping[int, int]:
        """The fixed values, whatever the time."""
        return dict(self.values)


class RestingVehicleSource:
    """A vehicle standing still at a fixed attitude, with small seeded sensor noise.

    At rest the accelerometers measure the specific force
    f = (g sin θ, -g sin φ cos θ, -g cos φ cos θ) (SPEC §1), converted to counts by the
    simulator's :func:`~mkflight.sim.mk_units.encode_analog` with the airframe ``params``'
    accelerometer scales. The noise comes from ``random.Random(seed)``, so the sequence
    of samples is the same for the same seed and the same calls.
    """

    def __init__(
        self,
        params: VehicleParams,
        seed: int,
        *,
        pitch_rad: float = 0.0,
        roll_rad: float = 0.0,
        yaw_rad: float = 0.0,
        battery_v: float = 12.4,
        noise: bool = True,
    ) -> None:
        """Compute the noiseless counts of the resting vehicle once.

        Raises:
            ValueError: a non-finite angle or voltage.
        """
        for name, value in (
            ("pitch_rad", pitch_rad),
            ("roll_rad", roll_rad),
            ("yaw_rad", yaw_rad),
            ("battery_v", battery_v),
        ):
            if not math.isfinite(value):
                msg = f"RestingVehicleSource.{name} must be finite, got {value}"
                raise ValueError(msg)
        g = params.g_mps2
        self.noise = noise
        self._rng = random.Random(seed)
        at_rest = ImuSi(
            pitch_rad,
            roll_rad,
            yaw_rad,
            g * math.sin(pitch_rad),
            -g * math.sin(roll_rad) * math.cos(pitch_rad),
            -g * math.cos(roll_rad) * math.cos(pitch_rad),
        )
        self.base_counts: dict[int, int] = encode_analog(at_rest, battery_v, params)

    def analog(self, t_ns: int, fc: FcModel) -> Mapping[int, int]:
        """The resting counts, plus ±2 counts on accelerations and ±1 on angles."""
        values = dict(self.base_counts)
        if not self.noise:
            return values
        rng = self._rng
        for index in _ACC_INDEXES:
            noisy = values[index] + rng.randint(-ACC_NOISE_COUNTS, ACC_NOISE_COUNTS)
            values[index] = max(INT16_MIN, min(INT16_MAX, noisy))
        for index in _ANGLE_INDEXES:
            noisy = values[index] + rng.randint(-ANGLE_NOISE_COUNTS, ANGLE_NOISE_COUNTS)
            values[index] = max(INT16_MIN, min(INT16_MAX, noisy))
        heading = values[ANALOG_GYRO_COMPASS]
        noise = rng.randint(-ANGLE_NOISE_COUNTS, ANGLE_NOISE_COUNTS)
        values[ANALOG_GYRO_COMPASS] = (heading + noise) % 360
        return values
