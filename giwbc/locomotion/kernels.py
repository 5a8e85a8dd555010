"""Compiled kernels of the walking controller's tick (issue 37): the swing trajectory's state, the
DCM reference's value and the DCM controller's CoP clipped along its ray, over plain float64 arrays.

Each kernel is the Python code it replaced, written over arrays (``giwbc.util.jit.compiled``: numba,
no ``fastmath``), with the same IEEE operations in the same order, so a rollout is bit for bit what it
was (``min``/``max`` written as the conditions Python's builtins evaluate, NaN included). A kernel
writes into an output array its caller owns: numba boxes a returned tuple of floats slower
(~1.2 µs for six) than the caller reads an array it made (~0.2 µs). Where the Python rounds as
numpy's ``gemv`` does (a fused multiply-add, :mod:`giwbc.locomotion.planar`), the kernel fuses the
same product with LLVM's ``fma``. The uncompiled functions (:func:`giwbc.util.jit.reference`) are
what the tests compare the compiled ones with.
"""

from __future__ import annotations

import math

import numpy as np

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic, overload

from giwbc.locomotion.planar import _ROW, _ROW_T, fma
from giwbc.util.jit import compiled

__all__ = [
    "DCM_COLUMNS", "FUSED_ROWS", "FUSED_ROWS_T", "STEP_FRAME", "STEP_INPUTS", "STEP_OUTPUTS", "SWING_COLUMNS", "clip_cop_along_ray", "dcm_evaluate",
    "fused_multiply_add", "step_adapt", "step_qp_solve", "swing_state", "warm_up",
]

# A swing's table row per coordinate (x, y, z, yaw): the number of quintic pieces (1 or 2), the
# chain's knots (3, the last unused for one piece), then each piece's six coefficients in s = t − knot.
SWING_COLUMNS = 16


