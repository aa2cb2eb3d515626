"""The matcher's two inner loops compiled by numba: the arithmetic of :mod:`kernel_numpy`.

Why a compiler: numpy pays about a microsecond per call on arrays of a few hundred
points, and one ICP iteration is some forty calls, so a pure numpy matcher spends most of
a scan in call overhead (measured: 2-6 ms a scan here, several times CSM's C). Written as
loops and compiled, the same iterations cost tens of microseconds. numba compiles to
machine code through LLVM on the target itself (it ships aarch64 wheels), needs no C
toolchain, and caches the machine code on disk (``cache=True``: next to this file, or in
``$NUMBA_CACHE_DIR``), so only the first start on a machine pays the compilation.

The functions mirror :mod:`kernel_numpy` statement by statement (same formulas, same
order of operations, same tie-breaking: the first minimum wins), so the poses agree to
rounding; a test runs both on the same scans. The 3x3 eigen-decomposition is a cyclic
Jacobi sweep (Golub & Van Loan, Matrix Computations, 4th ed., Algorithm 8.5.3) instead of
LAPACK's, which numba could reach only through scipy: the update and the structural
information do not depend on the order or the signs of the eigenvectors.

Importing this module compiles nothing; the first call of each function compiles it (or
loads it from the cache): :func:`warm_up` does that before a flight.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mkflight.scanmatch.kernel_numpy import (
    N_RESULTS,
    P_DEGENERACY_THRESHOLD,
    P_DEGENERATE_DISTANCE_FACTOR,
    P_GATE_M,
    P_KEEP_FRACTION,
    P_KEYFRAME_ANGLE_RAD,
    P_KEYFRAME_DISTANCE_M,
    P_MAX_GAP_M,
    P_MAX_ITERATIONS,
    P_MAX_LINE_RMS_M,
    P_MAX_PREDICTION_DT_S,
    P_MAX_RMS_M,
    P_MIN_CHORD_M,
    P_MIN_EIGENVALUE,
    P_MIN_GATE_M,
    P_MIN_LEVER2_M2,
    P_MIN_MATCHED_FRACTION,
    P_MIN_MATCHES,
    P_NOISE_FLOOR,
    P_ROBUST_SCALE_M,
    P_SHRINK,
    P_SHRINK_BELOW_M,
    P_SHRINK_BELOW_RAD,
    P_STEP_TOL_M,
    P_STEP_TOL_RAD,
    R_CONVERGED,
    R_FAILED,
    R_INLIERS,
    R_ITERATIONS,
    R_MIN_INFORMATION,
    R_RMS,
    R_TH,
    R_X,
    R_Y,
    S_HAS_VELOCITY,
    S_INCREMENT_X,
    S_KF_X,
    S_VELOCITY_X,
    S_X,
    T_CONVERGED,
    T_DEGENERATE,
    T_HANDLED,
    T_ITERATIONS,
    T_MATCH_X,
    T_MATCHED_FRACTION,
    T_MIN_INFORMATION,
    T_N_POINTS,
    T_NEW_KEYFRAME,
    T_RMS,
    T_VALID,
    T_X,
    BoolArray,
    FloatArray,
    IntArray,
)

_JACOBI_SWEEPS = 12
#: A squared length this far (relative) from a squared limit decides a length comparison.
_SQUARE_MARGIN = 1e-9
#: Points beyond this (m) are left to the Python path: no sum of them can overflow.
_LARGEST_COORDINATE_M = 1e150
#: Steps of the linear search from a nearby position before bisection takes over.
_MAX_LOCAL_STEPS = 8


@njit(cache=True, error_model="numpy", inline="always")
def _hypot_above(dx: float, dy: float, length_m: float, or_equal: bool) -> bool:
    """``math.hypot(dx, dy) > length_m`` (``>=`` when ``or_equal``), hypot only near the tie.

    The squared length decides when it is more than :data:`_SQUARE_MARGIN` (relative)
    from the squared limit: its rounding (a few 1e-16) and hypot's (under 1 ulp) cannot
    cross that, so the answer is hypot's to the bit. Limits outside 1e-100..1e100 (where
    a square could underflow or overflow) and NaN always take hypot.
    """
    if 1e-100 < length_m < 1e100:
        d2 = dx * dx + dy * dy
        l2 = length_m * length_m
        if d2 > l2 * (1.0 + _SQUARE_MARGIN):
            return True
        if d2 < l2 * (1.0 - _SQUARE_MARGIN):
            return False
    d = math.hypot(dx, dy)
    return d >= length_m if or_equal else d > length_m


@njit(cache=True, error_model="numpy")
def fit_lines(
    x: FloatArray,
    y: FloatArray,
    half_windows: IntArray,
    min_chord_m: float,
    max_gap_m: float,
    max_rms_m: float,
) -> FloatArray:
    """:func:`kernel_numpy.fit_lines`, as loops."""
    n = x.shape[0]
    out = np.full((n, 5), np.nan)
    cx = np.zeros(n + 1)
    cy = np.zeros(n + 1)
    cxx = np.zeros(n + 1)
    cxy = np.zeros(n + 1)
    cyy = np.zeros(n + 1)
    cbig = np.zeros(n)  # cbig[i]: jump edges among the first i gaps
    for i in range(n):
        cx[i + 1] = cx[i] + x[i]
        cy[i + 1] = cy[i] + y[i]
        cxx[i + 1] = cxx[i] + x[i] * x[i]
        cxy[i + 1] = cxy[i] + x[i] * y[i]
        cyy[i + 1] = cyy[i] + y[i] * y[i]
    for i in range(n - 1):
        big = 1.0 if _hypot_above(x[i + 1] - x[i], y[i + 1] - y[i], max_gap_m, False) else 0.0
        cbig[i + 1] = cbig[i] + big
    chosen = np.zeros(n, dtype=np.bool_)
    last = half_windows[-1]
    for w in half_windows:
        if 2 * w + 1 > n:
            break
        m = 2 * w + 1
        for lo in range(n - 2 * w):
            mid = lo + w
            if chosen[mid]:
                continue
            hi = lo + m
            if cbig[hi - 1] - cbig[lo] != 0:
                continue
            mx = (cx[hi] - cx[lo]) / m
            my = (cy[hi] - cy[lo]) / m
            sxx = (cxx[hi] - cxx[lo]) / m - mx * mx
            sxy = (cxy[hi] - cxy[lo]) / m - mx * my
            syy = (cyy[hi] - cyy[lo]) / m - my * my
            half_tr = 0.5 * (sxx + syy)
            disc = math.sqrt(max(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
            if not half_tr - disc <= max_rms_m * max_rms_m:
                continue
            # (a chord of finite points is >= 0: no test when the shortest is 0, as for
            # sparse lasers; non-finite windows failed the RMS test above)
            if (
                w != last
                and min_chord_m > 0.0
                and not _hypot_above(x[hi - 1] - x[lo], y[hi - 1] - y[lo], min_chord_m, True)
            ):
                continue
            phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
            off = abs(math.cos(phi) * (y[mid] - my) - math.sin(phi) * (x[mid] - mx))
            if not off <= max_rms_m:
                continue
            out[mid, 0] = mx
            out[mid, 1] = my
            out[mid, 2] = -math.sin(phi)
            out[mid, 3] = math.cos(phi)
            out[mid, 4] = 1.0
            chosen[mid] = True
    return out


@njit(cache=True, error_model="numpy")
def reference_rows(
    pts: FloatArray,
    half_windows: IntArray,
    min_chord_m: float,
    max_gap_m: float,
    max_rms_m: float,
) -> FloatArray:
    """:func:`kernel_numpy.reference_rows`, as loops."""
    lines = fit_lines(pts[:, 0], pts[:, 1], half_windows, min_chord_m, max_gap_m, max_rms_m)
    n = lines.shape[0]
    m = 0
    for i in range(n):
        if lines[i, 4] == 1.0:
            m += 1
    bearing = np.empty(m)
    index = np.empty(m, dtype=np.int64)
    k = 0
    for i in range(n):
        if lines[i, 4] == 1.0:
            bearing[k] = math.atan2(lines[i, 1], lines[i, 0])
            index[k] = i
            k += 1
    # A laser's sweep leaves the centres in bearing order nearly always: then the stable
    # sort's answer is the identity, found in one pass (a NaN or a descent: the sort).
    in_order = True
    for k in range(1, m):
        if not bearing[k] >= bearing[k - 1]:
            in_order = False
            break
    order = np.arange(m) if in_order else np.argsort(bearing, kind="mergesort")
    rows = np.empty((7, m))
    for k in range(m):
        i = index[order[k]]
        b = bearing[order[k]]
        rows[0, k] = b
        for r in range(4):
            rows[r + 1, k] = lines[i, r]
        rows[5, k] = math.cos(b)
        rows[6, k] = math.sin(b)
    return rows


@njit(cache=True, error_model="numpy")
def _eigh3(a: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues and eigenvectors (columns) of a symmetric 3x3 matrix by Jacobi rotations."""
    d = a.copy()
    v = np.eye(3)
    for _ in range(_JACOBI_SWEEPS):
        off = d[0, 1] ** 2 + d[0, 2] ** 2 + d[1, 2] ** 2
        if off == 0.0 or off < 1e-36 * (d[0, 0] ** 2 + d[1, 1] ** 2 + d[2, 2] ** 2):
            break
        for p in range(2):
            for q in range(p + 1, 3):
                if d[p, q] == 0.0:
                    continue
                theta = (d[q, q] - d[p, p]) / (2.0 * d[p, q])
                t = math.copysign(1.0, theta) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):
                    dkp, dkq = d[k, p], d[k, q]
                    d[k, p] = c * dkp - s * dkq
                    d[k, q] = s * dkp + c * dkq
                for k in range(3):
                    dpk, dqk = d[p, k], d[q, k]
                    d[p, k] = c * dpk - s * dqk
                    d[q, k] = s * dpk + c * dqk
                for k in range(3):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    return np.array([d[0, 0], d[1, 1], d[2, 2]]), v


