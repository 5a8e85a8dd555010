"""The physics engine as a randomized choice (the paper's future work: the engine in the domain)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from giwbc.randomization.distributions import RandomizationError
from giwbc.robot.mujoco_robot import MujocoRobot

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription
    from giwbc.robot.interface import Robot

ENGINES = ("mujoco", "pybullet")


class EngineChoice:
    """Draws an engine name with fixed probabilities, e.g. ``EngineChoice({"mujoco": 0.7, "pybullet": 0.3})``."""

    def __init__(self, probabilities: Mapping[str, float]) -> None:
        unknown = set(probabilities) - set(ENGINES)
        if unknown:
            raise RandomizationError(f"engine choice: unknown engines {sorted(unknown)}; known: {list(ENGINES)}")
        values = {name: float(p) for name, p in probabilities.items()}
        if not values or any(not math.isfinite(p) or p < 0 for p in values.values()):
            raise RandomizationError(f"engine choice: probabilities must be finite and >= 0, got {dict(probabilities)}")
        total = sum(values.values())
        if not math.isclose(total, 1.0, rel_tol=0, abs_tol=1e-9):
            raise RandomizationError(f"engine choice: probabilities must sum to 1, got {total}")
        self.engines = tuple(values)
        self.probabilities = np.array([values[name] for name in self.engines])

    def sample(self, rng: np.random.Generator) -> str:
        """One engine name (one uniform draw from ``rng``)."""
        index = int(np.searchsorted(np.cumsum(self.probabilities), rng.uniform(), side="right"))
        return self.engines[min(index, len(self.engines) - 1)]


def build_robot(engine: str, description: "RobotDescription", **options: object) -> "Robot":
    """A simulated robot of ``description`` on ``engine`` (``options`` go to its constructor)."""
    if engine == "mujoco":
        return MujocoRobot(description, **options)
    if engine == "pybullet":
        from giwbc.robot.pybullet_robot import PybulletRobot  # optional heavy dependency (imports pybullet)


        return PybulletRobot(description, **options)
    raise RandomizationError(f"unknown engine {engine!r}; known: {list(ENGINES)}")
