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

from giwbc.locomotion.planar import _ROW, fma
from giwbc.util.jit import compiled

__all__ = ["DCM_COLUMNS", "FUSED_ROWS", "SWING_COLUMNS", "clip_cop_along_ray", "dcm_evaluate", "fused_multiply_add", "swing_state", "warm_up"]

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