@njit(cache=True, error_model="numpy", inline="always")
def _bisect(sorted_values: FloatArray, m: int, value: float) -> int:
    """First index whose value is >= ``value`` (``np.searchsorted``, side left)."""
    lo, hi = 0, m
    while lo < hi:
        mid = (lo + hi) >> 1
        if sorted_values[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, error_model="numpy", inline="always")
def _before(ux: float, uy: float, qx: float, qy: float) -> int:
    """1: the ray ``u`` lies before the point's bearing, 0: not, -1: cannot tell here.

    Within 90 degrees of each other, ``bearing(u) < bearing(q)`` is ``u x q > 0``: a
    cross product instead of an arctangent; beyond, the caller bisects on the angle.
    """
    if ux * qx + uy * qy <= 0.0:
        return -1
    if qx < 0.0 and ux < 0.0 and (qy >= 0.0) != (uy >= 0.0):
        return -1  # on either side of the +-180 degree seam: the order of the angles flips
    return 1 if ux * qy - uy * qx > 0.0 else 0


@njit(cache=True, error_model="numpy", inline="always")
def _position(ref: FloatArray, qx: float, qy: float, start: int) -> int:
    """The first centre whose bearing is not before the point's (bisection's answer).

    From ``start`` (a nearby position; -1: none) by a few cross products; by bisection on
    the point's bearing when there is no start, it is far, or the angles are too far
    apart for the cross product.
    """
    m = ref.shape[1]
    if start >= 0:
        up = start
        for _ in range(_MAX_LOCAL_STEPS):
            if up < m:
                ahead = _before(ref[5, up], ref[6, up], qx, qy)
                if ahead < 0:
                    break
                if ahead == 1:
                    up += 1
                    continue
            if up > 0:
                behind = _before(ref[5, up - 1], ref[6, up - 1], qx, qy)
                if behind < 0:
                    break
                if behind == 0:
                    up -= 1
                    continue
            return up
    return _bisect(ref[0], m, math.atan2(qy, qx))


