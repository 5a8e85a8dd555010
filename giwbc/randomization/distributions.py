"""Probability distributions of randomized parameters: ``uniform``, ``loguniform``, ``gaussian``.

A distribution draws ``shape`` values from the caller's ``numpy.random.Generator``: it holds no
generator of its own, so a seeded environment stays reproducible. Bounds may be scalars or arrays
that broadcast against the drawn shape (e.g. a per-axis range for a centre-of-mass offset).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from giwbc.errors import RandomizationError

KINDS = {"uniform": ("low", "high"), "loguniform": ("low", "high"), "gaussian": ("mean", "std")}


@dataclass(frozen=True)
class Distribution:
    """One of :data:`KINDS`, with its two parameters (scalars or arrays)."""

    kind: str
    first: np.ndarray  # low or mean
    second: np.ndarray  # high or std

    @classmethod
    def from_config(cls, table: dict[str, Any], where: str) -> "Distribution":
        """Parse ``distribution = "uniform", low = .., high = ..`` (or ``mean``/``std``) from an entry."""
        kind = table.get("distribution")
        if kind not in KINDS:
            raise RandomizationError(f"{where}: 'distribution' must be one of {sorted(KINDS)}, got {kind!r}")
        names = KINDS[kind]
        values = []
        for name in names:
            if name not in table:
                raise RandomizationError(f"{where}: a {kind} distribution needs {names[0]!r} and {names[1]!r}; missing {name!r}")
            value = table[name]
            try:
                array = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise RandomizationError(f"{where}: {name!r} must be a number or a list of numbers, got {value!r}") from None
            if isinstance(value, bool) or array.ndim > 1 or not np.all(np.isfinite(array)):
                raise RandomizationError(f"{where}: {name!r} must be finite numbers, got {value!r}")
            values.append(array)
        first, second = values
        if first.shape != second.shape and first.ndim and second.ndim:
            raise RandomizationError(f"{where}: {names[0]!r} and {names[1]!r} have different lengths")
        if kind in ("uniform", "loguniform") and np.any(first > second):
            raise RandomizationError(f"{where}: low must be <= high, got low={first.tolist()} high={second.tolist()}")
        if kind == "loguniform" and np.any(first <= 0):
            raise RandomizationError(f"{where}: a loguniform distribution needs low > 0, got {first.tolist()}")
        if kind == "gaussian" and np.any(second < 0):
            raise RandomizationError(f"{where}: a gaussian distribution needs std >= 0, got {second.tolist()}")
        return cls(kind, first, second)

    @property
    def components(self) -> int:
        """Length of the bounds (0 for scalars): a vector parameter checks it against its size."""
        return max(self.first.size if self.first.ndim else 0, self.second.size if self.second.ndim else 0)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """``shape`` draws (bounds broadcast against the trailing axes)."""
        if self.kind == "uniform":
            return rng.uniform(self.first, self.second, size=shape)
        if self.kind == "loguniform":
            return np.exp(rng.uniform(np.log(self.first), np.log(self.second), size=shape))
        return rng.normal(self.first, self.second, size=shape)

    def describe(self) -> str:
        a, b = KINDS[self.kind]
        return f"{self.kind}({a}={self.first.tolist()}, {b}={self.second.tolist()})"
