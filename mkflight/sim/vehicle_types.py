"""The simulated vehicle's records (SPEC §8): its constants, its inputs and its state.

:class:`VehicleParams` (the airframe's true constants), :class:`Sticks` (what the FC
flies), :class:`FlightErrors` and :class:`VehicleState`. Their own module so the physics
(:mod:`mkflight.sim.vehicle`, which re-exports them), the sensors, the gusts and the
battery share them without import cycles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mkflight.sim.gusts import GustSeries


@dataclass(frozen=True, slots=True)
class VehicleParams:
    """The simulated airframe's TRUE constants (SPEC §8; defaults: the nominal airframe).

    The simulator's own: built from the ``sim`` config section by
    :func:`mkflight.sim.airframe.airframe_from_config` (nominal, or drawn from the
    envelope), never from ``mk``, ``control`` or the flight code's calibration. The MK's
    conventions (signs, units) are the FC's facts and are written here independently of
    the flight code's copy.
    """

    mass_kg: float = 1.04  # seed §L: 1,040 g all up
    g_mps2: float = 9.81
    counts_per_rad: float = 120.0  # the FC's attitude loop: stick counts per radian
    nick_sign: int = -1  # the MK: our angle = sign * counts / counts_per_rad (+ nick: nose down)
    roll_sign: int = -1
    yaw_sign: int = -1
    max_tilt_rad: float = 1.0  # the FC's attitude loop never commands more
    attitude_delay_s: float = 0.1  # seed §F
    attitude_tau_s: float = 0.1  # seed §F
    yaw_rate_radps_per_count: float = 0.02  # 40 counts -> 0.8 rad/s
    yaw_drift_radps: float = 0.0  # yaw rate with the yaw stick at neutral (clockwise +)
    hover_gas_counts: float = 104.0  # the gas that holds the weight at hover_voltage_v
    hover_voltage_v: float = 11.8
    gas_max_counts: float = 255.0  # the FC's gas is an unsigned char
    thrust_tau_s: float = 0.05  # motor + ESC spin-up
    ground_effect: float = 0.0  # extra thrust fraction on the ground (0.15 = +15 %)
    ground_effect_height_m: float = 0.1  # rotor height above the floor when landed
    # The landing gear (mkflight.sim.landing_gear): spring-damper + friction on the floor.
    gear_sag_m: float = 0.008  # static compression with the motors off (sets the stiffness)
    gear_compression_zeta: float = 0.3  # damping ratio while compressing: a ~40 ms stop
    gear_rebound_zeta: float = 6.0  # ... while extending: no bounce
    gear_friction: float = 0.6  # Coulomb friction coefficient on the floor
    battery_cells: int = 3  # seed §M: 3 cells, 2200 mAh
    battery_capacity_ah: float = 2.2
    battery_used_ah: float = 0.0  # already drawn at take-off
    battery_resistance_ohm: float = 0.05  # pack + wiring
    hover_current_a: float = 6.8  # seed §L: 4 x 1.7 A
    avionics_current_a: float = 0.5  # seed §L: Gumstix, laser, hub
    drag_linear_per_s: float = 0.3  # k1
    drag_quadratic_per_m: float = 0.1  # k2
    wind_std_mps: float = 0.1  # OU gust velocity, horizontal, felt through the drag
    wind_std_z_mps: float = 0.05  # OU gust velocity, vertical
    wind_tau_s: float = 2.0
    gusts: bool = True
    gust_accel_std_mps2: float = 0.0  # OU disturbance acceleration, horizontal (turbulence)
    gust_accel_z_ratio: float = 0.4  # ... vertical, as a fraction of that
    gust_tau_s: float = 1.0
    pitch_trim_std_rad: float = 0.005  # per flight, seeded (normal)
    trim_rad: tuple[float, float] = (0.0, 0.0)  # fixed angle bias (pitch, roll) of this FC
    acc_bias_std_mps2: float = 0.05  # per flight and axis, seeded (normal)
    acc_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)  # fixed bias of this FC
    vibration_std_mps2: float = 0.2  # left in the FC-averaged x/y accelerations at hover
    vibration_z_ratio: float = 1.0  # AccZ vibration as a fraction of the x/y one
    angle_noise_std_rad: float = 0.002
    battery_noise_std_v: float = 0.02
    # The FC's accelerometer as it really is (the MK's units, mk-serial.md §6; SPEC §1).
    acc_nick_counts_per_g: float = 606.3
    acc_roll_counts_per_g: float = 603.44
    acc_z_counts_per_mps2: float = 15.5
    acc_z_offset_mps2: float = 9.8
    # Timing of the links (the emulators and the lock-step simulation).
    laser_extra_delay_s: float = 0.0  # scans older than the driver's transport_delay_s says
    laser_jitter_s: float = 0.0  # USB jitter per URG reply, uniform 0..this
    debug_jitter_ticks: int = 0  # DebugOut leaves up to this many FC ticks late
    debug_late_fraction: float = 0.0  # this share of DebugOuts 5-25 ms late
    # The laser hat as built on this airframe (the sim's own, not the flight's laser.*).
    hat_steps: tuple[int, int] = (44, 127)  # URG steps the mirror folds down to the floor
    mirror_edge_last_step: int = 149  # steps after the hat up to this see the mirror's edge
    hat_offset_m: float = 0.05  # the hat's range on the floor minus the height (standing: 0)


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