@njit(cache=True, error_model="numpy", inline="always")
def _visit(
    ref: FloatArray, qx: float, qy: float, rho2: float, k: int, best: int, best_d2: float
) -> tuple[bool, int, float]:
    """One step of a walk of :func:`_nearest`: ``(walk goes on, best, best_d2)`` after centre k."""
    ux, uy = ref[5, k], ref[6, k]
    cross = qx * uy - qy * ux
    bound2 = cross * cross if qx * ux + qy * uy > 0.0 else rho2
    if bound2 > best_d2:
        return False, best, best_d2
    dx = qx - ref[1, k]
    dy = qy - ref[2, k]
    d2 = dx * dx + dy * dy
    if d2 < best_d2:
        return True, k, d2
    return True, best, best_d2


@njit(cache=True, error_model="numpy", inline="always")
def _nearest(ref: FloatArray, qx: float, qy: float, gate_m: float, hint: IntArray, i: int) -> int:
    """Index of the reference centre nearest to ``(qx, qy)`` within the gate, or -1.

    The centres are sorted by bearing; two walks start at the point's own bearing, one
    each way (round the ends: a 360-degree scan). A centre whose bearing is ``delta`` from
    the point's is at least ``rho * sin(delta)`` away while ``delta`` < 90 degrees (the
    point's distance from the centre's ray, ``|q x u|`` with u the ray's unit vector) and
    at least ``rho`` beyond; that bound grows along a walk, which stops once it exceeds
    the best squared distance so far. The walks take turns, so the best found by one
    shortens the other. The result is the exact nearest centre, as a KD-tree finds it,
    in a few steps.
    """
    m = ref.shape[1]
    rho2 = qx * qx + qy * qy
    up = hint[i]
    if up < 0 and i > 0:  # first iteration: the scan's previous point's, a step away
        up = hint[i - 1]
    up = _position(ref, qx, qy, up)
    hint[i] = up
    down = up - 1
    best = -1
    best_d2 = gate_m * gate_m
    up_open = True
    down_open = True
    for _ in range(m):
        if up_open:
            up_open, best, best_d2 = _visit(
                ref, qx, qy, rho2, up if up < m else up - m, best, best_d2
            )
            up += 1
        if down_open:
            k = down if down >= 0 else down + m
            down_open, best, best_d2 = _visit(ref, qx, qy, rho2, k, best, best_d2)
            down -= 1
        if not (up_open or down_open):
            break
    return best