@compiled
def swing_state(t: float, table: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = (position, velocity, acceleration)`` of coordinate ``i`` (x, y, z, yaw) of the swing
    whose quintic chains ``table`` holds (:data:`SWING_COLUMNS`), at ``t``: held at rest before the
    first knot (the first piece's start) and after the last (the last piece's end)."""
    for i in range(table.shape[0]):
        n = int(table[i, 0])
        hold = True
        s = 0.0
        piece = 0
        if not t < table[i, 1]:
            piece = -1
            for j in range(n):
                if t <= table[i, 2 + j]:
                    piece = j
                    break
            if piece < 0:
                piece = n - 1
                s = table[i, 1 + n] - table[i, n]
            else:
                s = t - table[i, 1 + piece]
                hold = False
        c = 4 + 6 * piece
        c0, c1, c2, c3, c4, c5 = table[i, c], table[i, c + 1], table[i, c + 2], table[i, c + 3], table[i, c + 4], table[i, c + 5]
        out[i, 0] = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
        if hold:
            out[i, 1] = 0.0
            out[i, 2] = 0.0
        else:
            out[i, 1] = c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))
            out[i, 2] = 2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))


# A DCM reference's table row per CoP segment: duration, start time, initial DCM (x, y), CoP start
# (x, y), CoP end (x, y).
DCM_COLUMNS = 8


@compiled
def dcm_evaluate(t: float, table: np.ndarray, omega: float, out: np.ndarray) -> None:
    """``out = (ξ_ref, ξ̇_ref, p_ref)`` (x, y each) at ``t`` inside the plan ``table``
    (:data:`DCM_COLUMNS`; ``t`` before the plan's end): the segment by ``bisect_right`` over the
    start times, the DCM of its linear CoP ramp in closed form."""
    n = table.shape[0]
    lo, hi = 0, n
    while lo < hi:  # bisect.bisect_right(starts, t), NaN included
        mid = (lo + hi) // 2
        if t < table[mid, 1]:
            hi = mid
        else:
            lo = mid + 1
    i = lo - 1
    i = n - 1 if n - 1 < i else i
    i = 0 if 0 > i else i
    duration, start = table[i, 0], table[i, 1]
    tau = t - start
    tau = 0.0 if 0.0 > tau else tau  # max(t - start, 0.0)
    tau = duration if duration < tau else tau  # min(..., duration)
    growth = math.exp(omega * tau)
    for axis in range(2):
        x0, sx, ex = table[i, 2 + axis], table[i, 4 + axis], table[i, 6 + axis]
        rate = (ex - sx) / duration
        p = sx + rate * tau
        xi = p + rate / omega + (x0 - sx - rate / omega) * growth
        out[axis] = xi
        out[2 + axis] = omega * (xi - p)
        out[4 + axis] = sx + (ex - sx) * (tau / duration)


def fused_multiply_add(a: float, b: float, c: float) -> float:
    """``a·b + c`` rounded once: :func:`giwbc.locomotion.planar.fma` in Python, LLVM's ``llvm.fma``
    (IEEE fused multiply-add: the same correctly rounded value) inside a kernel."""
    return fma(a, b, c)


@intrinsic
def _llvm_fma(typingctx, a, b, c):  # type: ignore[no-untyped-def]
    """``llvm.fma.f64`` (hardware FMA where the CPU has it, else libm's ``fma``: correctly rounded either way)."""
    signature = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        double = ir.DoubleType()
        function = builder.module.declare_intrinsic("llvm.fma", [double], ir.FunctionType(double, [double, double, double]))
        return builder.call(function, args)

    return signature, codegen


@overload(fused_multiply_add)
def _fused_multiply_add_compiled(a, b, c):  # type: ignore[no-untyped-def]
    def implementation(a, b, c):  # type: ignore[no-untyped-def]
        return _llvm_fma(float(a), float(b), float(c))

    return implementation


# How this machine's numpy rounds a row of a (k, 2) @ (2,) product (giwbc.locomotion.planar):
# the clip's edge rates are computed the same way.
FUSED_ROWS = _ROW is fma
FUSED_ROWS_T = _ROW_T is fma  # and of a transposed view's rows


@compiled
def _edge_rate(ey: float, ex: float, dx: float, dy: float, fused: bool) -> float:
    """:func:`giwbc.locomotion.planar.dot2` ``(ey, −ex, dx, dy)``: numpy's rounding of that row."""
    if fused:
        return fused_multiply_add(ey, dx, -ex * dy)
    return ey * dx + -ex * dy


@compiled
def _clip_nearest(px: float, py: float, hull: np.ndarray, out: np.ndarray) -> None:
    """:func:`giwbc.locomotion.support._clip` (k ≥ 2): ``(px, py)`` when inside, else the nearest
    boundary point (:func:`~giwbc.locomotion.support._nearest`, its conditions for min and max)."""
    k = hull.shape[0]
    outside = False
    for index in range(k):
        following = index + 1 if index + 1 < k else 0
        x, y = hull[index, 0], hull[index, 1]
        ex, ey = hull[following, 0] - x, hull[following, 1] - y
        if not (px - x) * ey + (py - y) * -ex <= 0.0:
            outside = True
            break
    if not outside:
        out[0], out[1] = px, py
        return
    best, bx, by = math.inf, 0.0, 0.0
    for index in range(k):
        following = index + 1 if index + 1 < k else 0
        x, y = hull[index, 0], hull[index, 1]
        ex, ey = hull[following, 0] - x, hull[following, 1] - y
        length2 = ex * ex + ey * ey
        s = ((px - x) * ex + (py - y) * ey) / (1e-18 if 1e-18 > length2 else length2)
        s = 0.0 if 0.0 > s else s
        s = 1.0 if s > 1.0 else s
        cx, cy = x + s * ex, y + s * ey
        distance = (cx - px) * (cx - px) + (cy - py) * (cy - py)
        if distance < best:
            best, bx, by = distance, cx, cy
    out[0], out[1] = bx, by


@compiled
def clip_cop_along_ray(ox: float, oy: float, px: float, py: float, hull: np.ndarray, fused: bool, out: np.ndarray) -> bool:
    """:func:`giwbc.locomotion.support.clip_along_ray` of ``(px, py)`` from ``(ox, oy)`` into the
    CCW ``hull`` of k ≥ 2 vertices, into ``out``: True. ``fused``: :data:`FUSED_ROWS` (the edge
    rates rounded as numpy's ``gemv``). False (``out`` untouched) for fewer vertices: the caller's
    Python function answers."""
    k = hull.shape[0]
    if k < 2:
        return False
    dx, dy = px - ox, py - oy
    s = 1.0
    for index in range(k):
        following = index + 1 if index + 1 < k else 0
        x, y = hull[index, 0], hull[index, 1]
        ex, ey = hull[following, 0] - x, hull[following, 1] - y
        inside = (ox - x) * ey + (oy - y) * -ex  # origin against the outward normal (e_y, −e_x): <= 0 inside
        if inside > 0.0 or k < 3:
            _clip_nearest(px, py, hull, out)
            return True
        a, b = ey * dx, ex * dy
        if a - b <= -4e-16 * (abs(a) + abs(b)):
            continue
        if -inside >= (a - b) + 1e-15 * (abs(a) + abs(b)) + 1e-300:
            continue
        rate = _edge_rate(ey, ex, dx, dy, fused)
        if rate > 0.0:
            ratio = -inside / rate
            s = ratio if ratio < s else s  # min(s, ratio)
    out[0] = ox + s * dx
    out[1] = oy + s * dy
    return True


@compiled
def _row(a0: float, x0: float, rest: float, fused: bool) -> float:
    """A row of a 2-column numpy product as :mod:`giwbc.locomotion.planar` rounds it: ``a0·x0 + rest``."""
    if fused:
        return fused_multiply_add(a0, x0, rest)
    return a0 * x0 + rest


@compiled
def step_qp_solve(w_u: float, w_s: float, w_b: float, un0: float, un1: float, sigma_nom: float, d0: float, d1: float, k0: float, k1: float,
                  lo0: float, lo1: float, s_lo: float, hi0: float, hi1: float, s_hi: float, out: np.ndarray) -> bool:
    """:func:`giwbc.locomotion.step_adapter.solve_step_qp` into ``out`` (u_x, u_y, σ): True; False
    (``out`` untouched) for an empty box, where the caller raises."""
    if s_lo > s_hi or lo0 > hi0 or lo1 > hi1:
        return False
    total = w_u + w_b
    a0, a1 = (w_u * un0 + w_b * k0) / total, (w_u * un1 + w_b * k1) / total
    b0, b1 = w_b * d0 / total, w_b * d1 / total
    knots = np.empty(6)
    knots[0], knots[1] = s_lo, s_hi
    count = 2
    for axis in range(2):
        a, b, lo, hi = (a0, b0, lo0, hi0) if axis == 0 else (a1, b1, lo1, hi1)
        if b != 0.0:
            for bound in (lo, hi):
                sigma = (bound - a) / b
                if s_lo < sigma < s_hi:
                    knots[count] = sigma
                    count += 1
    # sorted(set(...)): an insertion sort, then equal values dropped
    for i in range(1, count):
        value = knots[i]
        j = i - 1
        while j >= 0 and knots[j] > value:
            knots[j + 1] = knots[j]
            j -= 1
        knots[j + 1] = value
    unique = 1
    for i in range(1, count):
        if knots[i] != knots[unique - 1]:
            knots[unique] = knots[i]
            unique += 1
    pieces = 1 if unique == 1 else unique - 1
    best_cost = math.inf
    found = False
    bz0, bz1, bsigma = 0.0, 0.0, 0.0
    for piece in range(pieces):
        left = knots[piece]
        right = knots[piece + 1] if unique > 1 else knots[0]
        middle = 0.5 * (left + right)
        u = a0 + b0 * middle
        if u < lo0:
            alpha0, beta0 = lo0, 0.0
        elif u > hi0:
            alpha0, beta0 = hi0, 0.0
        else:
            alpha0, beta0 = a0, b0
        u = a1 + b1 * middle
        if u < lo1:
            alpha1, beta1 = lo1, 0.0
        elif u > hi1:
            alpha1, beta1 = hi1, 0.0
        else:
            alpha1, beta1 = a1, b1
        m0, m1 = d0 - beta0, d1 - beta1
        num = w_s * sigma_nom
        num -= w_u * beta0 * (alpha0 - un0) + w_b * m0 * (k0 - alpha0)
        num -= w_u * beta1 * (alpha1 - un1) + w_b * m1 * (k1 - alpha1)
        den = w_s
        den += w_u * beta0 * beta0 + w_b * m0 * m0
        den += w_u * beta1 * beta1 + w_b * m1 * m1
        if den > 0.0:
            sigma = num / den
            sigma = left if left > sigma else sigma  # max(num / den, left)
            sigma = right if right < sigma else sigma  # min(..., right)
        else:
            sigma = left
        z0 = alpha0 + beta0 * sigma
        z0 = lo0 if lo0 > z0 else z0
        z0 = hi0 if hi0 < z0 else z0
        z1 = alpha1 + beta1 * sigma
        z1 = lo1 if lo1 > z1 else z1
        z1 = hi1 if hi1 < z1 else z1
        cost = w_u * ((z0 - un0) ** 2 + (z1 - un1) ** 2) + w_s * (sigma - sigma_nom) ** 2
        cost += w_b * ((d0 * sigma + k0 - z0) ** 2 + (d1 * sigma + k1 - z1) ** 2)
        if cost < best_cost:
            best_cost, found = cost, True
            bz0, bz1, bsigma = z0, z1, sigma
    if not found:
        return False
    out[0], out[1], out[2] = bz0, bz1, bsigma
    return True


# StepAdapter.adapt_in's inputs: a step's frame (StepFrame.values: c, s, origin x, y, u_nom x, y,
# b_nom x, y) and a tick's (below); its outputs (below).
STEP_FRAME = 8
STEP_INPUTS = 20  # cop x, y, dcm x, y, ω, T_min, T_max, T_nom, w_u, w_σ, w_b, x_lo, x_hi, y_lo, y_hi, reach pieces (0: none), foot x, y, speed, slack
STEP_OUTPUTS = 7  # landing x, y (world), remaining time, ξ_end x, y and u x, y (stance frame)


@compiled
def step_adapt(frame: np.ndarray, inputs: np.ndarray, fused: bool, fused_t: bool, out: np.ndarray) -> bool:
    """:meth:`giwbc.locomotion.step_adapter.StepAdapter.adapt_in`'s arithmetic (inputs checked by the
    caller; :data:`STEP_FRAME`, :data:`STEP_INPUTS`, :data:`STEP_OUTPUTS`) into ``out``: True;
    False for an empty box (the caller raises). ``fused``, ``fused_t``: :data:`FUSED_ROWS`,
    :data:`FUSED_ROWS_T` (the rotations rounded as :mod:`giwbc.locomotion.planar`'s)."""
    c, sn, ox, oy, un0, un1, bn0, bn1 = frame[0], frame[1], frame[2], frame[3], frame[4], frame[5], frame[6], frame[7]
    cx, cy, xx, xy, omega, t_lo, t_hi, nominal = inputs[0], inputs[1], inputs[2], inputs[3], inputs[4], inputs[5], inputs[6], inputs[7]
    w_u, w_s, w_b = inputs[8], inputs[9], inputs[10]
    x_lo, x_hi, y_lo, y_hi = inputs[11], inputs[12], inputs[13], inputs[14]
    x, y = cx - ox, cy - oy
    p0, p1 = _row(c, x, sn * y, fused_t), _row(-sn, x, c * y, fused_t)
    x, y = xx - cx, xy - cy
    d0, d1 = _row(c, x, sn * y, fused_t), _row(-sn, x, c * y, fused_t)
    sigma_nom = nominal
    sigma_nom = t_lo if t_lo > sigma_nom else sigma_nom  # max(T_nom, T_min)
    sigma_nom = t_hi if t_hi < sigma_nom else sigma_nom  # min(..., T_max)
    sigma_nom = math.exp(omega * sigma_nom)
    k0, k1 = p0 - bn0, p1 - bn1
    solution = np.empty(3)
    pieces = int(inputs[15])
    if pieces == 0:
        if not step_qp_solve(w_u, w_s, w_b, un0, un1, sigma_nom, d0, d1, k0, k1, x_lo, y_lo, math.exp(omega * t_lo), x_hi, y_hi,
                             math.exp(omega * t_hi), solution):
            return False
    else:  # SwingReach: the time range in pieces, each with the reach of its shortest time (SwingReach.cut)
        foot_x, foot_y, speed, slack = inputs[16], inputs[17], inputs[18], inputs[19]
        n = pieces if t_hi > t_lo else 1
        best_cost = math.inf
        found = False
        piece = np.empty(3)
        for i in range(n):
            a, b = t_lo + (t_hi - t_lo) * i / n, t_lo + (t_hi - t_lo) * (i + 1) / n
            radius = slack + speed * a
            px_lo, px_hi = foot_x - radius, foot_x + radius
            px_lo = px_lo if px_lo > x_lo else x_lo  # max(lo, at − radius)
            px_hi = px_hi if px_hi < x_hi else x_hi  # min(hi, at + radius)
            if px_lo > px_hi:
                px_lo = px_hi = x_lo if foot_x < x_lo else x_hi
            py_lo, py_hi = foot_y - radius, foot_y + radius
            py_lo = py_lo if py_lo > y_lo else y_lo
            py_hi = py_hi if py_hi < y_hi else y_hi
            if py_lo > py_hi:
                py_lo = py_hi = y_lo if foot_y < y_lo else y_hi
            if not step_qp_solve(w_u, w_s, w_b, un0, un1, sigma_nom, d0, d1, k0, k1, px_lo, py_lo, math.exp(omega * a), px_hi, py_hi,
                                 math.exp(omega * b), piece):
                return False
            ux, uy, sigma = piece[0], piece[1], piece[2]
            cost = w_u * ((ux - un0) ** 2 + (uy - un1) ** 2) + w_s * (sigma - sigma_nom) ** 2  # step_cost
            cost = cost + w_b * ((d0 * sigma + k0 - ux) ** 2 + (d1 * sigma + k1 - uy) ** 2)
            if cost < best_cost:
                best_cost, found = cost, True
                solution[0], solution[1], solution[2] = ux, uy, sigma
        if not found:
            return False
    ux, uy, sigma = solution[0], solution[1], solution[2]
    out[0] = ox + _row(c, ux, -sn * uy, fused)
    out[1] = oy + _row(sn, ux, c * uy, fused)
    out[2] = math.log(sigma) / omega
    out[3], out[4] = p0 + d0 * sigma, p1 + d1 * sigma
    out[5], out[6] = ux, uy
    return True


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel here for the argument types the walker
    passes, so a first compile never lands inside a control tick (a walker's construction calls it)."""
    table = np.zeros((4, SWING_COLUMNS))
    table[:, 0], table[:, 2] = 1.0, 1.0
    swing_state(0.5, table, np.empty((4, 3)))
    dcm_evaluate(0.5, np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]), 3.5, np.empty(6))
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    for origin, point in (((0.0, 0.0), (0.1, 0.1)), ((0.0, 0.0), (2.0, 0.5)), ((3.0, 0.0), (2.0, 0.5))):
        clip_cop_along_ray(*origin, *point, square, FUSED_ROWS, np.empty(2))
    frame = np.array([1.0, 0.0, 0.0, 0.0, 0.0, -0.2, 0.0, 0.05])
    for pieces in (0.0, 12.0):
        inputs = np.array([0.0, 0.0, 0.05, 0.02, 3.5, 0.1, 0.5, 0.3, 1.0, 0.5, 100.0, -0.3, 0.4, -0.5, -0.1, pieces, 0.0, -0.2, 1.5, 0.05])
        step_adapt(frame, inputs, FUSED_ROWS, FUSED_ROWS_T, np.empty(STEP_OUTPUTS))
