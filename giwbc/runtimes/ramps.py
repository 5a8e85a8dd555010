"""Interpolation profiles for the runtime's ramps: ``s`` in [0, 1] -> (value, derivative), both
clamped to the interval. The start-up ramp uses one by name (:data:`PROFILES`)."""

from __future__ import annotations

import math
from collections.abc import Callable


def min_jerk(s: float) -> tuple[float, float]:
    """Minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5`` on [0, 1] and its derivative."""
    s = min(1.0, max(0.0, s))
    return s**3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2


def cosine(s: float) -> tuple[float, float]:
    """Cosine profile ``(1 - cos(pi s)) / 2`` on [0, 1] and its derivative."""
    s = min(1.0, max(0.0, s))
    return 0.5 * (1 - math.cos(math.pi * s)), 0.5 * math.pi * math.sin(math.pi * s)


PROFILES: dict[str, Callable[[float], tuple[float, float]]] = {"minjerk": min_jerk, "cosine": cosine}


__all__ = ["PROFILES", "cosine", "min_jerk"]