@njit(cache=True, error_model="numpy")
def _pairs(
    px: FloatArray,
    py: FloatArray,
    ref: FloatArray,
    pose: FloatArray,
    gate_m: float,
    work: FloatArray,
    hint: IntArray,
) -> int:
    """Rows ``(r, nx, ny, mx, my)`` of the pairs into ``work``; their number.

    ``hint``: each point's bearing position in the reference from the last iteration (-1:
    none yet), updated.
    """
    c, s = math.cos(pose[2]), math.sin(pose[2])
    k = 0
    for i in range(px.shape[0]):
        qx = c * px[i] - s * py[i] + pose[0]
        qy = s * px[i] + c * py[i] + pose[1]
        best = _nearest(ref, qx, qy, gate_m, hint, i)
        if best >= 0:
            nx, ny = ref[3, best], ref[4, best]
            work[0, k] = nx * (qx - ref[1, best]) + ny * (qy - ref[2, best])
            work[1, k] = nx
            work[2, k] = ny
            work[3, k] = qx
            work[4, k] = qy
            k += 1
    return k


@njit(cache=True, error_model="numpy")
def _trim(work: FloatArray, k: int, keep_fraction: float) -> int:
    """Keep the ``keep_fraction`` of the ``k`` pairs with the smallest residuals, in order."""
    keep = int(k * keep_fraction)
    if keep >= k or keep < 1:
        return k
    cut = np.partition(np.abs(work[0, :k]), keep - 1)[keep - 1]
    n = 0
    for i in range(k):
        if abs(work[0, i]) <= cut:
            for row in range(5):
                work[row, n] = work[row, i]
            n += 1
    return n


