"""The simulated landing gear: a stiff spring-damper on the floor (SPEC §8), pure maths.

The vehicle's floor contact (:func:`mkflight.sim.vehicle.step`) is a vertical spring with
damping, pushing only (a gear cannot pull the vehicle down), plus Coulomb friction on the
floor. Per unit mass, with ``d`` the gear's compression (m, > 0 in contact) and ``v`` the
downward speed:

    F = ω² d + 2 ζ ω v,   ζ = ζ_c while compressing (v > 0), ζ_e while extending,
    ω² = g / gear_sag_m   (so the static compression with the motors off is gear_sag_m).

The rebound (extension) is damped much more than the compression, as in an aircraft's or a
car's shock absorber: the compression is a soft, nearly sinusoidal pulse (ζ_c = 0.3), so a
0.3-0.5 m/s touchdown is stopped over ≈ 40 ms, long enough for the FC's DebugOut (one
sample per ~53 ms) to see it; the heavily damped extension (ζ_e = 6) gives back almost none
of the stored energy, so the vehicle does not bounce even with the thrust near its weight.
Why not one critically damped ζ: with ζ = 1 and a few mm of static compression the stop
takes ~20 ms, and any spring with symmetric damping releases the vehicle upward when the
thrust is near the weight (it then floats away on hover thrust).

The defaults (``VehicleParams.gear_*``): 8 mm static compression with the motors off
(ω = 35 rad/s, 5.6 Hz; at 90 % of the hover thrust it rests 0.8 mm down), friction 0.6.
Touchdowns at 0.3 and 0.5 m/s with the thrust at 0-90 % of the weight: the upward
acceleration peaks at 7-14 m/s² and stays above half of that for 40-46 ms, the downward
speed is below 10 % of the touchdown speed after 35-60 ms and within 5 % for good after
44-72 ms, the gear compresses 6-16 mm and the vehicle never rises again; a 53 ms sampler
sees >= 3 m/s² of it at ~80 % of its phases. The price of the extension damping: the gear
creeps back from a hard landing's compression with a ~0.3 s time constant.

Between two sub-steps the other accelerations (gravity, thrust, drag, gusts) are held, so
the vertical motion in contact is the linear ODE ``e'' + 2 ζ ω e' + ω² e = 0`` about the
equilibrium; :func:`transition` is its exact solution over a sub-step (stable at any step,
the gear's time constants being well under the 5 ms sub-step's accuracy otherwise).
"""

from __future__ import annotations

import math
from typing import Final

GEAR_LEVEL_TAU_S: Final = 0.02  # on the floor the gear levels the vehicle this fast
MIN_TOUCHDOWN_MPS: Final = 0.05  # slower re-contacts (a settling vehicle) are not touchdowns

#: The 2x2 transition ``(e, v) -> (p0 e + p1 v, p2 e + p3 v)`` over one step.
Transition = tuple[float, float, float, float]


def transition(zeta: float, omega_radps: float, h_s: float) -> Transition:
    """The exact transition of ``e'' + 2 ζ ω e' + ω² e = 0`` over ``h_s`` (any ζ >= 0).

    Returns ``(p0, p1, p2, p3)`` with ``e(h) = p0 e + p1 v`` and ``v(h) = p2 e + p3 v``.
    """
    w = omega_radps
    sigma = zeta * w
    decay = math.exp(-sigma * h_s)
    if abs(zeta - 1.0) < 1e-6:  # critical: e = (e0 + (v0 + w e0) t) exp(-w t)
        return (
            decay * (1.0 + w * h_s),
            decay * h_s,
            -decay * w * w * h_s,
            decay * (1.0 - w * h_s),
        )
    if zeta < 1.0:
        wd = w * math.sqrt(1.0 - zeta * zeta)
        co, si = math.cos(wd * h_s), math.sin(wd * h_s) / wd
    else:
        ws = w * math.sqrt(zeta * zeta - 1.0)
        co, si = math.cosh(ws * h_s), math.sinh(ws * h_s) / ws
    return (
        decay * (co + sigma * si),
        decay * si,
        -decay * w * w * si,
        decay * (co - sigma * si),
    )


def crossing_time(gap_m: float, v_mps: float, a_mps2: float, h_s: float) -> float:
    """When, within ``[0, h_s]``, a falling body meets the floor.

    The body is ``-gap_m`` above it (``gap_m <= 0``, z down) and moves at ``v_mps`` with a
    constant ``a_mps2`` (both down +).

    The first root of ``gap + v τ + a τ² / 2 = 0``, in the cancellation-free form.
    """
    disc = max(v_mps * v_mps - 2.0 * a_mps2 * gap_m, 0.0)
    den = v_mps + math.sqrt(disc)
    if den <= 0.0:
        return h_s
    return min(max(-2.0 * gap_m / den, 0.0), h_s)
