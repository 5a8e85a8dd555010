"""A simulated runtime whose plant is drawn per episode from a :class:`~giwbc.randomization.plant_distribution.PlantDistribution`.

``gymnasium.make("giwbc/G1Walk-v0", plant="random")`` (or a distribution dict / TOML path /
``PlantDistribution``) builds one. At every reset, from the seeded ``np_random`` and before any
other draw: the episode's variant, then its parameters (the env's ``randomization=`` and sim2real
knobs first, the distribution's entries after, all around the variant's own values), then the
task's initial state. Each variant's ``MjModel`` is compiled once, on its first draw, and kept with
its robot: a reset writes parameters in place and never recompiles.

The actor's observation is the task's (what a robot has); what the plant really is goes to
``info["privileged"]`` (names: :meth:`PlantDistributionRuntime.privileged_names`), e.g. for an
asymmetric critic, and ``info["plant"]`` names the variant.

With an estimator in the loop the start-up calibration can fail on a plant where the standing robot
creeps (seen on point feet and the soft floor: a leg joint moving > 1 mrad over the window);
``plant_redraws=N`` (a gymnasium.make option) then draws another plant, up to N times.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from giwbc.plants import NOMINAL, resolve_plant
from giwbc.randomization import DomainRandomizer, PerturbedRobot, RandomizationConfig
from giwbc.errors import EstimatorCalibrationError, RandomizationError
from giwbc.randomization.plant_distribution import RANDOM, PlantDistribution
from giwbc.robot.description import RobotDescription
from giwbc.runtimes import SimulatedRuntime
from giwbc.runtimes.engines import EnginePool
from giwbc.tasks.task import Task
from giwbc.util.toml import load_toml

_LEGS = r".*_(hip_(pitch|roll|yaw)|knee|ankle_(pitch|roll))_joint"


class PlantDistributionRuntime(SimulatedRuntime):
    """A :class:`SimulatedRuntime` (MuJoCo) on a plant drawn per episode (module docstring)."""

    def __init__(self, task: Task, description: RobotDescription, distribution: PlantDistribution, *,
                 randomizer: Any = None, engine: Any = None, engine_options: dict[str, dict[str, Any]] | None = None,
                 plant_redraws: int = 0, **kwargs: Any) -> None:
        """``plant_redraws``: with an estimator in the loop, how many times a reset draws another plant
        (from the same generator: still reproducible) when the estimator cannot calibrate on the drawn one
        (``EstimatorCalibrationError``); 0: the error is raised. For training; an evaluation counts them."""
        if isinstance(plant_redraws, bool) or not isinstance(plant_redraws, int) or plant_redraws < 0:
            raise ValueError(f"plant_redraws must be an integer >= 0, got {plant_redraws!r}")
        self.plant_redraws = plant_redraws
        self.redrawn = 0  # resets that drew another plant, since construction
        if engine not in (None, "mujoco"):
            raise ValueError(f"a plant distribution runs on MuJoCo, got engine={engine!r}")
        if engine_options and set(engine_options) - {"mujoco"} or (engine_options or {}).get("mujoco", {}).get("model") is not None:
            raise ValueError("a plant distribution builds its own models: give no engine_options model")
        self.distribution = distribution
        self._description = description
        first = distribution.variants[int(np.argmax(distribution.probabilities))]
        options = {"mujoco": {**(engine_options or {}).get("mujoco", {}), **resolve_plant(description, None if first == NOMINAL else first).robot_options()}}
        self._extra_options = dict((engine_options or {}).get("mujoco", {}))
        # Always a randomizer (the distribution's entries at least): the robots are PerturbedRobots.
        super().__init__(task, description, engine="mujoco", engine_options=options, randomizer=randomizer or {"parameters": []}, **kwargs)
        assert self.randomizer is not None
        self._base_config: RandomizationConfig = self.randomizer.config
        self._pools: dict[str, EnginePool] = {first: self.engines}
        self._randomizers: dict[str, DomainRandomizer] = {}
        self.plant = first
        self.randomizer = self._randomizer_of(first)
        joints = description.joint_names
        self._legs = np.array([i for i, name in enumerate(joints) if re.fullmatch(_LEGS, name)], dtype=int)
        self._armature = np.array([j.armature for j in description.joints], dtype=float)
        self._privileged = np.zeros(len(self.privileged_names()))

    # --- the plant of an episode ----------------------------------------------------------------
    def _randomizer_of(self, name: str) -> DomainRandomizer:
        randomizer = self._randomizers.get(name)
        if randomizer is None:
            config = self.distribution.merged(self._base_config, self._description, name)
            randomizer = self._randomizers[name] = DomainRandomizer(config, self._description)
        return randomizer

    def _use_plant(self, name: str) -> None:
        """Run the task on variant ``name``'s robot (built, and its model compiled, on first use)."""
        pool = self._pools.get(name)
        if pool is None:
            plant = resolve_plant(self._description, None if name == NOMINAL else name)
            pool = self._pools[name] = EnginePool(self._description, "mujoco", options={"mujoco": {**self._extra_options, **plant.robot_options()}},
                                                  perturbed=True)
        self.randomizer = self._randomizer_of(name)
        if pool is not self.engines:
            self.engines = pool
            self._use_engine("mujoco")
            for attribute in ("_renderer", "_viewer"):  # built for the previous plant's model: rebuilt on the next frame
                view = getattr(self, attribute)
                if view is not None:
                    view.close()
                    setattr(self, attribute, None)
        self.plant = name

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            gymnasium.Env.reset(self, seed=seed)  # seed first: the plant is the episode's first draw
        for attempt in range(self.plant_redraws + 1):
            self._use_plant(self.distribution.draw(self.np_random))
            try:
                observation, info = super().reset(seed=None, options=options)
                break
            except EstimatorCalibrationError:
                if attempt == self.plant_redraws:
                    raise
                self.redrawn += 1
        self._privileged = self._measure_plant()
        info = {**info, "plant": self.plant, "privileged": self._privileged.copy(), "plant_redraws": attempt}
        return observation, info

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        if self._reset_done:
            info["plant"] = self.plant
            info["privileged"] = self._privileged.copy()  # a new array per call (gymnasium: infos never shared)
        return info

    # --- privileged plant parameters (never in the actor's observation) ---------------------------
    def privileged_names(self) -> tuple[str, ...]:
        """Names of ``info["privileged"]``'s entries."""
        joints = [self._description.joint_names[i] for i in getattr(self, "_legs", ())]
        return (*(f"plant/{v}" for v in self.distribution.variants), *(f"frictionloss/{j}" for j in joints),
                *(f"damping/{j}" for j in joints), *(f"armature_ratio/{j}" for j in joints), *(f"lag/{j}" for j in joints),
                "contact/timeconst", "contact/dampratio", "contact/friction", "imu_mounting/x", "imu_mounting/y", "imu_mounting/z")

    def _measure_plant(self) -> np.ndarray:
        """The plant as simulated this episode, read back from the engine (its model and actuators)."""
        robot = self.engine_robot
        model = robot.model
        legs = self._legs
        dofs = np.array([model.joint(self._description.joint_names[i]).dofadr[0] for i in legs], dtype=int)
        geom = int(np.flatnonzero((model.geom_contype != 0) | (model.geom_conaffinity != 0))[-1])
        dynamics = getattr(robot, "actuator_dynamics", None)
        actuated = np.flatnonzero(self._description.actuated)
        lag = np.zeros(self._description.dofs)
        if dynamics is not None:
            lag[actuated] = dynamics.lag
        episode = self.randomization.episode if self.randomization is not None else None
        mounting = episode["imu_mounting"] if episode is not None else np.zeros(3)
        onehot = np.array([float(v == self.plant) for v in self.distribution.variants])
        values = np.concatenate([onehot, model.dof_frictionloss[dofs], model.dof_damping[dofs],
                                 model.dof_armature[dofs] / np.maximum(self._armature[legs], 1e-12), lag[legs],
                                 model.geom_solref[geom], model.geom_friction[geom, :1], mounting])
        return values

    def close(self) -> None:
        for pool in self._pools.values():
            if pool is not self.engines:
                pool.close()
        super().close()


def is_distribution(plant: Any) -> bool:
    """Whether a ``plant=`` option names a distribution (``"random"``, a dict, a distribution TOML, a
    PlantDistribution) rather than one plant."""
    if isinstance(plant, (PlantDistribution, Mapping)) or (isinstance(plant, str) and plant == RANDOM):
        return True
    if isinstance(plant, (str, os.PathLike)) and str(plant).lower().endswith(".toml") and Path(plant).is_file():
        try:  # a variant file has tables such as [feet] or [joints]; a distribution file has its own
            table = load_toml(Path(plant), RandomizationError)
        except RandomizationError:
            return False
        return "plant_distribution" in table or "variants" in table
    return False


__all__ = ["PlantDistributionRuntime", "is_distribution"]
