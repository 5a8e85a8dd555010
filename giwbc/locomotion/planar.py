"""Plain-float 2-D arithmetic for per-tick hot paths, bit for bit what numpy computes.

A numpy call on a 2-vector costs about a microsecond of overhead for a few flops; the walking
controller makes dozens per tick. These helpers do the same arithmetic on Python floats. They
keep numpy's *bits*: element-wise ``+ − × ÷`` are IEEE operations either way, but a matrix-vector
product ``R @ x`` (C-ordered ``R``) runs through OpenBLAS's ``gemv`` kernel, which on this
machine's CPUs rounds each row as ``fma(R[i,0], x[0], R[i,1]·x[1])`` — a fused multiply-add
that Python 3.11 floats lack. :func:`fma` computes it exactly (Dekker's error-free product,
then ``math.fsum``, correctly rounded), and :func:`dot2` uses it only where it can change the
result. (``Rᵀ @ x`` and ``einsum`` rows round as plain ``a·b + c·d``.)
"""

from __future__ import annotations

import math

_SPLIT = 134217729.0  # 2^27 + 1: Veltkamp's splitting constant for float64
_fsum = math.fsum


def fma(a: float, b: float, c: float) -> float:
    """``a·b + c`` rounded once (exact for finite values away from overflow)."""
    p = a * b
    t = _SPLIT * a
    a_hi = t - (t - a)
    a_lo = a - a_hi
    t = _SPLIT * b
    b_hi = t - (t - b)
    b_lo = b - b_hi
    error = ((a_hi * b_hi - p) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo  # a·b − p, exactly
    return _fsum((p, error, c))


def dot2(a0: float, a1: float, x0: float, x1: float) -> float:
    """One row of a (C-ordered) numpy ``(k, 2) @ (2,)`` product: ``fma(a0, x0, a1·x1)``."""
    return fma(a0, x0, a1 * x1)


def rotate(c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """``[[c, −s], [s, c]] @ (x, y)`` with numpy's bits (a C-ordered rotation matrix times a vector)."""
    return fma(c, x, -s * y), fma(s, x, c * y)


def rotate_back(c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """``[[c, −s], [s, c]]ᵀ @ (x, y)`` with numpy's bits (a transposed view: plain products)."""
    return c * x + s * y, -s * x + c * y
