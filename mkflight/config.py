"""Configuration: every constant, gain and limit, as frozen msgspec Structs decoded from YAML.

The defaults are those of the 2011 QUT CyPhy MikroKopter documentation (its sections,
equations and tables are cited as §D, eq 7, TABLE I) and of SPEC.md; ``config.yaml`` at the
repository root spells out the same values (a test keeps them identical). Each default is
defined here only: the components take their section (or a view derived from it by a
``from_config`` classmethod) and repeat none of these values. Each field carries its unit in
its name and its range in a ``Meta``; msgspec rejects an unknown key, a wrong type or an
out-of-range value with the path (``$.control.kp_xy``), which :func:`load_config` turns
into a :class:`ConfigError` naming the dotted key. The loader never prints or exits.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
import yaml
from msgspec import Meta

from mkflight.errors import ConfigError

Sign = Literal[-1, 1]
PosFloat = Annotated[float, Meta(gt=0)]
NonNegFloat = Annotated[float, Meta(ge=0)]
Gain = Annotated[float, Meta(ge=0, le=1000)]
Step = Annotated[int, Meta(ge=0, le=1080)]
TrimRad = Annotated[float, Meta(ge=-0.2, le=0.2)]
AccBias = Annotated[float, Meta(ge=-2, le=2)]


class MkSigns(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """MK command sign per axis: MK counts = sign x our angle (SPEC §1: all -1)."""

    nick: Sign = -1
    roll: Sign = -1
    yaw: Sign = -1


class MkConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The FlightCtrl link and the MK raw<->SI calibration (SPEC §1-2, §D eq 7-8)."""

    port: str = "/dev/mkflight-fc"
    """The FC's adapter by the name ``tools/99-mkflight.rules`` gives it (not ttyUSBn,
    whose number depends on the order the adapters enumerate)."""
    baudrate: Annotated[int, Meta(ge=1200, le=4_000_000)] = 57600
    debug_interval_10ms: Annotated[int, Meta(ge=1, le=255)] = 5
    resubscribe_s: Annotated[float, Meta(gt=0, le=2.0)] = 1.3
    """Renew 'd' this often: the FC expires it ~4.1 s after the last renewal it *received*,
    and a renewal can be lost (a frame whose '#' arrives while the FC still handles the
    previous one is dropped, mk-serial.md §3). At 2 s two lost renewals in a row stop the
    DebugOuts for a stale time; at 1.3 s it takes three."""
    version_retry_s: Annotated[float, Meta(gt=0, le=5)] = 0.5
    answer_timeout_s: Annotated[float, Meta(gt=0, le=30)] = 2.0
    min_frame_gap_s: Annotated[float, Meta(ge=0.003, le=0.05)] = 0.003
    confirm_every: Annotated[int, Meta(ge=1, le=20)] = 8
    """Number one in this many ExternControl frames that take control (1: every one); the
    others carry Frame 0, which asks the FC for no 'B' confirm (mk-serial.md §5.3). Each
    confirm is a frame the daemon wakes up for: ~0.18 ms of CPU on the development VM
    (1 in 4 instead of every one saved 0.14 ms a step). At 8, one every ~0.4 s still gives
    the round-trip time and the lost-confirm count. Config = 0 frames (the handshake, the
    release) are always numbered: their confirms are checked. At most 20 (one a second)."""
    release_frames: Annotated[int, Meta(ge=3, le=50)] = 5
    release_interval_s: Annotated[float, Meta(ge=0.003, le=0.5)] = 0.05
    handshake_s: Annotated[float, Meta(ge=1.0, le=10)] = 1.0
    reopen_backoff_s: Annotated[float, Meta(gt=0, le=10)] = 0.1
    reopen_backoff_max_s: Annotated[float, Meta(gt=0, le=60)] = 2.0
    signs: MkSigns = msgspec.field(default_factory=MkSigns)
    counts_per_rad: Annotated[float, Meta(gt=0, le=1000)] = 120.0
    angle_unit_deg: PosFloat = 0.1
    acc_nick_counts_per_g: PosFloat = 606.3
    acc_roll_counts_per_g: PosFloat = 603.44
    acc_z_counts_per_mps2: PosFloat = 15.5
    acc_z_offset_mps2: float = 9.8
    voltage_unit_v: PosFloat = 0.1
    g_mps2: Annotated[float, Meta(ge=9.7, le=9.9)] = 9.81


class LaserConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The Hokuyo URG and the laser hat (SPEC §2-3, §K eq 26)."""

    port: str = "/dev/mkflight-urg"
    """The URG's port by the name ``tools/99-mkflight.rules`` gives it."""
    scan_steps: tuple[Step, Step] = (150, 725)
    hat_steps: tuple[Step, Step] = (44, 127)
    hat_offset_m: Annotated[float, Meta(ge=0, le=1)] = 0.05
    min_range_m: NonNegFloat = 0.02
    max_range_m: PosFloat = 5.6
    transport_delay_s: Annotated[float, Meta(ge=0, le=0.5)] = 0.03
    stall_s: Annotated[float, Meta(gt=0, le=5)] = 0.3
    """No scan for this long: QT, drain, re-issue MD (``scip2.md`` §6)."""
    request_timeout_s: Annotated[float, Meta(gt=0, le=10)] = 1.0
    """Longest wait for the answer to one request."""
    drain_silence_s: Annotated[float, Meta(gt=0, le=1)] = 0.15
    """After QT, the sensor is quiet once it sent nothing for this long..."""
    drain_max_s: Annotated[float, Meta(gt=0, le=10)] = 1.0
    """... waiting at most this long for it."""
    max_restarts: Annotated[int, Meta(ge=0, le=100)] = 5
    """MD re-issued this many times in a row without a good scan: the sensor failed."""
    sum_error_run: Annotated[int, Meta(ge=1, le=100)] = 3
    """This many scans in a row with a bad sum re-issue MD."""
    reopen_backoff_s: Annotated[float, Meta(gt=0, le=10)] = 0.1
    """First wait before re-opening a vanished port, doubling..."""
    reopen_backoff_max_s: Annotated[float, Meta(gt=0, le=60)] = 2.0
    """... up to this."""


class EstimationConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The velocity filter (§H eq 15-17, or a Kalman filter) and latency compensation."""

    filter_period_s: Annotated[float, Meta(gt=0, le=1)] = 0.05
    filter_gain_per_s: Gain = 6.7
    filter_gain_z_per_s: Gain = 20.0
    latency_compensation: bool = True
    tilt_acceleration: bool = True
    """Integrate the attitude's horizontal acceleration corrected by the accelerometers
    (``mkflight.estimation.tilt_accel``) instead of the vibrating accelerometers alone."""
    imu_history_s: Annotated[float, Meta(gt=0, le=5)] = 0.5
    filter: Literal["kalman", "complementary"] = "kalman"
    """``kalman``: position, velocity and disturbance per axis with gains from the noises
    (``mkflight.estimation.kalman``); ``complementary``: eq 15-17 with the gains k above."""
    pose_noise_m: Annotated[float, Meta(gt=0, le=0.5)] = 0.002
    """The scan matcher's position noise at hover (the Kalman filter's trust in it), m."""
    height_noise_m: Annotated[float, Meta(gt=0, le=0.5)] = 0.0005
    """The hat height's weight in the Kalman filter, as a noise (m): below the hat's own
    (~1.5 mm, the median of its beams) because the thrust model's errors are slow, not
    white; chosen on the airframe envelope."""
    model_noise_mps2: Annotated[float, Meta(gt=0, le=10)] = 0.3
    """White noise on the model's acceleration (attitude, thrust), m/s^2 per sample."""


class ControlConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Position, velocity, yaw and altitude loops and their limits (SPEC §4, §C, J, K)."""

    kp_xy: Gain = 2.0
    ki_xy: Gain = 0.05
    kd_xy: Gain = 0.0
    max_speed_mps: Annotated[float, Meta(gt=0, le=5)] = 0.5
    kp_vxy: Gain = 5.1
    ki_vxy: Gain = 0.46
    kd_vxy: Gain = 1.1
    max_tilt_rad: Annotated[float, Meta(gt=0, le=0.6)] = 0.30
    disturbance_ff: Annotated[float, Meta(ge=0, le=1)] = 0.0
    """Counter this share of the turbulence the estimator sees (feed-forward, 0..1)."""
    kp_yaw: Gain = 40.0
    ki_yaw: Gain = 0.0
    kd_yaw: Gain = 0.0
    yaw_max_counts: Annotated[int, Meta(ge=0, le=127)] = 40
    kp_z: Gain = 4.0
    ki_z: Gain = 0.0
    kd_z: Gain = 0.0
    max_climb_mps: Annotated[float, Meta(gt=0, le=2)] = 0.5
    kp_vz: Gain = 60.0
    ki_vz: Gain = 20.0
    kd_vz: Gain = 5.0
    integral_limit_gas: Annotated[float, Meta(ge=0, le=255)] = 30.0
    hover_gas: Annotated[float, Meta(ge=0, le=255)] = 100.0
    hover_voltage_v: PosFloat = 11.8
    gas_max: Annotated[int, Meta(ge=0, le=255)] = 130
    climb_mps: Annotated[float, Meta(gt=0, le=2)] = 0.3
    land_mps: Annotated[float, Meta(gt=0, le=2)] = 0.3
    takeoff_height_m: Annotated[float, Meta(gt=0, le=3)] = 0.6
    land_detect_height_m: NonNegFloat = 0.05
    land_detect_s: NonNegFloat = 1.0


class ScanmatchConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Point-to-line ICP and keyframes (:func:`mkflight.scanmatch.icp.match`, KeyframeMatcher).

    CSM is the matcher ROS laser_scan_matcher runs; its defaults are given for comparison.
    """

    max_iterations: Annotated[int, Meta(ge=1, le=100)] = 10
    """Gauss-Newton steps at most (CSM/laser_scan_matcher: 10)."""
    max_correspondence_m: Annotated[float, Meta(gt=0, le=5)] = 0.5
    """Gate on the point to line-centre distance in the first iterations (CSM:
    0.3 m; wider so an odometry prior that is 0.3 m off on a 1 m step still converges)."""
    min_correspondence_m: Annotated[float, Meta(gt=0, le=5)] = 0.2
    """Once steps are below 1 cm / 0.01 rad the gate shrinks by 0.7 per iteration down to
    this, so late iterations ignore far outliers."""
    keep_fraction: Annotated[float, Meta(gt=0, le=1)] = 1.0
    """Share of the gated correspondences kept, smallest residuals first (CSM
    ``outliers_maxPerc`` = 0.9); 1 = off, because the Cauchy weights measured better on
    the real logs."""
    robust_scale_m: Annotated[float, Meta(ge=0, le=1)] = 0.05
    """Cauchy weight ``1 / (1 + (r / c)^2)`` on each residual, c in metres; 0 = plain
    least squares."""
    step_tolerance_m: Annotated[float, Meta(gt=0, le=0.1)] = 1e-4
    """Converged when the translation step is below this..."""
    step_tolerance_rad: Annotated[float, Meta(gt=0, le=0.1)] = 1e-4
    """... and the rotation step below this."""
    min_matches: Annotated[int, Meta(ge=3, le=10000)] = 20
    """Fewest inlier correspondences of a valid result."""
    min_matched_fraction: Annotated[float, Meta(ge=0, le=1)] = 0.1
    """Fewest inliers of a valid result, as a fraction of the scan's points."""
    max_rms_m: Annotated[float, Meta(gt=0, le=1)] = 0.05
    """Largest RMS point-to-line residual of a valid result."""
    degeneracy_threshold: Annotated[float, Meta(ge=0, le=1)] = 0.01
    """Structural information below which a direction counts as unobservable. Measured:
    the synthetic rooms score >= 0.09 on their weakest axis, real offices (Intel, fr079)
    0.01-0.1 in 99 % of scans, the 12 m corridor exactly 0."""
    noise_floor: Annotated[float, Meta(ge=0, le=1)] = 0.2
    """A residual row counts toward a direction's structural information only when its
    projection on that direction exceeds this: wall normals tilted by range noise give
    ~0.05 and must not make a corridor look observable."""
    max_points: Annotated[int, Meta(ge=0, le=100000)] = 0
    """The current scan is thinned evenly to at most this many points (0 = all); fewer
    points cost proportionally less time."""
    keyframe_distance_m: Annotated[float, Meta(gt=0, le=5)] = 0.10
    """A new keyframe after this much motion from the current one (laser_scan_matcher's
    ``kf_dist_linear``)..."""
    keyframe_angle_rad: Annotated[float, Meta(gt=0, le=3.2)] = 0.1745
    """... or this much turn (10 degrees, its ``kf_dist_angular``)."""
    worker: Literal["process", "inline"] = "inline"
    """Where the daemon runs the matcher: on its event loop between steps (``inline``: a
    compiled match costs well under a millisecond) or in a worker process at lower
    priority (``process``: for the numpy kernel, or a slow board)."""
    kernel: Literal["auto", "numba", "numpy"] = "auto"
    """The matcher's inner loops: compiled by numba (``auto`` when numba imports) or the
    numpy reference (same poses to rounding; several times slower)."""


class SafetyConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Failsafe thresholds (SPEC §5)."""

    box_m: Annotated[float, Meta(gt=0, le=50)] = 2.0
    max_height_m: Annotated[float, Meta(gt=0, le=10)] = 1.5
    warn_voltage_v: Annotated[float, Meta(ge=0, le=60)] = 10.8
    land_voltage_v: Annotated[float, Meta(ge=0, le=60)] = 10.4
    voltage_filter_s: Annotated[float, Meta(gt=0, le=60)] = 2.0
    laser_stale_s: Annotated[float, Meta(gt=0, le=5)] = 0.3
    degenerate_land_s: Annotated[float, Meta(ge=0, le=10)] = 1.0
    mk_stale_s: Annotated[float, Meta(gt=0, le=5)] = 0.2
    mk_release_s: Annotated[float, Meta(gt=0, le=10)] = 1.0
    nonfinite_land_steps: Annotated[int, Meta(ge=1, le=100)] = 3
    pilot_stick_counts: Annotated[int, Meta(ge=1, le=500)] = 25  # a stick moved: release


class LoggingConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Where flight folders go (SPEC §6)."""

    dir: str = "flights"


class LiveConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The live view's rates (``fly --live``): each kind at its own rate, or these lower ones.

    The step's values come every DebugOut (≈ 19 Hz), the scans every 100 ms; a lower rate
    here publishes only the newest value once per its period. Phase changes and failsafe
    events are always published.
    """

    state_rate_hz: Annotated[float, Meta(gt=0, le=20)] = 20.0
    """Pose, set-point, frame transforms, height, attitude, velocity, command, battery."""
    scan_rate_hz: Annotated[float, Meta(gt=0, le=10)] = 10.0
    """The laser scan (``/scan``)."""
    backlog_messages: Annotated[int, Meta(ge=1, le=10000)] = 64
    """Messages queued per client; a slow client loses the oldest beyond this."""


class SimFcConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The FlightCtrl emulator's settings (``mk-serial.md`` §5-7)."""

    version: str = "0.84a"
    external_control: Annotated[int, Meta(ge=0, le=255)] = 200
    stick_gas: Annotated[int, Meta(ge=0, le=255)] = 200
    mk3mag_frames: bool = True
    receiver_level: Annotated[int, Meta(ge=0, le=255)] = 200
    battery_v: Annotated[float, Meta(ge=0, le=60)] = 12.4


class SimVehicleConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The nominal simulated airframe's TRUE constants (``mkflight.sim.airframe``, SPEC §8).

    A second opinion, not a mirror: nothing here is read by the flight code, and the
    simulator reads nothing of ``mk``, ``control`` or the flight code's calibration. The
    defaults are SPEC §8's nominal airframe; ``hover_gas`` (104) differs from
    ``control.hover_gas`` (100, the controller's feed-forward) on purpose, as a real airframe
    does from its tuning, and the MK's conventions (signs, accelerometer scales) are the
    FC's facts, written here independently of ``mk``'s copy. ``sim.airframe: random``
    draws the envelope's constants (``mkflight.sim.airframe.ENVELOPE``) and takes the
    others from these defaults, not from this section.
    """

    mass_kg: Annotated[float, Meta(gt=0, le=20)] = 1.04
    """All up (§L: 1,040 g)."""
    g_mps2: Annotated[float, Meta(ge=9.7, le=9.9)] = 9.81
    hover_gas: Annotated[float, Meta(gt=0, le=255)] = 104.0
    """The gas that holds the weight at ``hover_voltage_v``."""
    hover_voltage_v: Annotated[float, Meta(gt=0, le=60)] = 11.8
    gas_max_counts: Annotated[float, Meta(gt=0, le=255)] = 255.0
    """The FC's gas is an unsigned char."""
    counts_per_rad: Annotated[float, Meta(gt=0, le=1000)] = 120.0
    """The FC's attitude loop: stick counts per radian."""
    nick_sign: Sign = -1
    """The MK: angle = sign x counts / counts_per_rad (+ nick: nose down)."""
    roll_sign: Sign = -1
    yaw_sign: Sign = -1
    max_tilt_rad: Annotated[float, Meta(gt=0, le=1.6)] = 1.0
    """The FC's attitude loop never commands more."""
    yaw_rate_radps_per_count: Annotated[float, Meta(gt=0, le=1)] = 0.02
    """The yaw stick is a rate: 40 counts -> 0.8 rad/s."""
    yaw_drift_radps: Annotated[float, Meta(ge=-1, le=1)] = 0.0
    """Yaw rate with the yaw stick at neutral (clockwise +)."""
    attitude_delay_s: Annotated[float, Meta(ge=0, le=1)] = 0.1
    """The attitude response's pure delay (§F)..."""
    attitude_tau_s: Annotated[float, Meta(gt=0, le=2)] = 0.1
    """... and first-order lag."""
    gas_tau_s: Annotated[float, Meta(gt=0, le=1)] = 0.05
    """Motors + ESCs: gas -> thrust lag."""
    ground_effect: Annotated[float, Meta(ge=0, le=1)] = 0.0
    """Extra thrust on the floor (0.15: +15 %), fading with height."""
    ground_effect_height_m: Annotated[float, Meta(gt=0, le=1)] = 0.1
    """The rotors' height above the floor when landed."""
    gear_sag_m: Annotated[float, Meta(gt=0, le=0.1)] = 0.008
    """Landing gear: static compression with the motors off (sets the stiffness)."""
    gear_compression_zeta: Annotated[float, Meta(gt=0, le=20)] = 0.3
    """Damping ratio while compressing: a ~40 ms stop."""
    gear_rebound_zeta: Annotated[float, Meta(gt=0, le=20)] = 6.0
    """Damping ratio while extending: no bounce."""
    gear_friction: Annotated[float, Meta(ge=0, le=2)] = 0.6
    """Coulomb friction coefficient on the floor."""
    drag_linear_per_s: Annotated[float, Meta(ge=0, le=5)] = 0.3
    """k1 of the drag ``k1 v + k2 |v| v`` per unit mass."""
    drag_quadratic_per_m: Annotated[float, Meta(ge=0, le=5)] = 0.1
    """k2 of the same."""
    gusts: bool = True
    wind_std_mps: Annotated[float, Meta(ge=0, le=5)] = 0.1
    """Ornstein-Uhlenbeck wind velocity, horizontal (half of it vertical), through the drag."""
    wind_tau_s: Annotated[float, Meta(gt=0, le=60)] = 2.0
    gust_accel_std_mps2: Annotated[float, Meta(ge=0, le=5)] = 0.0
    """Ornstein-Uhlenbeck disturbance acceleration, horizontal (turbulence)..."""
    gust_accel_z_ratio: Annotated[float, Meta(ge=0, le=5)] = 0.4
    """... vertical, as a fraction of that."""
    gust_tau_s: Annotated[float, Meta(gt=0, le=60)] = 1.0
    trim_std_rad: Annotated[float, Meta(ge=0, le=0.2)] = 0.005
    """Attitude trim per flight and axis, seeded (normal)."""
    trim_rad: tuple[TrimRad, TrimRad] = (0.0, 0.0)
    """The fixed angle bias (pitch, roll) of this FC."""
    acc_bias_std_mps2: Annotated[float, Meta(ge=0, le=2)] = 0.05
    """Accelerometer bias per flight and axis, seeded (normal)."""
    acc_bias_mps2: tuple[AccBias, AccBias, AccBias] = (0.0, 0.0, 0.0)
    """The fixed accelerometer bias (x, y, z) of this FC."""
    vibration_std_mps2: Annotated[float, Meta(ge=0, le=5)] = 0.2
    """Motor vibration left in the FC-averaged x/y accelerations at hover."""
    vibration_z_ratio: Annotated[float, Meta(ge=0, le=5)] = 1.0
    """... on AccZ, as a fraction of that."""
    angle_noise_std_rad: Annotated[float, Meta(ge=0, le=0.1)] = 0.002
    acc_nick_counts_per_g: PosFloat = 606.3
    """The FC's accelerometer as it is (``mk-serial.md`` §6; SPEC §1)."""
    acc_roll_counts_per_g: PosFloat = 603.44
    acc_z_counts_per_mps2: PosFloat = 15.5
    acc_z_offset_mps2: float = 9.8
    battery_cells: Annotated[int, Meta(ge=1, le=12)] = 3
    """§M: 3 cells, 2200 mAh."""
    battery_capacity_ah: Annotated[float, Meta(gt=0, le=50)] = 2.2
    battery_used_ah: Annotated[float, Meta(ge=0, le=50)] = 0.0
    """Already drawn at take-off."""
    battery_resistance_ohm: Annotated[float, Meta(ge=0, le=1)] = 0.05
    """Pack + wiring."""
    hover_current_a: Annotated[float, Meta(gt=0, le=100)] = 6.8
    """§L: 4 x 1.7 A."""
    avionics_current_a: Annotated[float, Meta(ge=0, le=20)] = 0.5
    """§L: Gumstix, laser, hub."""
    battery_noise_std_v: Annotated[float, Meta(ge=0, le=1)] = 0.02
    laser_extra_delay_s: Annotated[float, Meta(ge=0, le=0.5)] = 0.0
    """The URG's data is this much older than the driver's ``transport_delay_s`` says."""
    laser_jitter_s: Annotated[float, Meta(ge=0, le=0.1)] = 0.0
    """USB jitter per URG reply, uniform 0..this."""
    debug_jitter_ticks: Annotated[int, Meta(ge=0, le=50)] = 0
    """The FC's main loop sends DebugOut up to this many 1.024 ms ticks late..."""
    debug_late_fraction: Annotated[float, Meta(ge=0, le=0.5)] = 0.0
    """... and this share of DebugOuts 5-25 ms late."""
    hat_steps: tuple[Step, Step] = (44, 127)
    """URG steps the laser hat's mirror folds down to the floor, as built on this airframe."""
    mirror_edge_last_step: Step = 149
    """Steps after the hat up to this one see the mirror's edge."""
    hat_offset_m: Annotated[float, Meta(ge=0, le=1)] = 0.05
    """The hat's range on the floor minus the height (standing on the floor: 0)."""


class SimConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The simulator (SPEC §8)."""

    seed: Annotated[int, Meta(ge=0)] = 1
    airframe: Literal["nominal", "random"] = "nominal"
    """``random``: every airframe constant drawn from the envelope with ``seed``."""
    fc: SimFcConfig = msgspec.field(default_factory=SimFcConfig)
    vehicle: SimVehicleConfig = msgspec.field(default_factory=SimVehicleConfig)


class Config(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The whole configuration (``config.yaml``)."""

    mk: MkConfig = msgspec.field(default_factory=MkConfig)
    laser: LaserConfig = msgspec.field(default_factory=LaserConfig)
    estimation: EstimationConfig = msgspec.field(default_factory=EstimationConfig)
    scanmatch: ScanmatchConfig = msgspec.field(default_factory=ScanmatchConfig)
    control: ControlConfig = msgspec.field(default_factory=ControlConfig)
    safety: SafetyConfig = msgspec.field(default_factory=SafetyConfig)
    logging: LoggingConfig = msgspec.field(default_factory=LoggingConfig)
    live: LiveConfig = msgspec.field(default_factory=LiveConfig)
    sim: SimConfig = msgspec.field(default_factory=SimConfig)


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader, plus YAML 1.2's exponent floats without a dot (``1e-3``).

    YAML 1.1, which PyYAML follows, reads ``1e-3`` as the string "1e-3", and a gain
    written that way would be refused as "got str".
    """


class YamlDumper(yaml.SafeDumper):
    """PyYAML's safe dumper that quotes what :class:`_YamlLoader` would read as a float.

    Its stock resolver writes the string "1e-3" unquoted, which our loader reads back
    as the number 0.001: a file we write must read back as what we wrote.
    """


_EXPONENT_FLOAT = re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")
for _yaml_class in (_YamlLoader, YamlDumper):
    _yaml_class.add_implicit_resolver(
        "tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789")
    )
_NON_FINITE = re.compile(r"[-+]?(?:nan|inf|infinity)", re.IGNORECASE)


def _load_yaml(text: str) -> Any:
    """Parse YAML safely (never a Python object tag), with :class:`_YamlLoader`."""
    return yaml.load(text, Loader=_YamlLoader)  # a SafeLoader: no Python tags


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read the YAML config file ``path`` as a mapping of sections (an empty file: ``{}``).

    The one reader of config files (:func:`load_config`, ``calibrate --write-config``):
    a file one command accepts, another must not refuse (PyYAML's ``safe_load`` reads
    ``1e-4`` as a string). Not validated: that is :func:`config_from_dict`'s job.

    Raises:
        ConfigError: unreadable file, not UTF-8, invalid YAML, or a top level that is not
            a mapping; the message starts with the path.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as err:
        msg = f"{source}: cannot read config file: {err.strerror or err}"
        raise ConfigError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{source}: not UTF-8 text (byte {err.start}): {err.reason}"
        raise ConfigError(msg) from err
    try:
        data = _load_yaml(text)
    except yaml.YAMLError as err:
        msg = f"{source}: invalid YAML: {err}"
        raise ConfigError(msg) from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        msg = f"{source}: the top level must be a mapping of sections"
        raise ConfigError(msg)
    return data


def dump_yaml(data: dict[str, Any]) -> str:
    """A config mapping as YAML text that :func:`read_yaml` reads back unchanged.

    Keys keep their order; comments of a file that was read are not kept.
    """
    return yaml.dump(data, Dumper=YamlDumper, sort_keys=False, allow_unicode=True)


def _check_finite(obj: Any, path: str, source: str) -> None:
    """Reject NaN/inf anywhere: YAML's ``.nan`` would otherwise pass every range check."""
    if isinstance(obj, float) and not math.isfinite(obj):
        msg = f"{source}: {path}: must be a finite number, got {obj}"
        raise ConfigError(msg)
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{path}.{k}" if path else str(k), source)
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            _check_finite(v, f"{path}[{i}]", source)


def _dotted(msgspec_path: str) -> str:
    """``$.control.kp_xy`` -> ``control.kp_xy``."""
    return msgspec_path.removeprefix("$.").removeprefix("$")


def _cross_checks(cfg: Config, source: str) -> None:
    """Rules that span fields, which a per-field range cannot express."""
    step_ranges = {
        "laser.scan_steps": cfg.laser.scan_steps,
        "laser.hat_steps": cfg.laser.hat_steps,
        "sim.vehicle.hat_steps": cfg.sim.vehicle.hat_steps,
    }
    for key, (lo, hi) in step_ranges.items():
        if lo > hi:
            msg = f"{source}: {key}: first step {lo} is after last step {hi}"
            raise ConfigError(msg)
    if cfg.safety.land_voltage_v > cfg.safety.warn_voltage_v:
        msg = f"{source}: safety.land_voltage_v: must not exceed safety.warn_voltage_v"
        raise ConfigError(msg)
    if cfg.control.takeoff_height_m > cfg.safety.max_height_m:
        msg = f"{source}: control.takeoff_height_m: above safety.max_height_m"
        raise ConfigError(msg)
    if cfg.scanmatch.min_correspondence_m > cfg.scanmatch.max_correspondence_m:
        msg = f"{source}: scanmatch.min_correspondence_m: above max_correspondence_m"
        raise ConfigError(msg)
    for section in ("mk", "laser"):
        backoff = getattr(cfg, section)
        if backoff.reopen_backoff_s > backoff.reopen_backoff_max_s:
            msg = (
                f"{source}: {section}.reopen_backoff_s: must not exceed "
                f"{section}.reopen_backoff_max_s"
            )
            raise ConfigError(msg)


def config_from_dict(data: Any, source: str = "config") -> Config:
    """Decode a plain mapping (parsed YAML) into a :class:`Config`, or raise ConfigError."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        msg = f"{source}: the top level must be a mapping of sections, got {type(data).__name__}"
        raise ConfigError(msg)
    _check_finite(data, "", source)
    try:
        cfg = msgspec.convert(data, type=Config, strict=True)
    except msgspec.ValidationError as err:
        text, where = str(err), ""
        located = re.fullmatch(r"(.*) - at `(key` in `)?(\$[^`]*)`", text, re.DOTALL)
        if located:
            text, where = located.group(1), _dotted(located.group(3))
            if located.group(2):
                text = f"keys must be names: {text}"
        unknown = re.fullmatch(r"Object contains unknown field `(.+)`", text)
        if unknown:
            where = f"{where}.{unknown.group(1)}" if where else unknown.group(1)
            text = "unknown key"
        msg = f"{source}: {where}: {text}" if where else f"{source}: {text}"
        raise ConfigError(msg) from err
    _cross_checks(cfg, source)
    return cfg


def parse_override(item: str) -> tuple[list[str], Any]:
    """Split ``section.key=value`` into a key path and a YAML-parsed value."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        msg = f"--set {item!r}: expected KEY=VALUE, e.g. control.kp_xy=1.2"
        raise ConfigError(msg)
    parts = key.split(".")
    if any(not p for p in parts):
        msg = f"--set {item!r}: malformed key {key!r}"
        raise ConfigError(msg)
    try:
        value = _load_yaml(raw) if raw.strip() else ""
    except yaml.YAMLError as err:
        msg = f"--set {key}: cannot parse value {raw!r}"
        raise ConfigError(msg) from err
    if isinstance(value, str) and _NON_FINITE.fullmatch(value.strip()):
        value = float(value)  # --set k=nan: refused as not finite, naming the key
    return parts, value


def apply_override(data: dict[str, Any], parts: list[str], value: Any) -> None:
    """Set ``data[p0][p1]... = value``, creating missing sections (unknown ones fail later)."""
    node = data
    for i, part in enumerate(parts[:-1]):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            dotted = ".".join(parts[: i + 1])
            msg = f"--set {'.'.join(parts)}: {dotted} is a value, not a section"
            raise ConfigError(msg)
        node = child
    node[parts[-1]] = value


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Load the built-in defaults, then the YAML file ``path`` (if any), then ``--set`` items.

    Raises:
        ConfigError: unreadable file, bad YAML, unknown key, wrong type, out-of-range or
            non-finite value; the message names the file and the dotted key.
    """
    data: dict[str, Any] = {}
    source = "config"
    if path is not None:
        source = str(path)
        data = read_yaml(path)
    for item in overrides or []:
        parts, value = parse_override(item)
        apply_override(data, parts, value)
    if overrides:
        source = f"{source} with --set"
    return config_from_dict(data, source)


def config_to_dict(cfg: Config) -> dict[str, Any]:
    """The configuration as plain builtins (for ``flight.json`` and ``config show``)."""
    out: dict[str, Any] = msgspec.to_builtins(cfg)
    return out
