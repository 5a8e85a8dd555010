"""Simulated plants that differ from the controller's model: named variants, your own MJCF, randomization.

giwbc's controllers are built from the robot description (Pinocchio); the plant they run on in
simulation is a MuJoCo model. By default that model is built from the same description (box feet,
frictionless joints, the description's armature). A **plant** here is anything else to run on:

- a **variant** (:class:`PlantVariant`): the description's model with documented changes in
  physical units: foot collision shape, contact softness and friction, joint friction loss and
  damping, armature and effort per joint group, actuator lag and torque-speed envelope, solver
  iterations, the IMU's mounting error. Named variants ship as ``robots/<robot>/plants/<name>.toml``;
- an **MJCF file** or an ``MjModel`` of the same robot built elsewhere (a vendor's): bound to the
  description by name and checked (:mod:`giwbc.robot.mujoco_plant`).

Use::

    from giwbc.plants import resolve_plant, plant_robot, available_variants, sole_points
    available_variants(description)                  # ['all_at_once', 'capsule_feet', ...]
    plant = resolve_plant(description, "point_feet")  # a name, a variant .toml, an MJCF .xml, an MjModel, a PlantVariant
    robot = plant_robot(description, "point_feet")    # a MujocoRobot on that plant (lag and envelope applied per step)
    plant.variant.feet.shape, sole_points(description, plant.variant, "left_foot")  # (n, 3) sole points, foot link frame
    MujocoRobot(description, **plant.robot_options())  # the same, by hand (or engine_options={"mujoco": ...})

Per episode (engine level, in place, from a seeded generator): the randomization parameters
``joint_friction``, ``joint_damping``, ``joint_armature``, ``actuator_strength``, ``ground_friction``,
``contact_timeconst``, ``contact_dampratio``, ``solver_iterations``, ``actuator_lag`` and ``imu_mounting``
(:data:`giwbc.randomization.PARAMETERS`) vary a plant around any of these; the foot shape changes
the model's geometry, so it is a plant (a variant) rather than a per-episode draw. A plant drawn per
episode among the variants, its parameters randomized around the drawn variant's own values, is
:class:`giwbc.randomization.plant_distribution.PlantDistribution` (``plant="random"`` in the envs).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import mujoco

from giwbc.errors import PlantMismatchError
from giwbc.plants.build import Plant, actuator_dynamics, build_plant, contact_geoms, sole_points, write_parameters
from giwbc.plants.variant import FOOT_SHAPES, FootShape, PlantVariant, load_variant, variant_from_dict
from giwbc.robot.description import RobotDescription
from giwbc.robot.mujoco_plant import plant_from_file
from giwbc.robot.mujoco_robot import MujocoRobot

PLANTS_FOLDER = "plants"  # in a robot's folder: the shipped named variants
NOMINAL = "nominal"
MJCF_SUFFIXES = (".xml", ".mjcf")

PlantSpec = Union[str, os.PathLike, mujoco.MjModel, PlantVariant, Plant, None]


def variants_folder(description: RobotDescription) -> Path:
    return Path(description.folder) / PLANTS_FOLDER


def available_variants(description: RobotDescription) -> list[str]:
    """Names of the robot's shipped variants (sorted), ``"nominal"`` not included."""
    folder = variants_folder(description)
    return sorted(path.stem for path in folder.glob("*.toml")) if folder.is_dir() else []


def named_variant(description: RobotDescription, name: str) -> PlantVariant:
    """A shipped variant by name (``"nominal"``: no change)."""
    if name == NOMINAL:
        return PlantVariant()
    path = variants_folder(description) / f"{name}.toml"
    if not path.is_file():
        raise PlantMismatchError(f"unknown plant {name!r} for robot {description.name!r}; variants: {[NOMINAL, *available_variants(description)]}, or an MJCF file")
    return load_variant(path)


def resolve_plant(description: RobotDescription, plant: PlantSpec) -> Plant:
    """A plant from what a user gives: None or ``"nominal"``, a variant name, a variant ``.toml``, an MJCF
    file (``.xml``), an ``MjModel``, a :class:`PlantVariant` or a :class:`Plant`."""
    if plant is None:
        return build_plant(description)
    if isinstance(plant, Plant):
        return plant
    if isinstance(plant, PlantVariant):
        return build_plant(description, plant)
    if isinstance(plant, mujoco.MjModel):
        return Plant("model", plant)
    if isinstance(plant, (str, os.PathLike)):
        path = Path(plant)
        if path.suffix.lower() in MJCF_SUFFIXES:
            return Plant(path.stem, plant_from_file(description, path))
        if path.suffix.lower() == ".toml":
            if not path.is_file():
                raise PlantMismatchError(f"plant variant file {path} does not exist")
            return build_plant(description, load_variant(path))
        return build_plant(description, named_variant(description, str(plant)))
    raise PlantMismatchError(f"a plant is a variant name, a .toml or MJCF path, an MjModel or a PlantVariant, got {type(plant).__name__}")


def plant_robot(description: RobotDescription, plant: PlantSpec) -> MujocoRobot:
    """A :class:`MujocoRobot` of ``description`` stepping ``plant``."""
    return MujocoRobot(description, **resolve_plant(description, plant).robot_options())  # type: ignore[arg-type]


def plant_label(plant: PlantSpec) -> str:
    """A short name for reports."""
    if plant is None:
        return NOMINAL
    if isinstance(plant, (Plant, PlantVariant)):
        return plant.name
    if isinstance(plant, mujoco.MjModel):
        return "model"
    return Path(plant).stem if isinstance(plant, os.PathLike) or str(plant).lower().endswith((*MJCF_SUFFIXES, ".toml")) else str(plant)


__all__ = [
    "FOOT_SHAPES",
    "NOMINAL",
    "FootShape",
    "Plant",
    "PlantSpec",
    "PlantVariant",
    "actuator_dynamics",
    "available_variants",
    "build_plant",
    "contact_geoms",
    "load_variant",
    "named_variant",
    "plant_label",
    "plant_robot",
    "resolve_plant",
    "sole_points",
    "variant_from_dict",
    "write_parameters",
]