@njit(cache=True, error_model="numpy")
def _normal_equations(
    work: FloatArray, n_in: int, robust_scale_m: float, h: FloatArray, g: FloatArray
) -> tuple[float, float]:
    """``h = J^T W J``, ``g = J^T W r`` of the pairs; returns ``(sum r^2, sum |m|^2)``.

    The 3x3 sums are written out so that they stay in registers: the same products in
    the same order as the loop over ``a, b`` (``(j_a w) j_b``), so the same bits.
    """
    c = robust_scale_m
    h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
    g0 = g1 = g2 = 0.0
    rr = 0.0
    ll = 0.0
    for i in range(n_in):
        r, nx, ny, mx, my = work[0, i], work[1, i], work[2, i], work[3, i], work[4, i]
        j2 = ny * mx - nx * my
        wgt = 1.0 / (1.0 + (r * (1.0 / c)) ** 2) if c > 0.0 else 1.0
        a0, a1, a2 = nx * wgt, ny * wgt, j2 * wgt
        h00 += a0 * nx
        h01 += a0 * ny
        h02 += a0 * j2
        h10 += a1 * nx
        h11 += a1 * ny
        h12 += a1 * j2
        h20 += a2 * nx
        h21 += a2 * ny
        h22 += a2 * j2
        g0 += a0 * r
        g1 += a1 * r
        g2 += a2 * r
        rr += r * r
        ll += mx * mx + my * my
    h[0, 0], h[0, 1], h[0, 2] = h00, h01, h02
    h[1, 0], h[1, 1], h[1, 2] = h10, h11, h12
    h[2, 0], h[2, 1], h[2, 2] = h20, h21, h22
    g[0], g[1], g[2] = g0, g1, g2
    return rr, ll


@njit(cache=True, error_model="numpy")
def _structural_information(
    work: FloatArray, n_in: int, coef: FloatArray, floor: float, sinfo: FloatArray
) -> None:
    """``sinfo[e]``: the structural information along eigen-direction e (module doc).

    The mean squared projection of the Jacobian rows on ``coef[:, e]`` (the scaled
    eigenvector), over the rows whose projection exceeds ``floor``; one pass for the
    three directions, each sum in point order.
    """
    s0 = s1 = s2 = 0.0
    c00, c10, c20 = coef[0, 0], coef[1, 0], coef[2, 0]
    c01, c11, c21 = coef[0, 1], coef[1, 1], coef[2, 1]
    c02, c12, c22 = coef[0, 2], coef[1, 2], coef[2, 2]
    for i in range(n_in):
        nx, ny, mx, my = work[1, i], work[2, i], work[3, i], work[4, i]
        j2 = ny * mx - nx * my
        p = c00 * nx + c10 * ny + c20 * j2
        if abs(p) > floor:
            s0 += p * p
        p = c01 * nx + c11 * ny + c21 * j2
        if abs(p) > floor:
            s1 += p * p
        p = c02 * nx + c12 * ny + c22 * j2
        if abs(p) > floor:
            s2 += p * p
    sinfo[0], sinfo[1], sinfo[2] = s0 / n_in, s1 / n_in, s2 / n_in


@njit(cache=True, error_model="numpy")
def _solve_step(work: FloatArray, n_in: int, params: FloatArray, step: FloatArray) -> None:
    """``step[:] = dx, dy, dth, rms, min_information`` (kernel_numpy._solve_step)."""
    h = np.empty((3, 3))
    g = np.empty(3)
    rr, ll = _normal_equations(work, n_in, params[P_ROBUST_SCALE_M], h, g)
    lever2 = ll / n_in
    lever = math.sqrt(lever2) if lever2 > params[P_MIN_LEVER2_M2] else 1.0
    scale = np.array([1.0, 1.0, 1.0 / lever])
    hs = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            hs[a, b] = h[a, b] * (scale[a] * scale[b]) / n_in
    evals, evecs = _eigh3(hs)
    coef = np.empty((3, 3))
    for a in range(3):
        for e in range(3):
            coef[a, e] = evecs[a, e] * scale[a]
    sinfo = np.empty(3)
    _structural_information(work, n_in, coef, params[P_NOISE_FLOOR], sinfo)
    u = np.zeros(3)
    info_min = math.inf
    for e in range(3):
        info_min = min(info_min, sinfo[e])
        if sinfo[e] > params[P_DEGENERACY_THRESHOLD] and evals[e] > params[P_MIN_EIGENVALUE]:
            proj = 0.0
            for a in range(3):
                proj += evecs[a, e] * (g[a] * scale[a] / n_in)
            for a in range(3):
                u[a] += evecs[a, e] * (-proj / evals[e])
    step[0], step[1], step[2] = u[0], u[1], u[2] / lever
    step[3], step[4] = math.sqrt(rr / n_in), info_min


