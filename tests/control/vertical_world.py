"""A 1-D vertical vehicle for the descent tests: thrust from gas, drag, a landing gear.

A test double, deliberately simpler than ``mkflight.sim``: a point mass with thrust
``m g (gas / hover)`` through a motor lag, linear drag, a spring-damper floor contact
(stops a 0.3 m/s touchdown in ~60 ms, or instantly with ``instant_floor``), and an
accelerometer that reads the true acceleration plus white noise. Everything up positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

G = 9.81
SUBSTEP_S = 0.001
STEP_NS = 53_248_000


@dataclass
class VerticalWorld:
    """The vehicle's true state and its sensors."""

    height_m: float = 0.6
    vz_mps: float = 0.0
    hover_gas: float = 100.0
    thrust_tau_s: float = 0.05
    drag_per_s: float = 0.3
    noise_mps2: float = 0.2
    disturbance_mps2: float = 0.0
    instant_floor: bool = False
    seed: int = 0
    thrust_ratio: float = 1.0
    acc_mps2: float = 0.0
    touchdowns: list[float] = field(default_factory=list)
    on_floor: bool = False
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def fly(self, gas: float, seconds: float) -> None:
        """Fly ``gas`` for ``seconds`` (1 ms sub-steps)."""
        for _ in range(round(seconds / SUBSTEP_S)):
            target = max(gas, 0.0) / self.hover_gas
            self.thrust_ratio += (target - self.thrust_ratio) * (
                1.0 - math.exp(-SUBSTEP_S / self.thrust_tau_s)
            )
            a = G * (self.thrust_ratio - 1.0) - self.drag_per_s * self.vz_mps
            a += self.disturbance_mps2
            if self.height_m <= 0.0:  # on the gear
                if not self.on_floor and self.vz_mps < -0.05:
                    self.touchdowns.append(-self.vz_mps)
                self.on_floor = True
                if self.instant_floor:
                    self.vz_mps = 0.0
                    self.height_m = 0.0
                    a = max(a, 0.0)
                else:
                    a += -4000.0 * self.height_m - 120.0 * self.vz_mps
            elif self.height_m > 0.01:
                self.on_floor = False
            if self.height_m <= 0.0 and a < 0.0 and self.vz_mps >= 0.0:
                a = 0.0  # resting: the floor holds it
            self.vz_mps += a * SUBSTEP_S
            self.height_m += self.vz_mps * SUBSTEP_S
            self.acc_mps2 = a

    def accel(self) -> float:
        """What the FC's accelerometer reads now (level, up, bias removed)."""
        return self.acc_mps2 + float(self.rng.normal(0.0, self.noise_mps2))
