"""The simulated vehicle's records (SPEC §8): its constants, its inputs and its state.

:class:`VehicleParams` (the airframe's true constants), :class:`Sticks` (what the FC
flies), :class:`FlightErrors` and :class:`VehicleState`. Their own module so the physics
(:mod:`mkflight.sim.vehicle`, which re-exports them), the sensors and the battery share
them without import cycles (the gusts read the airframe through
:class:`~mkflight.sim.gusts.GustParams`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mkflight.config import SimVehicleConfig
from mkflight.sim.gusts import GustSeries


@dataclass(frozen=True, slots=True)
class VehicleParams:
    """The simulated airframe's TRUE constants (SPEC §8), SI, as the physics reads them.

    The simulator's own: :meth:`from_config` takes them from the ``sim.vehicle`` config
    section (the nominal airframe), :func:`mkflight.sim.airframe.draw_airframe` draws an
    airframe from the envelope; never from ``mk``, ``control`` or the flight code's
    calibration. No defaults: every value has its one home in
    :class:`~mkflight.config.SimVehicleConfig`, documented there. Three fields carry their
    unit in the name where the config key does not (``hover_gas_counts`` is
    ``hover_gas``, ``thrust_tau_s`` is ``gas_tau_s``, ``pitch_trim_std_rad`` is
    ``trim_std_rad``); ``wind_std_z_mps`` is derived (half the horizontal wind).
    """

    mass_kg: float
    g_mps2: float
    counts_per_rad: float
    nick_sign: int
    roll_sign: int
    yaw_sign: int
    max_tilt_rad: float
    attitude_delay_s: float
    attitude_tau_s: float
    yaw_rate_radps_per_count: float
    yaw_drift_radps: float
    hover_gas_counts: float
    hover_voltage_v: float
    gas_max_counts: float
    thrust_tau_s: float
    ground_effect: float
    ground_effect_height_m: float
    gear_sag_m: float
    gear_compression_zeta: float
    gear_rebound_zeta: float
    gear_friction: float
    battery_cells: int
    battery_capacity_ah: float
    battery_used_ah: float
    battery_resistance_ohm: float
    hover_current_a: float
    avionics_current_a: float
    drag_linear_per_s: float
    drag_quadratic_per_m: float
    wind_std_mps: float
    wind_std_z_mps: float
    wind_tau_s: float
    gusts: bool
    gust_accel_std_mps2: float
    gust_accel_z_ratio: float
    gust_tau_s: float
    pitch_trim_std_rad: float
    trim_rad: tuple[float, float]
    acc_bias_std_mps2: float
    acc_bias_mps2: tuple[float, float, float]
    vibration_std_mps2: float
    vibration_z_ratio: float
    angle_noise_std_rad: float
    battery_noise_std_v: float
    acc_nick_counts_per_g: float
    acc_roll_counts_per_g: float
    acc_z_counts_per_mps2: float
    acc_z_offset_mps2: float
    laser_extra_delay_s: float
    laser_jitter_s: float
    debug_jitter_ticks: int
    debug_late_fraction: float
    hat_steps: tuple[int, int]
    mirror_edge_last_step: int
    hat_offset_m: float

    @classmethod
    def from_config(cls, vehicle: SimVehicleConfig) -> VehicleParams:
        """The airframe the ``sim.vehicle`` section describes (the nominal one)."""
        return cls(
            mass_kg=vehicle.mass_kg,
            g_mps2=vehicle.g_mps2,
            counts_per_rad=vehicle.counts_per_rad,
            nick_sign=vehicle.nick_sign,
            roll_sign=vehicle.roll_sign,
            yaw_sign=vehicle.yaw_sign,
            max_tilt_rad=vehicle.max_tilt_rad,
            attitude_delay_s=vehicle.attitude_delay_s,
            attitude_tau_s=vehicle.attitude_tau_s,
            yaw_rate_radps_per_count=vehicle.yaw_rate_radps_per_count,
            yaw_drift_radps=vehicle.yaw_drift_radps,
            hover_gas_counts=vehicle.hover_gas,
            hover_voltage_v=vehicle.hover_voltage_v,
            gas_max_counts=vehicle.gas_max_counts,
            thrust_tau_s=vehicle.gas_tau_s,
            ground_effect=vehicle.ground_effect,
            ground_effect_height_m=vehicle.ground_effect_height_m,
            gear_sag_m=vehicle.gear_sag_m,
            gear_compression_zeta=vehicle.gear_compression_zeta,
            gear_rebound_zeta=vehicle.gear_rebound_zeta,
            gear_friction=vehicle.gear_friction,
            battery_cells=vehicle.battery_cells,
            battery_capacity_ah=vehicle.battery_capacity_ah,
            battery_used_ah=vehicle.battery_used_ah,
            battery_resistance_ohm=vehicle.battery_resistance_ohm,
            hover_current_a=vehicle.hover_current_a,
            avionics_current_a=vehicle.avionics_current_a,
            drag_linear_per_s=vehicle.drag_linear_per_s,
            drag_quadratic_per_m=vehicle.drag_quadratic_per_m,
            wind_std_mps=vehicle.wind_std_mps,
            wind_std_z_mps=vehicle.wind_std_mps / 2.0,
            wind_tau_s=vehicle.wind_tau_s,
            gusts=vehicle.gusts,
            gust_accel_std_mps2=vehicle.gust_accel_std_mps2,
            gust_accel_z_ratio=vehicle.gust_accel_z_ratio,
            gust_tau_s=vehicle.gust_tau_s,
            pitch_trim_std_rad=vehicle.trim_std_rad,
            trim_rad=vehicle.trim_rad,
            acc_bias_std_mps2=vehicle.acc_bias_std_mps2,
            acc_bias_mps2=vehicle.acc_bias_mps2,
            vibration_std_mps2=vehicle.vibration_std_mps2,
            vibration_z_ratio=vehicle.vibration_z_ratio,
            angle_noise_std_rad=vehicle.angle_noise_std_rad,
            battery_noise_std_v=vehicle.battery_noise_std_v,
            acc_nick_counts_per_g=vehicle.acc_nick_counts_per_g,
            acc_roll_counts_per_g=vehicle.acc_roll_counts_per_g,
            acc_z_counts_per_mps2=vehicle.acc_z_counts_per_mps2,
            acc_z_offset_mps2=vehicle.acc_z_offset_mps2,
            laser_extra_delay_s=vehicle.laser_extra_delay_s,
            laser_jitter_s=vehicle.laser_jitter_s,
            debug_jitter_ticks=vehicle.debug_jitter_ticks,
            debug_late_fraction=vehicle.debug_late_fraction,
            hat_steps=vehicle.hat_steps,
            mirror_edge_last_step=vehicle.mirror_edge_last_step,
            hat_offset_m=vehicle.hat_offset_m,
        )


@dataclass(frozen=True, slots=True)
class Sticks:
    """What the FC flies (``mkflight.sim.fc_control.FcCommand``), in MK counts.

    + nick = nose down, + roll = left side down, + yaw = nose turns left; gas 0..255.
    """

    nick_counts: float = 0.0
    roll_counts: float = 0.0
    yaw_counts: float = 0.0
    gas_counts: float = 0.0


@dataclass(frozen=True, slots=True)
class FlightErrors:
    """This flight's constant errors: attitude trim and accelerometer biases.

    Each is the airframe's fixed value (``VehicleParams.trim_rad``, ``acc_bias_mps2``) plus
    a per-flight normal draw (``pitch_trim_std_rad``, ``acc_bias_std_mps2``), made by
    :func:`initial_state`.
    """

    pitch_trim_rad: float = 0.0
    roll_trim_rad: float = 0.0
    acc_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)


Vec3 = tuple[float, float, float]
_ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Everything :func:`step` needs (SI, world frame W, z down; resting on the floor: z = 0).

    ``targets`` is the delay line: ``(t_s, pitch*, roll*, yaw_rate*)`` per step, newest
    last. ``acc_w_mps2`` is the last acceleration, floor contact included (for the specific
    force). ``wind_w_mps`` and ``gust_w_mps2`` are the air at ``t_s`` (from ``gusts``, the
    flight's :class:`~mkflight.sim.gusts.GustSeries`; ``None``: made with seed 0 when
    needed). ``touchdowns`` holds ``(t_s, speed_mps)`` of every contact with the floor from
    the air at >= 0.05 m/s, the downward speed at first contact (the truth of a landing's
    hardness). ``on_ground``: the landing gear touches the floor.

    :func:`mkflight.sim.vehicle.step` builds the next state field by field (faster than
    ``dataclasses.replace``): a new field must be carried there too.
    """

    t_s: float = 0.0
    pos_w_m: Vec3 = _ZERO
    vel_w_mps: Vec3 = _ZERO
    acc_w_mps2: Vec3 = _ZERO
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    thrust_n: float = 0.0
    used_ah: float = 0.0
    battery_v: float = 0.0
    current_a: float = 0.0
    wind_w_mps: Vec3 = _ZERO
    gust_w_mps2: Vec3 = _ZERO
    on_ground: bool = True
    errors: FlightErrors = field(default_factory=FlightErrors)
    targets: tuple[tuple[float, float, float, float], ...] = ()
    touchdowns: tuple[tuple[float, float], ...] = ()
    gusts: GustSeries | None = None

    @property
    def height_m(self) -> float:
        """Height above the resting position (motors off), positive up."""
        return -self.pos_w_m[2]
