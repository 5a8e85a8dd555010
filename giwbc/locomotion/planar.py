"""Plain-float 2-D arithmetic for per-tick hot paths, bit for bit what numpy computes.

A numpy call on a 2-vector costs about a microsecond of overhead for a few flops; the walking
controller makes dozens per tick. These helpers do the same arithmetic on Python floats. They
keep numpy's *bits*: element-wise ``+ − × ÷`` are IEEE operations either way, but a matrix-vector
product ``R @ x`` (C-ordered ``R``) runs through OpenBLAS's ``gemv`` kernel, which on this
machine's CPUs rounds each row as ``fma(R[i,0], x[0], R[i,1]·x[1])`` — a fused multiply-add
that Python 3.11 floats lack. :func:`fma` computes it exactly (Dekker's error-free product,
then ``math.fsum``, correctly rounded). Which rounding numpy uses depends on the CPU and the BLAS
build, so it is asked once at import (:func:`_rounding`) for ``R @ x`` and for ``Rᵀ @ x`` (a
transposed view: plain ``a·b + c·d`` here, as ``einsum`` rows are).
"""

from __future__ import annotations

import math

import numpy as np

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


def _plain(a: float, b: float, c: float) -> float:
    return a * b + c


def _rounding(transposed: bool) -> object:
    """How this machine's numpy rounds a row of a 2-column matrix-vector product: ``fma`` when it
    fuses the first product (OpenBLAS's ``gemv`` kernels on FMA CPUs), ``_plain`` when it rounds
    both products; asked once, at import, on a row where the two differ (``a² − 1``)."""
    a = 1.0 + 2.0**-30
    rows = np.array([[a, -1.0], [-1.0, a]])
    product = float(((rows.T if transposed else rows) @ np.array([a, 1.0]))[0])
    if product == fma(a, a, -1.0):
        return fma
    if product == a * a - 1.0:
        return _plain
    raise RuntimeError(f"numpy's 2 × 2 matrix-vector product rounds neither as a fused nor as a plain multiply-add ({product!r})")


_ROW = _rounding(transposed=False)  # C-ordered (k, 2) @ (2,)
_ROW_T = _rounding(transposed=True)  # a transposed view's rows


def dot2(a0: float, a1: float, x0: float, x1: float) -> float:
    """One row of a (C-ordered) numpy ``(k, 2) @ (2,)`` product (``fma(a0, x0, a1·x1)`` here)."""
    return _ROW(a0, x0, a1 * x1)  # type: ignore[operator]


def rotate(c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """``[[c, −s], [s, c]] @ (x, y)`` with numpy's bits (a C-ordered rotation matrix times a vector)."""
    row = _ROW
    return row(c, x, -s * y), row(s, x, c * y)  # type: ignore[operator]


def rotate_back(c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """``[[c, −s], [s, c]]ᵀ @ (x, y)`` with numpy's bits (a transposed view: plain products here)."""
    row = _ROW_T
    return row(c, x, s * y), row(-s, x, c * y)  # type: ignore[operator]


def distance2(a: np.ndarray, b: np.ndarray) -> float:
    """``‖a − b‖`` of two (x, y) points, as ``np.linalg.norm`` computes it (``√(dx² + dy²)``), on floats."""
    dx, dy = float(a[0]) - float(b[0]), float(a[1]) - float(b[1])
    return math.sqrt(dx * dx + dy * dy)