@njit(cache=True, error_model="numpy")
def icp_solve(
    pts: FloatArray, ref: FloatArray, guess: FloatArray, params: FloatArray
) -> FloatArray:
    """:func:`kernel_numpy.icp_solve`, as loops."""
    out = np.zeros(N_RESULTS)
    out[R_RMS] = math.nan
    pose = guess.copy()
    gate_m = params[P_GATE_M]
    px = pts[:, 0]
    py = pts[:, 1]
    work = np.empty((5, px.shape[0]))
    hint = np.full(px.shape[0], -1, dtype=np.int64)  # each point's bearing position
    step = np.empty(5)
    for _ in range(int(params[P_MAX_ITERATIONS])):
        out[R_ITERATIONS] += 1.0
        k = _pairs(px, py, ref, pose, gate_m, work, hint)
        if k < params[P_MIN_MATCHES]:
            out[R_FAILED] = 1.0
            return out
        n_in = _trim(work, k, params[P_KEEP_FRACTION])
        _solve_step(work, n_in, params, step)
        dx, dy, dth = step[0], step[1], step[2]
        out[R_RMS], out[R_MIN_INFORMATION], out[R_INLIERS] = step[3], step[4], n_in
        c, s = math.cos(dth), math.sin(dth)
        x = dx + c * pose[0] - s * pose[1]
        y = dy + s * pose[0] + c * pose[1]
        pose[0], pose[1] = x, y
        pose[2] = (dth + pose[2] + math.pi) % (2.0 * math.pi) - math.pi
        step_m = math.hypot(dx, dy)
        if step_m < params[P_STEP_TOL_M] and abs(dth) < params[P_STEP_TOL_RAD]:
            out[R_CONVERGED] = 1.0
            break
        if step_m < params[P_SHRINK_BELOW_M] and abs(dth) < params[P_SHRINK_BELOW_RAD]:
            gate_m = max(params[P_MIN_GATE_M], params[P_SHRINK] * gate_m)
    out[R_X], out[R_Y], out[R_TH] = pose[0], pose[1], pose[2]
    return out


# ----- one scan of the keyframe matcher ----------------------------------------------------


