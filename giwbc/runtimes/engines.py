"""The simulated robots of one environment: one per physics engine, built on first use, closed together.

A simulated runtime runs on one engine (``"mujoco"`` or ``"pybullet"``) or draws one per episode
from an :class:`~giwbc.randomization.EngineChoice`. Every engine's robot is built from the same
robot description; a robot that must carry robot-level perturbations (actuator latency, gain
scales, sensor noise, pushes) is wrapped once in a :class:`~giwbc.randomization.PerturbedRobot`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from giwbc.randomization import ENGINES, EngineChoice, PerturbedRobot, RandomizationError, build_robot
from giwbc.robot.interface import Robot

EngineSpec = str | EngineChoice | Mapping[str, float]


def engine_of(robot: Robot) -> str:
    """The engine name of a simulated robot (``"mujoco"``, ``"pybullet"``, else its class name)."""
    if isinstance(robot, PerturbedRobot):
        robot = robot.robot
    model = getattr(robot, "model", None)
    if model is not None and hasattr(model, "opt"):
        return "mujoco"
    if type(robot).__name__ == "PybulletRobot":  # by name: importing pybullet just to check prints a banner
        return "pybullet"
    return type(robot).__name__


def parse_engine(engine: EngineSpec | None) -> str | EngineChoice:
    """``"mujoco"``, ``"pybullet"``, an EngineChoice, or a ``{engine: probability}`` mapping (JSON-friendly)."""
    if engine is None:
        return "mujoco"
    if isinstance(engine, EngineChoice):
        return engine
    if isinstance(engine, Mapping):
        return EngineChoice(engine)
    if engine not in ENGINES:
        raise RandomizationError(f"engine must be one of {list(ENGINES)}, an EngineChoice or a {{engine: probability}} dict, got {engine!r}")
    return engine


class EnginePool:
    """Builds, caches and closes one robot per engine for one environment.

    ``robot`` given: the pool holds that robot only (its engine cannot change). Otherwise robots of
    ``description`` are built on first use with ``options[engine]`` as constructor keywords (e.g.
    ``{"mujoco": {"model": model}}``). ``perturbed``: hand out robots wrapped in a PerturbedRobot.
    """

    def __init__(
        self,
        description: Any,
        engine: EngineSpec | None = None,
        *,
        options: Mapping[str, Mapping[str, Any]] | None = None,
        robot: Robot | None = None,
        perturbed: bool = False,
    ) -> None:
        self.description = description
        self.options = {name: dict(values) for name, values in (options or {}).items()}
        unknown = set(self.options) - set(ENGINES)
        if unknown:
            raise RandomizationError(f"engine_options: unknown engines {sorted(unknown)}; known: {list(ENGINES)}")
        self.perturbed = perturbed
        self._engines: dict[str, Robot] = {}
        self._wrapped: dict[str, Robot] = {}
        self._built: set[str] = set()  # engines whose robot this pool built (and so closes)
        if robot is not None:
            if engine is not None and not (isinstance(engine, str) and engine == engine_of(robot)):
                raise RandomizationError(f"a runtime given a robot runs on its engine ({engine_of(robot)}); got engine={engine!r}")
            self.choice: str | EngineChoice = engine_of(robot)
            if isinstance(robot, PerturbedRobot):  # already wrapped: never wrap twice
                self._wrapped[self.choice], robot = robot, robot.robot
            self._engines[self.choice] = robot
        else:
            self.choice = parse_engine(engine)

    @property
    def engines(self) -> tuple[str, ...]:
        """The engines this pool may hand out, the first being the one used before any reset."""
        if isinstance(self.choice, EngineChoice):
            return tuple(name for name, p in zip(self.choice.engines, self.choice.probabilities) if p > 0)
        return (self.choice,)

    def choose(self, rng: np.random.Generator) -> str:
        """This episode's engine: one draw from ``rng`` for an EngineChoice, none for a fixed engine."""
        return self.choice.sample(rng) if isinstance(self.choice, EngineChoice) else self.choice

    def engine_robot(self, engine: str) -> Robot:
        """The bare engine robot (built now if it is the first use)."""
        robot = self._engines.get(engine)
        if robot is None:
            if self.description is None:
                raise RandomizationError(f"cannot build a {engine} robot: this runtime was given a robot, not a description")
            robot = self._engines[engine] = build_robot(engine, self.description, **self.options.get(engine, {}))
            self._built.add(engine)
        return robot

    def robot(self, engine: str) -> Robot:
        """The robot the task runs on for ``engine`` (wrapped in a PerturbedRobot when perturbed)."""
        wrapped = self._wrapped.get(engine)
        if not self.perturbed and wrapped is None:
            return self.engine_robot(engine)
        if wrapped is None:
            wrapped = self._wrapped[engine] = PerturbedRobot(self.engine_robot(engine))
        return wrapped

    def close(self) -> None:
        """Close the robots this pool built (PyBullet disconnects its server); a robot it was given stays open."""
        for engine in sorted(self._built):
            close = getattr(self._engines.pop(engine), "close", None)
            self._wrapped.pop(engine, None)
            if callable(close):
                close()
        self._built.clear()
