"""Compiled kernels of the active-set guess's KKT solve (issue 37): the system's assembly before
LAPACK's ``dgesv`` and the optimality check after it, each one call instead of a dozen numpy calls.

Why compiled: a KKT solve of the G1 problem (65 x 65) is ~16 µs of ``dgesv`` and ~10 µs of numpy
glue around it — block copies, gathers, a negation, the limits' differences, the multipliers'
signs, an argmax — each call ~0.5-1 µs on 20- to 130-vectors. Compiled with numba
(:func:`giwbc.util.jit.compiled`: ``cache=True``, no ``fastmath``), the glue is two calls.

What stays outside: the factorisation (scipy's ``dgesv``: numba's ``np.linalg.solve`` copies its
operands and measured slower at this size) and the product ``[A; C; I] x`` (numpy's BLAS
``dgemv``, whose sums these kernels do not reorder). The kernels only copy, negate, subtract,
multiply and compare — operations rounded once each whatever their order — so their results are
the numpy implementation's bit for bit, and a rollout's bits do not change.
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.util.jit import compiled, reference

__all__ = ["kkt_check", "kkt_fill", "reference", "warm"]


@compiled
def kkt_fill(K: np.ndarray, rhs: np.ndarray, H: np.ndarray, g: np.ndarray, stack: np.ndarray, keep: np.ndarray,
             eq_rows: np.ndarray, limits: np.ndarray, rhs_index: np.ndarray, diagonal: float) -> None:
    """Write the KKT system of an active set: ``K = [[H_kk, E_kᵀ], [E_k, −δ I]]`` and
    ``rhs = [−g_k, limits[rhs_index]]``, with ``k = keep`` the variables kept (all, or all but the
    fixed ones), ``E = stack[eq_rows]`` (the kept equality rows, then the active inequality rows)
    restricted to those columns, ``−δ = diagonal`` (``0.0``: no regularisation; written as given,
    so an unregularised system holds ``+0.0`` there, as numpy's ``fill(0.0)`` wrote). ``K`` is C-ordered and written
    whole (LAPACK factorised its transpose in place last time)."""
    n = keep.shape[0]
    size = K.shape[0]
    m = size - n
    for i in range(n):
        row = keep[i]
        for j in range(n):
            K[i, j] = H[row, keep[j]]
        rhs[i] = -g[row]
    for a in range(m):
        source = eq_rows[a]
        for j in range(n):
            value = stack[source, keep[j]]
            K[n + a, j] = value
            K[j, n + a] = value
        for b in range(m):
            K[n + a, n + b] = 0.0
        K[n + a, n + a] = diagonal
        rhs[n + a] = limits[rhs_index[a]]


@compiled
def kkt_check(r: np.ndarray, lo: np.ndarray, hi: np.ndarray, check: np.ndarray, active_rows: np.ndarray,
              sign_open: np.ndarray, multipliers: np.ndarray, signs: bool) -> float:
    """The optimality check of a KKT candidate whose rows ``[A; C; I] x`` are ``r``: writes
    ``check[:m] = r − hi`` (over), ``check[m:2m] = lo − r`` (under) and, when ``signs``, the signed
    multipliers ``check[2m:2m+k] = λ · s`` with ``s = 0`` for a row this tick's limits pin
    (``lo = hi``) and ``sign_open`` (− at an upper bound, + at a lower one) otherwise; returns the
    largest of what it wrote (``-inf`` for nothing, NaN when any is NaN: as numpy's ``argmax``)."""
    m = r.shape[0]
    worst = -math.inf
    nan = False
    for i in range(m):
        over = r[i] - hi[i]
        under = lo[i] - r[i]
        check[i] = over
        check[m + i] = under
        if over != over or under != under:
            nan = True
        if over > worst:
            worst = over
        if under > worst:
            worst = under
    if signs:
        for a in range(active_rows.shape[0]):
            row = active_rows[a]
            sign = 0.0 if lo[row] + 0.0 == hi[row] else sign_open[a]
            value = multipliers[a] * sign
            check[2 * m + a] = value
            if value != value:
                nan = True
            if value > worst:
                worst = value
    return math.nan if nan else worst


def warm() -> None:
    """Compile (or load from numba's cache) both kernels for the argument types the guess passes —
    the stacked rows read-only (a view over the controller's adjacent ``A`` and ``C``) or the
    guess's own writable copy — on a 1-variable system, so that a compile never lands in a
    control loop's first ticks."""
    K, rhs, H, g, limits = np.eye(2), np.zeros(2), np.eye(1), np.zeros(1), np.zeros(2)
    index = np.zeros(1, dtype=np.int64)
    stack = np.ones((1, 1))
    for rows in (stack, np.lib.stride_tricks.as_strided(stack, shape=(1, 1), strides=stack.strides, writeable=False)):
        kkt_fill(K, rhs, H, g, rows, index, index, limits, index, 0.0)
    kkt_check(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(3), index, np.ones(1), np.zeros(1), True)