@njit(cache=True, error_model="numpy", inline="always")
def _wrap(angle_rad: float) -> float:
    """:func:`kernel_numpy.wrap_angle`."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, error_model="numpy", inline="always")
def _compose(
    a0: float, a1: float, a2: float, b0: float, b1: float, b2: float
) -> tuple[float, float, float]:
    """:func:`~mkflight.scanmatch.geometry.compose` on scalars (the same operations)."""
    c, s = math.cos(a2), math.sin(a2)
    return a0 + c * b0 - s * b1, a1 + s * b0 + c * b1, _wrap(a2 + b2)


@njit(cache=True, error_model="numpy", inline="always")
def _between(
    a0: float, a1: float, a2: float, b0: float, b1: float, b2: float
) -> tuple[float, float, float]:
    """:func:`~mkflight.scanmatch.geometry.between`: the inverse of a, composed with b."""
    c, s = math.cos(a2), math.sin(a2)
    return _compose(-c * a0 - s * a1, s * a0 - c * a1, _wrap(-a2), b0, b1, b2)


@njit(cache=True, error_model="numpy")
def _plain(pts: FloatArray) -> bool:
    """Every coordinate finite and small enough that no sum of them overflows."""
    for i in range(pts.shape[0]):
        for j in range(2):
            if not abs(pts[i, j]) < _LARGEST_COORDINATE_M:
                return False
    return True


@njit(cache=True, error_model="numpy", inline="always")
def _increment(
    state: FloatArray, params: FloatArray, prior: tuple[float, float, float], dt_s: float
) -> tuple[float, float, float]:
    """The motion since the last scan: the prior when finite, else constant velocity.

    ``KeyframeMatcher._predict``'s rules; ``dt_s`` NaN stands for no dt (the last increment).
    """
    if math.isfinite(prior[0]) and math.isfinite(prior[1]) and math.isfinite(prior[2]):
        return prior
    if math.isnan(dt_s):
        return state[S_INCREMENT_X], state[S_INCREMENT_X + 1], state[S_INCREMENT_X + 2]
    if state[S_HAS_VELOCITY] == 0.0 or not 0.0 < dt_s <= params[P_MAX_PREDICTION_DT_S]:
        return 0.0, 0.0, 0.0
    v = S_VELOCITY_X
    return state[v] * dt_s, state[v + 1] * dt_s, state[v + 2] * dt_s


@njit(cache=True, error_model="numpy")
def _match(
    pts: FloatArray,
    kf: FloatArray,
    guess: tuple[float, float, float],
    params: FloatArray,
    out: FloatArray,
) -> None:
    """:func:`~mkflight.scanmatch.icp.match`: the MatchResult's fields into ``out``."""
    if not (math.isfinite(guess[0]) and math.isfinite(guess[1]) and math.isfinite(guess[2])):
        guess = (0.0, 0.0, 0.0)
    n = pts.shape[0]
    out[T_MATCH_X], out[T_MATCH_X + 1], out[T_MATCH_X + 2] = guess
    out[T_VALID] = out[T_DEGENERATE] = out[T_MATCHED_FRACTION] = 0.0
    out[T_ITERATIONS] = out[T_CONVERGED] = out[T_MIN_INFORMATION] = 0.0
    out[T_RMS] = math.nan
    out[T_N_POINTS] = n
    if n < params[P_MIN_MATCHES] or kf.shape[1] < 3:
        return
    res = icp_solve(pts, kf, np.array(guess), params)
    if res[R_FAILED] != 0.0:
        return
    frac = res[R_INLIERS] / n
    rms = res[R_RMS]
    valid = (
        math.isfinite(res[R_X])
        and math.isfinite(res[R_Y])
        and math.isfinite(res[R_TH])
        and res[R_INLIERS] >= params[P_MIN_MATCHES]
        and frac >= params[P_MIN_MATCHED_FRACTION]
        and math.isfinite(rms)
        and rms <= params[P_MAX_RMS_M]
    )
    if valid:
        out[T_MATCH_X], out[T_MATCH_X + 1], out[T_MATCH_X + 2] = res[R_X], res[R_Y], res[R_TH]
        out[T_VALID] = 1.0
        out[T_DEGENERATE] = 1.0 if res[R_MIN_INFORMATION] < params[P_DEGENERACY_THRESHOLD] else 0.0
    out[T_RMS], out[T_MATCHED_FRACTION] = rms, frac
    out[T_ITERATIONS], out[T_CONVERGED] = res[R_ITERATIONS], res[R_CONVERGED]
    out[T_MIN_INFORMATION] = res[R_MIN_INFORMATION]


@njit(cache=True, error_model="numpy")
def _new_keyframe(
    pts: FloatArray, half_windows: IntArray, params: FloatArray, out: FloatArray
) -> FloatArray:
    """The keyframe policy: the scan's line rows when it becomes the keyframe, else (7, 0).

    A new keyframe after ``keyframe_distance_m`` (x the degenerate factor in a degenerate
    scene) or ``keyframe_angle_rad`` from the current one, or after a failed match; only
    when at least 3 lines fit (``geometry.build_reference``'s rule).
    """
    rx, ry, rth = out[T_MATCH_X], out[T_MATCH_X + 1], out[T_MATCH_X + 2]
    factor = params[P_DEGENERATE_DISTANCE_FACTOR] if out[T_DEGENERATE] == 1.0 else 1.0
    limit_m = params[P_KEYFRAME_DISTANCE_M] * factor
    far = math.hypot(rx, ry) > limit_m or abs(rth) > params[P_KEYFRAME_ANGLE_RAD]
    if (far or out[T_VALID] != 1.0) and pts.shape[0] >= 5:
        rows = reference_rows(
            pts, half_windows, params[P_MIN_CHORD_M], params[P_MAX_GAP_M], params[P_MAX_LINE_RMS_M]
        )
        if rows.shape[1] >= 3:
            return rows
    return np.empty((7, 0))


