"""A URG scan's hat height and level points in one compiled call (numba).

The per-scan geometry of :class:`~mkflight.flight.laser_pipeline.LaserPipeline`: the hat
height of :func:`~mkflight.urg.hat.hat_height` (eq 26 after a median-absolute-deviation
gate) and then the scan beams as level-frame points of
:func:`~mkflight.flight.laser_pipeline.level_points` (floor hits dropped with that height).
In numpy they are some forty calls of a few microseconds each on a few hundred beams, and
run once every 100 ms on caches the sleep in between has cooled: here they are one call.

The numpy functions are the reference and stay the path without numba: these loops make
the same floating-point operations in the same order (the products of the rotation, the
sorted medians, the comparisons), so both give the same numbers to the last bit (tested,
``tests/flight/test_laser_per_scan_references.py``). What is not arithmetic -- the
reasons a height is refused, the attitude's trigonometry -- stays in Python.

Importing this module compiles nothing; the first call compiles it or loads it from
numba's cache (:func:`~mkflight.scanmatch.kernels.warm_up` does that before a flight).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mkflight.scanmatch.kernel_numpy import (
    G_FLOOR_FRACTION,
    G_FLOOR_OFFSET_M,
    G_HAT_INLIER_GATE_M,
    G_HAT_MAX_RANGE_M,
    G_HAT_MAX_SPREAD_M,
    G_HAT_MIN_BEAMS,
    G_HAT_MIN_HEIGHT_M,
    G_HAT_MIN_INLIER_FRACTION,
    G_HAT_MIN_RANGE_M,
    G_HAT_OFFSET_M,
    G_MAD_TO_SIGMA,
    G_MAX_RANGE_M,
    G_MIN_RANGE_M,
    H_CODE,
    H_HEIGHT_M,
    H_SPREAD_M,
    H_USED_BEAMS,
    H_VALID_BEAMS,
    HAT_SKIPPED,
    FloatArray,
)
from mkflight.urg.hat import HAT_DISAGREE, HAT_FEW_VALID, HAT_IMPLAUSIBLE, HAT_SPREAD, HAT_VALID


@njit(cache=True, error_model="numpy", inline="always")
def _median(ordered: FloatArray, n: int) -> float:
    """``mkflight.urg.hat._median`` of ``ordered[:n]``: the middle, or the middle two's mean."""
    half = n // 2
    middle: float = ordered[half]
    if n % 2:
        return middle
    below: float = ordered[half - 1]
    return (below + middle) / 2


@njit(cache=True, error_model="numpy")
def _hat(
    ranges: FloatArray,
    start: int,
    stop: int,
    min_valid: int,
    cpcr: float,
    p: FloatArray,
    out: FloatArray,
) -> None:
    """:func:`~mkflight.urg.hat.hat_height` on ``ranges[start:stop]``, past its attitude checks.

    ``min_valid``: the valid beams it needs (``max(min_beams, ceil(fraction * beams))``);
    ``cpcr``: ``cos(pitch) * cos(roll)``; ``out`` gets the outcome (``H_*``).
    """
    low, high = p[G_HAT_MIN_RANGE_M], p[G_HAT_MAX_RANGE_M]
    good = np.empty(stop - start)
    n_valid = 0
    for i in range(start, stop):
        r = ranges[i]
        if r >= low and r <= high and math.isfinite(r):
            good[n_valid] = r
            n_valid += 1
    out[H_VALID_BEAMS] = n_valid
    out[H_USED_BEAMS] = 0.0
    out[H_SPREAD_M] = math.nan
    out[H_HEIGHT_M] = math.nan
    if n_valid < min_valid or n_valid == 0:
        out[H_CODE] = HAT_FEW_VALID
        return
    good = np.sort(good[:n_valid])
    median = _median(good, n_valid)
    deviation = np.empty(n_valid)
    for i in range(n_valid):
        deviation[i] = abs(good[i] - median)
    ordered = np.sort(deviation)
    mad = _median(ordered, n_valid)
    gate = max(3.0 * p[G_MAD_TO_SIGMA] * mad, p[G_HAT_INLIER_GATE_M])
    if ordered[n_valid - 1] <= gate:
        n_used = n_valid
        inlier_median, inlier_mad = median, mad
    else:
        inliers = np.empty(n_valid)
        n_used = 0
        for i in range(n_valid):
            if deviation[i] <= gate:
                inliers[n_used] = good[i]
                n_used += 1
    out[H_USED_BEAMS] = n_used
    if n_used < max(p[G_HAT_MIN_BEAMS], math.ceil(p[G_HAT_MIN_INLIER_FRACTION] * n_valid)):
        out[H_CODE] = HAT_DISAGREE
        return
    if n_used != n_valid:
        inlier_median = _median(inliers, n_used)
        for i in range(n_used):
            deviation[i] = abs(inliers[i] - inlier_median)
        inlier_mad = _median(np.sort(deviation[:n_used]), n_used)
    spread = p[G_MAD_TO_SIGMA] * inlier_mad
    out[H_SPREAD_M] = spread
    if spread > p[G_HAT_MAX_SPREAD_M]:
        out[H_CODE] = HAT_SPREAD
        return
    height = cpcr * inlier_median - p[G_HAT_OFFSET_M]
    out[H_HEIGHT_M] = height
    out[H_CODE] = HAT_IMPLAUSIBLE if height < p[G_HAT_MIN_HEIGHT_M] else HAT_VALID


