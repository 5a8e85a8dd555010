"""A distribution over simulated plants: per episode, one plant variant (foot shape, joints, actuators,
contacts, IMU mounting) drawn by weight, its physical parameters then randomized around the variant's
own values. For training and evaluating a policy on plants the controller was not built for.

A variant's geometry (its feet) needs its own compiled ``MjModel``; the parameters (joint friction,
damping, armature, contact softness, actuator lag, IMU mounting, ...) are written in place into that
model at every reset by the ordinary :class:`~giwbc.randomization.DomainRandomizer` machinery, whose
``scale`` / ``add`` operations act on the **variant's** values here (:func:`variant_nominal`): a
``joint_friction`` entry adding U(0, 0.5) N m gives 0-0.5 N m on the nominal plant and 1.2-1.7 N m on
a knee of ``frictional_joints``.

As a dict (or TOML under an optional ``[plant_distribution]`` table; the G1's shipped one is
``robots/g1/plant_distribution.toml``, what ``plant="random"`` names)::

    {
        "description": "what it models",
        "variants": {"nominal": 1.0, "capsule_feet": 1.0, "all_at_once": 0.5},  # relative weights
        "parameters": [  # randomization entries (giwbc.randomization.config), around the variant's values
            {"parameter": "joint_friction", "distribution": "uniform", "low": 0.0, "high": 0.5,
             "operation": "add", "regex": ".*_(hip|knee)_.*"},
            {"parameter": "contact_timeconst", "distribution": "loguniform", "low": 0.7, "high": 1.5,
             "operation": "scale"},
        ],
    }

Every draw (the variant, then the parameters) comes from the environment's seeded generator, in a
fixed order: the same seed gives the same plant, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

import numpy as np

from giwbc.errors import PlantMismatchError, RandomizationError
from giwbc.plants import NOMINAL, available_variants, named_variant
from giwbc.plants.variant import PlantVariant
from giwbc.randomization.config import RandomizationConfig
from giwbc.randomization.parameters import PARAMETERS, Nominal
from giwbc.robot.description import RobotDescription
from giwbc.util.toml import load_toml

RANDOM = "random"  # plant="random": the robot's shipped distribution
DEFAULT_DISTRIBUTION_NAME = "plant_distribution.toml"  # in a robot's folder
_KEYS = {"description", "variants", "parameters"}
# What a variant changes that a randomization parameter also describes (the rest keep the description's nominal).
VARIANT_PARAMETERS = ("joint_friction", "joint_damping", "joint_armature", "actuator_strength", "ground_friction",
                      "contact_timeconst", "contact_dampratio", "solver_iterations", "actuator_lag")

DistributionSpec = Union["PlantDistribution", Mapping[str, Any], str, os.PathLike, None]


def variant_nominal(description: RobotDescription, variant: PlantVariant, base: Nominal | None = None) -> Nominal:
    """The randomization's nominal values with the variant's own in place of the description's
    (joint friction, damping, armature, effort, floor friction, contact softness, solver, actuator lag)."""
    base = base or Nominal.from_description(description)
    names = description.joint_names
    armature = np.array([j.armature for j in description.joints], dtype=float)
    own = {
        "joint_friction": variant.per_joint("frictionloss", names),
        "joint_damping": variant.per_joint("damping", names),
        "joint_armature": variant.per_joint("armature_scale", names) * armature,
        "actuator_strength": variant.per_joint("effort_scale", names) * np.asarray(description.effort_limits, dtype=float),
        "ground_friction": np.array([(variant.friction or (description.floor_friction,))[0]], dtype=float),
        "contact_timeconst": np.array([variant.solref[0]], dtype=float),
        "contact_dampratio": np.array([variant.solref[1]], dtype=float),
        "solver_iterations": np.array([float(variant.iterations or 100)]),
        "actuator_lag": variant.per_joint("lag", names),
    }
    values = dict(base.values)
    for name, array in own.items():
        array = np.array(array, dtype=float).reshape(base.values[name].shape)
        array.flags.writeable = False
        values[name] = array
    return dataclasses.replace(base, values=values)


@dataclass(frozen=True)
class PlantDistribution:
    """Variants with their probabilities, and the parameter entries randomized around each (module docstring)."""

    variants: tuple[str, ...]
    probabilities: np.ndarray
    config: RandomizationConfig  # the parameter entries (physics group), nominal: the description's
    description: str = ""

    @classmethod
    def from_dict(cls, table: Mapping[str, Any], robot: RobotDescription, where: str = "plant distribution") -> "PlantDistribution":
        if not isinstance(table, Mapping):
            raise RandomizationError(f"{where}: a plant distribution is a table, got {type(table).__name__}")
        table = table.get("plant_distribution", table)
        unknown = sorted(set(table) - _KEYS)
        if unknown:
            raise RandomizationError(f"{where}: unknown key(s) {unknown}; expected {sorted(_KEYS)}")
        weights = table.get("variants")
        if not isinstance(weights, Mapping) or not weights:
            raise RandomizationError(f"{where}: 'variants' must be a table of variant name = weight (at least one)")
        known = [NOMINAL, *available_variants(robot)]
        for name, weight in weights.items():
            if name not in known:
                raise RandomizationError(f"{where}: unknown variant {name!r}; the robot's: {known}")
            if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (weight >= 0 and math.isfinite(weight)):
                raise RandomizationError(f"{where}: the weight of {name!r} must be a finite number >= 0, got {weight!r}")
        total = float(sum(weights.values()))
        if total <= 0:
            raise RandomizationError(f"{where}: the variants' weights sum to 0")
        entries = table.get("parameters", [])
        config = RandomizationConfig.from_dict({"parameters": entries}, robot)
        episode = sorted(p for p in config.parameters if PARAMETERS[p].group != "physics" and p != "imu_mounting")
        if episode:
            raise RandomizationError(f"{where}: {episode} are not plant parameters (sensor noise and pushes go in randomization=)")
        names = tuple(weights)
        return cls(names, np.array([float(weights[n]) / total for n in names]), config, str(table.get("description", "")))

    @classmethod
    def load(cls, spec: DistributionSpec, robot: RobotDescription) -> "PlantDistribution":
        """From ``"random"`` (the robot's ``plant_distribution.toml``), a TOML path, a dict or a PlantDistribution."""
        if isinstance(spec, PlantDistribution):
            return spec
        if isinstance(spec, Mapping):
            return cls.from_dict(spec, robot)
        if spec is None or str(spec) == RANDOM:
            path = Path(robot.folder) / DEFAULT_DISTRIBUTION_NAME
            if not path.is_file():
                raise RandomizationError(f"robot {robot.name!r} ships no plant distribution ({path} is missing)")
        else:
            path = Path(spec)
            if not path.is_file():
                raise RandomizationError(f"plant distribution file {path} does not exist")
        return cls.from_dict(load_toml(path, RandomizationError), robot, str(path))

    def draw(self, rng: np.random.Generator) -> str:
        """One variant's name (one uniform draw from ``rng``)."""
        index = int(np.searchsorted(np.cumsum(self.probabilities), rng.uniform(), side="right"))
        return self.variants[min(index, len(self.variants) - 1)]

    def variant(self, robot: RobotDescription, name: str) -> PlantVariant:
        try:
            return named_variant(robot, name)
        except PlantMismatchError as error:
            raise RandomizationError(str(error)) from None

    def merged(self, base: RandomizationConfig | None, robot: RobotDescription, name: str) -> RandomizationConfig:
        """The randomization of an episode on variant ``name``: ``base``'s entries (the env's
        ``randomization=`` and sim2real knobs) then this distribution's, all around the variant's values."""
        nominal = variant_nominal(robot, self.variant(robot, name), base.nominal if base is not None else None)
        if base is None:
            return dataclasses.replace(self.config, nominal=nominal)
        if base.physics_every != 1:
            raise RandomizationError("a plant distribution draws the plant at every reset: the randomization's physics_every must be 1")
        return dataclasses.replace(base, entries=base.entries + self.config.entries, nominal=nominal)


__all__ = ["DEFAULT_DISTRIBUTION_NAME", "RANDOM", "VARIANT_PARAMETERS", "DistributionSpec", "PlantDistribution", "variant_nominal"]
