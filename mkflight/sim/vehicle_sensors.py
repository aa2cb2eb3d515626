"""What the FC measures of the simulated vehicle (SPEC §1, §8): truth plus real-flight errors.

:func:`imu_truth_si` is the noiseless DebugOut content in SI (the specific force
``R^T (a - g)``); :func:`imu_measured_si` and :func:`battery_reading_v` add what real
flight adds: the motor vibration left in the FC's averaged accelerations (``vibration_std_mps2``
on x and y, ``vibration_z_ratio`` of that on z, scaled by thrust / weight), the attitude
trim and accelerometer biases (the airframe's fixed ones plus this flight's draws: the
state's :class:`~mkflight.sim.vehicle.FlightErrors`) and noise.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mkflight.frames import wrap_pi
from mkflight.sim.vehicle import VehicleParams, VehicleState, body_to_world


class ImuSi(NamedTuple):
    """DebugOut content in SI (SPEC §1): angles and body specific force (FRD)."""

    pitch_rad: float
    roll_rad: float
    yaw_rad: float
    acc_x_mps2: float
    acc_y_mps2: float
    acc_z_mps2: float


def imu_truth_si(state: VehicleState, params: VehicleParams) -> ImuSi:
    """True attitude and body specific force ``f = R^T (a - (0, 0, g))`` (SPEC §1, §8).

    At rest this is ``(g sin θ, -g sin φ cos θ, -g cos φ cos θ)``.
    """
    rot = body_to_world(state.pitch_rad, state.roll_rad, state.yaw_rad)
    f = rot.T @ (np.array(state.acc_w_mps2) - np.array([0.0, 0.0, params.g_mps2]))
    return ImuSi(
        state.pitch_rad, state.roll_rad, state.yaw_rad, float(f[0]), float(f[1]), float(f[2])
    )


def imu_measured_si(state: VehicleState, params: VehicleParams, rng: np.random.Generator) -> ImuSi:
    """What the FC reports: truth minus trim, plus biases, vibration and angle noise.

    The FC's horizon is off by the trim (it flies ``command + trim``, reports ``true -
    trim``); the motor vibration left in its averaged accelerations scales with thrust
    (``vibration_std_mps2`` on x and y at hover, ``vibration_z_ratio`` of that on z, none
    with the motors off).
    """
    truth = imu_truth_si(state, params)
    e = state.errors
    vib = params.vibration_std_mps2 * state.thrust_n / (params.mass_kg * params.g_mps2)
    acc_noise = rng.normal(0.0, 1.0, 3) * vib
    acc_noise[2] *= params.vibration_z_ratio
    ang_noise = rng.normal(0.0, params.angle_noise_std_rad, 3)
    return ImuSi(
        truth.pitch_rad - e.pitch_trim_rad + float(ang_noise[0]),
        truth.roll_rad - e.roll_trim_rad + float(ang_noise[1]),
        wrap_pi(truth.yaw_rad + float(ang_noise[2])),
        truth.acc_x_mps2 + e.acc_bias_mps2[0] + float(acc_noise[0]),
        truth.acc_y_mps2 + e.acc_bias_mps2[1] + float(acc_noise[1]),
        truth.acc_z_mps2 + e.acc_bias_mps2[2] + float(acc_noise[2]),
    )


def battery_reading_v(
    state: VehicleState, params: VehicleParams, rng: np.random.Generator
) -> float:
    """The FC's voltage reading: terminal voltage plus noise (quantised later to 0.1 V)."""
    return state.battery_v + float(rng.normal(0.0, params.battery_noise_std_v))
