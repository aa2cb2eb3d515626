"""Which implementation of the matcher's inner loops runs: compiled (numba) or numpy.

``scanmatch.kernel`` chooses: ``numba`` (:mod:`kernel_numba`, the flight's default when
numba imports), ``numpy`` (:mod:`kernel_numpy`, the reference: no compiler, several times
slower) or ``auto`` (numba when it imports and compiles, else numpy). Both give the same
poses to rounding (tested), so the choice is one of speed only.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import structlog

from mkflight.errors import ConfigError
from mkflight.scanmatch import kernel_numpy
from mkflight.scanmatch.kernel_numpy import (
    CONSTANT_PARAMS,
    N_GEOMETRY_PARAMS,
    N_HAT_OUT,
    N_PARAMS,
    N_STATE,
    N_TRACK_OUT,
    N_TRACK_PARAMS,
    BoolArray,
    FloatArray,
    IntArray,
)
from mkflight.urg.replies import BlockDecoder

KernelName = Literal["auto", "numba", "numpy"]
#: ``kernel_numba.track_step``'s signature: points, keyframe rows, state, params, line
#: half-widths, output, prior pose, dt -> the new keyframe's rows.
TrackStep = Callable[
    [
        FloatArray,
        FloatArray,
        FloatArray,
        FloatArray,
        IntArray,
        FloatArray,
        tuple[float, float, float],
        float,
    ],
    FloatArray,
]
#: ``kernel_scan.scan_geometry``'s signature: ranges, hat start, stop and valid beams
#: needed, scan start and stop, the scan beams' cosines and sines, cos and sin of pitch
#: and roll, cos pitch * cos roll, parameters, the hat's output -> the level points.
ScanGeometry = Callable[
    [
        FloatArray,
        int,
        int,
        int,
        int,
        int,
        FloatArray,
        FloatArray,
        float,
        float,
        float,
        float,
        float,
        FloatArray,
        FloatArray,
    ],
    FloatArray,
]
log = structlog.get_logger("mkflight.scanmatch")


@dataclass(frozen=True, slots=True)
class Kernel:
    """One implementation: its name and its functions (as in :mod:`kernel_numpy`).

    ``track_step``: a whole scan of the keyframe matcher in one call; ``beam_points``: a
    log's beams to points in one call; ``scan_geometry``: a URG scan's hat height and level
    points in one call (:mod:`kernel_scan`); ``scan_blocks``: a URG scan's SCIP data
    blocks checked and decoded in one call (:mod:`mkflight.urg.kernel_numba`) (compiled
    kernel only; None: the callers take their Python paths, with the same results).
    """

    name: Literal["numba", "numpy"]
    reference_rows: Callable[[FloatArray, IntArray, float, float, float], FloatArray]
    icp_solve: Callable[[FloatArray, FloatArray, FloatArray, FloatArray], FloatArray]
    track_step: TrackStep | None = None
    beam_points: Callable[[FloatArray, BoolArray, FloatArray], FloatArray] | None = None
    scan_geometry: ScanGeometry | None = None
    scan_blocks: BlockDecoder | None = None


NUMPY = Kernel("numpy", kernel_numpy.reference_rows, kernel_numpy.icp_solve)


def warm_up(kernel: Kernel) -> None:
    """Run each function the flight calls once on a small square room (none compiles in flight).

    Nor does any load from numba's cache in flight. ``beam_points`` is for logs only: it
    loads at its first call (``mkflight scanmatch``), not at every start of the daemon.
    """
    t = np.linspace(-1.0, 1.0, 40)
    x = np.concatenate((np.full(40, 2.0), t * 2.0))
    y = np.concatenate((t * 2.0, np.full(40, 2.0)))
    pts = np.ascontiguousarray(np.stack((x, y), axis=1))
    ref = kernel.reference_rows(pts, np.array([1, 2, 4], dtype=np.int64), 0.1, 0.5, 0.03)
    params = np.array(
        [5, 0.5, 0.2, 0.9, 0.05, 1e-4, 1e-4, 3, 0.2, 0.01, *CONSTANT_PARAMS], dtype=np.float64
    )
    assert params.shape == (N_PARAMS,)
    kernel.icp_solve(pts, ref, np.array([0.01, 0.0, 0.0]), params)
    if kernel.track_step is not None:
        # ICP tuning, then the keyframe policy (kernel_numpy.P_MIN_MATCHED_FRACTION on)
        policy = [0.1, 0.05, 0.1, 0.1745, 3.0, 1.0, 0.1, 0.5, 0.03]
        track = np.array([*params, *policy], dtype=np.float64)
        assert track.shape == (N_TRACK_PARAMS,)
        state, out = np.zeros(N_STATE), np.zeros(N_TRACK_OUT)
        windows = np.array([1, 2, 4], dtype=np.int64)
        kernel.track_step(pts, ref, state, track, windows, out, (0.01, 0.0, 0.0), 0.1)
    if kernel.scan_geometry is not None:
        # a floor 0.6 m down under 20 hat beams, then the square room's walls
        ranges = np.concatenate((np.linspace(0.64, 0.66, 20), np.hypot(x, y)))
        angles = np.arctan2(y, x)
        geometry = np.array([0.02, 4.0, 8, 0.5, 0.03, 0.05, -0.1, 0.05, 0.05, 0.8, 0.02, 5.6, 1.5])
        assert geometry.shape == (N_GEOMETRY_PARAMS,)
        hat_out = np.zeros(N_HAT_OUT)
        c, s = math.cos(0.01), math.sin(0.01)
        cos_b, sin_b = np.cos(angles), np.sin(angles)
        kernel.scan_geometry(
            ranges, 0, 20, 8, 20, 100, cos_b, sin_b, c, s, c, s, c * c, geometry, hat_out
        )
    if kernel.scan_blocks is not None:
        # two blocks of SCIP characters with their sums ('0' + 6 bits of the byte sum)
        block = b"0" * 64
        line = block + bytes(((sum(block) & 0x3F) + 0x30,))
        kernel.scan_blocks(line + b"\n" + line, 3)


@functools.cache
def _compiled() -> Kernel | None:
    """The numba kernel, compiled and run once; None when numba is missing or fails."""
    try:
        from mkflight.scanmatch import kernel_numba, kernel_scan
        from mkflight.urg import kernel_numba as urg_kernel

        kernel = Kernel(
            "numba",
            kernel_numba.reference_rows,
            kernel_numba.icp_solve,
            kernel_numba.track_step,
            kernel_numba.beam_points,
            kernel_scan.scan_geometry,
            urg_kernel.scan_blocks,
        )
        warm_up(kernel)
    except Exception as err:  # not installed, no cache directory, a compiler error
        log.warning("scan matcher: numba unusable, the numpy kernel runs", error=repr(err))
        return None
    return kernel


def load_kernel(name: KernelName) -> Kernel:
    """The kernel ``name`` asks for (``auto``: numba when it works, else numpy).

    Raises:
        ConfigError: ``numba`` was asked for and numba is not installed or fails.
    """
    if name == "numpy":
        return NUMPY
    compiled = _compiled()
    if compiled is not None:
        return compiled
    if name == "numba":
        msg = "scanmatch.kernel: numba is not installed or cannot compile (pip install numba)"
        raise ConfigError(msg)
    return NUMPY
