"""Compiled kernels of the whole-body controller's QP assembly (issue 37): the equation of motion's
rows, written in one call instead of four numpy calls.

Each kernel is a plain Python function compiled by :func:`giwbc.util.jit.compiled` (numba,
``cache=True``, no ``fastmath``); ``reference(kernel)`` is the same function uncompiled (what the
tests compare it with). They only copy, negate and subtract — one rounding per entry, whatever the
order — so their results are the numpy implementation's bit for bit. (The KKT solve's kernels are
in :mod:`giwbc.control.qp.kernels`.)
"""

from __future__ import annotations

import numpy as np

from giwbc.util.jit import compiled, reference

__all__ = ["dynamics_rows", "reference", "warm"]


@compiled
def dynamics_rows(D_M: np.ndarray, M: np.ndarray, h: np.ndarray, b_base: np.ndarray, tau_lo: np.ndarray, tau_hi: np.ndarray,
                  l_torque: np.ndarray, u_torque: np.ndarray) -> None:
    """The equation of motion's rows when every joint's torque is limited: ``D_M = M`` (the mass
    matrix block of ``[M, −JᵀΦ]``), ``b_base = −h_b`` (the floating base's ``nb = len(b_base)``
    equality rows) and the torque rows' limits ``l = τ_min − h_j``, ``u = τ_max − h_j``."""
    rows, columns = M.shape
    for i in range(rows):
        for j in range(columns):
            D_M[i, j] = M[i, j]
    nb = b_base.shape[0]
    for i in range(nb):
        b_base[i] = -h[i]
    for i in range(tau_lo.shape[0]):
        l_torque[i] = tau_lo[i] - h[nb + i]
        u_torque[i] = tau_hi[i] - h[nb + i]


def _like(array: np.ndarray) -> np.ndarray:
    """A small 2-D array numba types as ``array`` (C-ordered, Fortran-ordered or strided)."""
    if array.flags.c_contiguous:
        return np.zeros((2, 2))
    if array.flags.f_contiguous:
        return np.zeros((2, 2), order="F")
    return np.zeros((2, 4))[:, :2]


def warm(M: np.ndarray) -> None:
    """Compile (or load from numba's cache) :func:`dynamics_rows` for a controller's mass matrix
    ``M`` and both layouts of its ``D_M`` block (a strided view of ``[M, −JᵀΦ]``, C-ordered when
    there is no contact), on small arrays, so that a compile never lands in a control loop's
    first ticks."""
    empty = np.zeros(0)
    for D_M in (np.zeros((2, 4))[:, :2], np.zeros((2, 2))):
        dynamics_rows(D_M, _like(M), np.zeros(2), empty, empty, empty, np.zeros(0), np.zeros(0))
