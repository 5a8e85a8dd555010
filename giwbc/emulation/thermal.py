"""Coil temperature of the emulated motors (:class:`ThermalModel`).

``dT/dt = k tau^2 + h - (T - ambient) / time_constant`` with ``k`` such that the model's rated
torque gives ``rated_rise`` kelvin at steady state; ``h`` is extra heating (the ``overheat`` fault).
Above ``trip`` the firmware latches an over-temperature error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ThermalModel:
    """First-order coil temperature of every motor (see the module docstring)."""

    ambient: float = 25.0  # °C
    time_constant: float = 120.0  # s
    rated_rise: float = 40.0  # K at steady state under rated torque
    rated_fraction: float = 0.3  # rated torque as a fraction of the model's torque range
    trip: float = 90.0  # °C: the firmware latches an over-temperature error above this
    mos_fraction: float = 0.4  # driver (MOS) temperature rise as a fraction of the coil's

    def __post_init__(self) -> None:
        if not (self.time_constant > 0 and self.rated_rise > 0 and 0 < self.rated_fraction <= 1):
            raise ValueError("thermal model needs time_constant > 0, rated_rise > 0, 0 < rated_fraction <= 1")

    def heating(self, torque_max: np.ndarray) -> np.ndarray:
        """K/s per (N m)^2 of motor-side torque, per motor."""
        rated = self.rated_fraction * np.asarray(torque_max, dtype=float)
        return self.rated_rise / (rated**2 * self.time_constant)

    def step(self, temperature: np.ndarray, torque: np.ndarray, dt: float, k: np.ndarray, extra: np.ndarray) -> np.ndarray:
        """Exact step of the linear model over ``dt`` with torque and extra heating held (K/s)."""
        steady = self.ambient + (k * torque**2 + extra) * self.time_constant
        return steady + (temperature - steady) * math.exp(-dt / self.time_constant)


__all__ = ["ThermalModel"]
