"""Domain randomization: physics parameters, sensors, actuators, pushes, and the engine itself.

In an environment: ``gymnasium.make(env_id, randomization=config, engine=...)`` (a config dict, a
TOML path, ``"default"`` for the robot's ``randomization.toml``); the simulated runtime samples
and applies it at every reset from its seeded generator. By hand (see :class:`DomainRandomizer`)::

    randomizer = DomainRandomizer(config_dict, description)   # validated here, errors name the entry
    robot = PerturbedRobot(MujocoRobot(description))           # or PybulletRobot(description)
    ...
    drawn = randomizer.randomize(robot, self.np_random)        # at reset, before robot.reset(...)
    robot.reset(q0)

Physics parameters change the engine's model in place from its nominal values (MuJoCo arrays,
PyBullet ``changeDynamics``); the Pinocchio model of the controller stays nominal unless
:func:`randomized_pinocchio_model` is used.
"""

from giwbc.randomization.config import Entry, RandomizationConfig
from giwbc.randomization.distributions import Distribution, RandomizationError
from giwbc.randomization.engine import ENGINES, EngineChoice, build_robot
from giwbc.randomization.parameters import PARAMETERS, Nominal, ParameterSpec
from giwbc.randomization.perturbed import PerturbedRobot
from giwbc.randomization.pinocchio import randomized_pinocchio_model
from giwbc.randomization.randomizer import DomainRandomizer, Randomization, default_config_path, make_applier, make_randomizer
from giwbc.randomization.sampling import Push, Sample, sample_group


__all__ = [
    "ENGINES",
    "PARAMETERS",
    "DomainRandomizer",
    "Distribution",
    "EngineChoice",
    "Entry",
    "Nominal",
    "ParameterSpec",
    "PerturbedRobot",
    "Push",
    "RandomizationConfig",
    "RandomizationError",
    "Randomization",
    "Sample",
    "build_robot",
    "default_config_path",
    "make_applier",
    "make_randomizer",
    "randomized_pinocchio_model",
    "sample_group",
]
