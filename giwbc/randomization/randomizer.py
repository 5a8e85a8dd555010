"""The domain randomizer a runtime calls at every reset, with its seeded generator."""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

import numpy as np

from giwbc.randomization.config import RandomizationConfig
from giwbc.randomization.distributions import RandomizationError
from giwbc.randomization.mujoco import MujocoApplier
from giwbc.randomization.perturbed import PerturbedRobot
from giwbc.randomization.sampling import Sample, sample_group
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import Robot

DEFAULT_CONFIG_NAME = "randomization.toml"  # in a robot's folder: what ``"default"`` names

RandomizerSpec = Union["DomainRandomizer", RandomizationConfig, dict, str, os.PathLike, None]


@dataclass(frozen=True)
class Randomization:
    """What :meth:`DomainRandomizer.randomize` drew: the physics sample (possibly an earlier
    episode's) and this episode's sample, and whether the physics was resampled now."""

    physics: Sample
    episode: Sample
    resampled: bool


class DomainRandomizer:
    """Samples a config at each reset and applies it to a robot (MuJoCo or PyBullet, bare or perturbed).

    Physics parameters are resampled every ``config.physics_every`` calls (the first call always
    samples) and written over the engine's nominal model; episode parameters are resampled at
    every call. Everything is drawn from the ``rng`` passed in, in a fixed order, so equal seeds
    give equal samples. Robot-level parameters (latency, gain scales, noise, pushes) need the robot
    to be a :class:`PerturbedRobot`; randomizing them on a bare engine robot is an error.
    """

    def __init__(self, config: RandomizationConfig | dict[str, Any], description: RobotDescription) -> None:
        self.config = config if isinstance(config, RandomizationConfig) else RandomizationConfig.from_dict(config, description)
        self.description = description
        self.episodes = 0
        self.physics: Sample | None = None
        self._appliers: weakref.WeakKeyDictionary[Any, Any] = weakref.WeakKeyDictionary()

    def sample(self, rng: np.random.Generator) -> Randomization:
        """Draw this reset's samples without applying them."""
        resampled = self.physics is None or self.episodes % self.config.physics_every == 0
        if resampled:
            self.physics = sample_group(self.config, "physics", rng)
        self.episodes += 1
        return Randomization(self.physics, sample_group(self.config, "episode", rng), resampled)

    def randomize(self, robot: Robot, rng: np.random.Generator) -> Randomization:
        """Sample and apply; call it before ``robot.reset(...)`` (PyBullet may reload the robot)."""
        drawn = self.sample(rng)
        self.apply(robot, drawn)
        return drawn

    def apply(self, robot: Robot, drawn: Randomization) -> None:
        engine = robot.robot if isinstance(robot, PerturbedRobot) else robot
        self._applier(engine).apply(drawn.physics)
        if isinstance(robot, PerturbedRobot):
            robot.set_perturbations(drawn.physics, drawn.episode)
            return
        robot_level = {"actuator_latency", "kp_scale", "kd_scale"} & drawn.physics.randomized | drawn.episode.randomized
        if robot_level:
            raise RandomizationError(
                f"randomizing {sorted(robot_level)} needs the robot wrapped in giwbc.randomization.PerturbedRobot"
            )

    def restore(self, robot: Robot) -> None:
        """The nominal model and no perturbation."""
        engine = robot.robot if isinstance(robot, PerturbedRobot) else robot
        self._applier(engine).restore()
        if isinstance(robot, PerturbedRobot):
            robot.set_perturbations(None, None)

    def _applier(self, engine: Robot) -> Any:
        applier = self._appliers.get(engine)
        if applier is None:
            applier = make_applier(engine, self.config)
            self._appliers[engine] = applier
        return applier


def make_applier(engine: Robot, config: RandomizationConfig) -> Any:
    """The physics applier of an engine robot (it snapshots the nominal model now)."""
    model = getattr(engine, "model", None)
    if model is not None and hasattr(model, "opt"):
        description = getattr(engine, "description", None)
        return MujocoApplier(model, config.nominal, engine.floating_base, getattr(description, "urdf_path", None),
                             engine if hasattr(engine, "set_actuator_dynamics") else None)
    from giwbc.robot.pybullet_robot import PybulletRobot  # optional heavy dependency (imports pybullet)

    if isinstance(engine, PybulletRobot):
        from giwbc.randomization.pybullet import PybulletApplier  # optional heavy dependency (pybullet)


        return PybulletApplier(engine, config.nominal)
    raise RandomizationError(f"cannot randomize the physics of {type(engine).__name__}: not a MuJoCo or PyBullet robot")


def default_config_path(description: RobotDescription) -> Path:
    """The robot's shipped randomization config (``robots/<name>/randomization.toml``)."""
    return Path(description.folder) / DEFAULT_CONFIG_NAME


def make_randomizer(spec: RandomizerSpec, description: RobotDescription) -> DomainRandomizer | None:
    """A randomizer from what a user gives: a DomainRandomizer (as is), a RandomizationConfig, a config
    dict, a TOML file path (or TOML text), ``"default"`` (the robot's shipped config), or ``None``."""
    if spec is None or isinstance(spec, DomainRandomizer):
        return spec
    if isinstance(spec, (RandomizationConfig, dict)):
        return DomainRandomizer(spec, description)
    if isinstance(spec, (str, os.PathLike)):
        if spec == "default":
            spec = default_config_path(description)
            if not spec.is_file():
                raise RandomizationError(f"robot {description.name!r} ships no default randomization config ({spec} is missing)")
        text = str(spec)
        if "\n" not in text and "=" not in text and not Path(text).is_file():
            raise RandomizationError(f"randomization config file {text!r} does not exist")
        return DomainRandomizer(RandomizationConfig.from_toml(spec, description), description)
    raise RandomizationError(
        f"randomization must be a config dict, a TOML path, 'default', a RandomizationConfig or a DomainRandomizer, got {type(spec).__name__}"
    )