@njit(cache=True, error_model="numpy")
def scan_geometry(
    ranges: FloatArray,
    hat_start: int,
    hat_stop: int,
    hat_min_valid: int,
    scan_start: int,
    scan_stop: int,
    cb: FloatArray,
    sb: FloatArray,
    cp: float,
    sp: float,
    cr: float,
    sr: float,
    cpcr: float,
    params: FloatArray,
    hat_out: FloatArray,
) -> FloatArray:
    """The hat height (into ``hat_out``) and the level points of one scan (returned).

    ``ranges[hat_start:hat_stop]`` are the hat beams (``hat_start == hat_stop``: no hat
    height is asked for, ``hat_out[H_CODE]`` is ``HAT_SKIPPED``; ``hat_min_valid``: the
    valid beams it needs), ``ranges[scan_start:
    scan_stop]`` the scan beams, whose directions are ``cb``, ``sb`` (cosine and sine of
    the body angle); ``cp, sp, cr, sr`` the cosine and sine of pitch and roll, ``cpcr``
    ``cp * cr`` as eq 26 takes it. A valid height drops the beams that hit the floor.
    Returns the (M, 2) points ``(x forward, y left)`` in scan order.
    """
    hat_out[H_CODE] = HAT_SKIPPED
    limit = math.nan
    if hat_stop > hat_start:
        _hat(ranges, hat_start, hat_stop, hat_min_valid, cpcr, params, hat_out)
        if hat_out[H_CODE] == HAT_VALID:
            floor_depth = hat_out[H_HEIGHT_M] + params[G_FLOOR_OFFSET_M]
            if math.isfinite(floor_depth):
                limit = params[G_FLOOR_FRACTION] * floor_depth
    floor = not math.isnan(limit)
    low, high = params[G_MIN_RANGE_M], params[G_MAX_RANGE_M]
    n = scan_stop - scan_start
    keep = np.empty(n, dtype=np.bool_)
    m = 0
    minus_sp, cpsr = -sp, cp * sr
    for i in range(n):
        r = ranges[scan_start + i]
        ok = r >= low and r <= high and math.isfinite(r)
        if ok and floor:
            ok = r * (minus_sp * cb[i] + cpsr * sb[i]) < limit
        keep[i] = ok
        m += ok
    points = np.empty((m, 2))
    spsr, minus_cr = sp * sr, -cr
    k = 0
    for i in range(n):
        if keep[i]:
            r = ranges[scan_start + i]
            points[k, 0] = r * (cp * cb[i] + spsr * sb[i])
            points[k, 1] = r * (minus_cr * sb[i])
            k += 1
    return points
