"""A flight folder written from a known airframe, for the identification and tune tests.

The FC's angle is computed by superposing exact step responses of delay + first-order lag
(independently of :mod:`mkflight.analysis.attitude_fit`'s recursion); the accelerometer
reads the thrust along body z plus body-frame biases and white vibration; the gas is the
flight's feed-forward for the airframe's true hover gas. Times jitter like the FC's loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from mkflight.config import Config
from mkflight.logs.events import EventsWriter
from mkflight.logs.flight_json import new_flight_info, write_flight_json
from mkflight.logs.schema import Step
from mkflight.logs.table4 import Table4Row, Table4Writer

PERIOD_S = 0.053248
G_MPS2 = 9.81


@dataclass(frozen=True, slots=True)
class Airframe:
    """The truth a synthetic flight is made of."""

    delay_s: float = 0.12
    tau_s: float = 0.1
    fc_counts_per_rad: float = 100.0
    hover_gas: float = 95.0  # at the config's hover_voltage_v, in the flight's model
    battery_v: float = 12.0
    vibration_mps2: tuple[float, float, float] = (0.2, 0.15, 0.1)
    bias_mps2: tuple[float, float, float] = (0.05, -0.08, 0.1)
    offset_rad: tuple[float, float] = (0.01, -0.005)
    angle_noise_rad: float = 0.002
    excite_rad: float = 0.05  # square-wave amplitude of the commanded angle
    dwell_s: float = 1.5


def step_responses(t_s: np.ndarray, cmd: np.ndarray, delay_s: float, tau_s: float) -> np.ndarray:
    """The lag's output at ``t_s`` for ``cmd`` held from each ``t_s`` on, delayed."""
    steps = np.diff(cmd, prepend=0.0)
    age = t_s[:, None] - (t_s[None, :] + delay_s)  # row j, switch k
    response = np.where(age >= 0.0, 1.0 - np.exp(-np.maximum(age, 0.0) / tau_s), 0.0)
    out: np.ndarray = response @ steps
    return out


def _step(t_s: float, vz_up_mps: float, gas_counts: int, battery_v: float, phase: str) -> Step:
    """The step event of a flight whose clock starts at 1 s."""
    return Step(
        t_ns=1_000_000_000 + round(t_s * 1e9),
        height_m=0.6,
        vz_up_mps=vz_up_mps,
        gas_counts=gas_counts,
        battery_v=battery_v,
        phase=phase,
        action="NONE",
    )


def write_flight(
    folder: Path,
    airframe: Airframe | None = None,
    *,
    seconds: float = 36.0,
    seed: int = 0,
    cfg: Config | None = None,
    hold: bool = True,
) -> Path:
    """Write a flight folder: 1 s handshake, 3 s take-off, HOLD, the last 2 s LAND."""
    a = airframe or Airframe()
    cfg = cfg or Config()
    rng = np.random.default_rng(seed)
    n = int(seconds / PERIOD_S)
    t = np.arange(n) * PERIOD_S + rng.uniform(0.0, 0.004, n)
    phase = np.full(n, "HOLD" if hold else "TAKEOFF", dtype="U16")
    phase[t < 4.0] = "TAKEOFF"
    phase[t < 1.0] = "HANDSHAKE"
    phase[t > seconds - 2.0] = "LAND"
    # Commanded angles: a square wave per axis (the roll one shifted), zero before take-off.
    cmd = np.empty((2, n))
    for axis in range(2):
        level = np.where(((t + axis * a.dwell_s / 2) // a.dwell_s) % 2 == 0, 1.0, -1.0)
        cmd[axis] = np.where(phase == "HANDSHAKE", 0.0, a.excite_rad * level)
    signs = (cfg.mk.signs.nick, cfg.mk.signs.roll)
    counts = np.array(
        [np.clip(np.round(cmd[i] * signs[i] * cfg.mk.counts_per_rad), -127, 127) for i in (0, 1)]
    )
    flown = counts / (np.array(signs)[:, None] * a.fc_counts_per_rad)  # the FC's reading
    angle = np.array(
        [
            step_responses(t, flown[i], a.delay_s, a.tau_s)
            + a.offset_rad[i]
            + rng.normal(0.0, a.angle_noise_rad, n)
            for i in (0, 1)
        ]
    )
    tilt = np.cos(angle[0]) * np.cos(angle[1])
    vib = rng.normal(0.0, 1.0, (3, n)) * np.array(a.vibration_mps2)[:, None]
    acc = np.array([a.bias_mps2[0] + vib[0], a.bias_mps2[1] + vib[1], vib[2]])
    acc[2] += a.bias_mps2[2] - G_MPS2 / tilt
    hv = cfg.control.hover_voltage_v
    gas = np.round(a.hover_gas * hv / a.battery_v / tilt + rng.normal(0.0, 2.0, n))

    folder.mkdir(parents=True)
    write_flight_json(folder, new_flight_info(datetime(2026, 1, 1, tzinfo=UTC), cfg))
    t4, events = Table4Writer(folder), EventsWriter(folder)
    try:
        for k in range(n):
            t4.write_row(
                Table4Row(
                    float(angle[0, k]),
                    float(angle[1, k]),
                    0.0,
                    float(acc[0, k]),
                    float(acc[1, k]),
                    float(acc[2, k]),
                    int(counts[0, k]),
                    int(counts[1, k]),
                    0,
                    0,
                    0,
                    0,
                    200,
                    k + 1,
                )
            )
            vz_up_mps = round(float(rng.normal(0.0, 0.02)), 4)
            events.write(_step(t[k], vz_up_mps, int(gas[k]), a.battery_v, str(phase[k])))
    finally:
        t4.close()
        events.close()
    return folder