@njit(cache=True, error_model="numpy")
def track_step(
    pts: FloatArray,
    kf: FloatArray,
    state: FloatArray,
    params: FloatArray,
    half_windows: IntArray,
    out: FloatArray,
    prior: tuple[float, float, float],
    dt_s: float,
) -> FloatArray:
    """One scan of :meth:`~mkflight.scanmatch.keyframe.KeyframeMatcher.update`, compiled.

    The prediction (``prior`` when finite, NaN: none; else constant velocity over ``dt_s``,
    NaN: unknown), the match against the keyframe's rows ``kf``, the world pose, the
    keyframe policy (the new keyframe's line rows are returned; (7, 0): no new keyframe)
    and the state update (``state``, ``S_*`` indices, in place), with the same operations
    as the Python path so that the poses are the same to the bit. ``out`` (``T_*``) gets
    the pose and the match's fields; ``out[T_HANDLED]`` is 0 (nothing changed) when a
    point is not finite: the Python path handles such scans.
    """
    out[T_HANDLED] = 0.0
    if not _plain(pts):
        return np.empty((7, 0))
    inc = _increment(state, params, prior, dt_s)
    px, py, pth = state[S_X], state[S_X + 1], state[S_X + 2]
    kx, ky, kth = state[S_KF_X], state[S_KF_X + 1], state[S_KF_X + 2]
    predicted = _compose(px, py, pth, inc[0], inc[1], inc[2])
    guess = _between(kx, ky, kth, predicted[0], predicted[1], predicted[2])
    _match(pts, kf, guess, params, out)
    pose = predicted
    if out[T_VALID] == 1.0:
        pose = _compose(kx, ky, kth, out[T_MATCH_X], out[T_MATCH_X + 1], out[T_MATCH_X + 2])
    rows = _new_keyframe(pts, half_windows, params, out)
    out[T_NEW_KEYFRAME] = 1.0 if rows.shape[1] > 0 else 0.0
    if rows.shape[1] > 0:
        state[S_KF_X], state[S_KF_X + 1], state[S_KF_X + 2] = pose
    step = _between(px, py, pth, pose[0], pose[1], pose[2])
    state[S_INCREMENT_X], state[S_INCREMENT_X + 1], state[S_INCREMENT_X + 2] = step
    if 0.0 < dt_s <= params[P_MAX_PREDICTION_DT_S]:
        v = S_VELOCITY_X
        state[v], state[v + 1], state[v + 2] = step[0] / dt_s, step[1] / dt_s, step[2] / dt_s
        state[S_HAS_VELOCITY] = 1.0
    else:
        state[S_HAS_VELOCITY] = 0.0
    state[S_X], state[S_X + 1], state[S_X + 2] = pose
    out[T_X], out[T_X + 1], out[T_X + 2] = pose
    out[T_HANDLED] = 1.0
    return rows


@njit(cache=True, error_model="numpy")
def beam_points(ranges_m: FloatArray, mask: BoolArray, directions: FloatArray) -> FloatArray:
    """The (M, 2) points ``r * (cos, sin)`` of the beams in ``mask``, in beam order.

    ``directions``: (N, 2) each beam's cosine and sine (computed once per beam layout by
    the caller); the products are those of :func:`~mkflight.scanmatch.geometry.scan_to_points`.
    """
    m = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            m += 1
    out = np.empty((m, 2))
    k = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            out[k, 0] = ranges_m[i] * directions[i, 0]
            out[k, 1] = ranges_m[i] * directions[i, 1]
            k += 1
    return out
