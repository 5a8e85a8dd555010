"""Compiled numerical kernels (issue 37): one decorator for every numba kernel in giwbc, and the way
back to a kernel's plain Python function (what the tests compare it with).

A kernel is a plain Python function over float64 arrays, tuples and scalars, compiled by numba in
nopython mode at its first call with each argument types. No ``fastmath``: IEEE arithmetic in the
order written, so a rollout stays bit for bit reproducible on one machine. The compiled code is
cached on disk (numba's ``cache=True``): in ``NUMBA_CACHE_DIR`` when set, else in ``__pycache__``
next to the source file, else in the user's cache folder (``~/.cache/numba``); where none is
writable (a read-only installation, no home) the kernels compile at the first call of every process.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba

__all__ = ["compiled", "reference"]


def compiled(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function`` compiled by numba (module doc), cached on disk where a cache folder is writable."""
    try:
        return numba.njit(cache=True, nogil=True)(function)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available" (nothing writable)
        return numba.njit(nogil=True)(function)


def reference(kernel: Callable[..., Any]) -> Callable[..., Any]:
    """The uncompiled Python function of ``kernel`` (``kernel`` itself under ``NUMBA_DISABLE_JIT=1``)."""
    return getattr(kernel, "py_func", kernel)
