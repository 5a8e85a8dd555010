"""Build the simulated plant of a variant: the description's MuJoCo model, changed as the variant says.

Geometry (feet), the IMU's mounting and the solver are set in the spec before compiling; joint
friction, damping, armature, effort limits and contact softness are written into the compiled
model by :func:`write_parameters`; per episode the randomizer writes them in place
(:mod:`giwbc.randomization.mujoco`; around a variant's own values:
:mod:`giwbc.randomization.plant_distribution`); actuator lag and the torque-speed envelope become
the robot's :class:`~giwbc.robot.actuator_dynamics.ActuatorDynamics`, applied per physics step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from giwbc.errors import PlantMismatchError
from giwbc.plants.variant import PlantVariant
from giwbc.robot.actuator_dynamics import ActuatorDynamics
from giwbc.robot.description import RobotDescription
from giwbc.robot.mujoco_model import COLLISION_BIT, SOLE_THICKNESS, build_mujoco_spec
from giwbc.robot.mujoco_plant import PlantBinding, bind

_SQRT_HALF = math.sqrt(0.5)
_ALONG_X = [_SQRT_HALF, 0.0, _SQRT_HALF, 0.0]  # a capsule's z axis turned onto x
_ALONG_Y = [_SQRT_HALF, -_SQRT_HALF, 0.0, 0.0]  # ... onto y


@dataclass(frozen=True)
class Plant:
    """A simulated plant: the model a :class:`~giwbc.robot.mujoco_robot.MujocoRobot` steps, and its actuators."""

    name: str
    model: mujoco.MjModel
    actuator_dynamics: ActuatorDynamics | None = None
    variant: PlantVariant | None = None  # None: a plant built elsewhere (an MJCF file, an MjModel)

    def robot_options(self) -> dict[str, object]:
        """Keywords for ``MujocoRobot(description, **options)`` (a copy of the model: robots never share one)."""
        import copy

        return {"model": copy.copy(self.model), "actuator_dynamics": self.actuator_dynamics}


def sole_points(description: RobotDescription, variant: PlantVariant, contact: str) -> np.ndarray:
    """(n, 3) points of the variant's sole that touch a flat floor, in the foot link's frame."""
    rectangle = description.contact(contact)
    points = variant.feet.sole_points(rectangle.half_length, rectangle.half_width)
    center = np.asarray(rectangle.center, dtype=float)
    return np.column_stack([points + center[:2], np.full(len(points), center[2])])


def _add_feet(spec: mujoco.MjSpec, description: RobotDescription, variant: PlantVariant) -> None:
    feet = variant.feet
    if feet.shape == "box":
        return
    friction = list(variant.friction or (description.floor_friction, 0.005, 0.0001))
    for contact in description.contacts:
        spec.delete(spec.geom(f"{contact.name}_sole"))
        body = spec.body(contact.link)
        cx, cy, sole = contact.center
        r, hl, hw = feet.radius, contact.half_length, contact.half_width
        if r >= min(hl, hw):
            raise PlantMismatchError(f"plant variant {variant.name!r}: foot radius {r} m does not fit the {2 * hl} x {2 * hw} m sole")
        shapes: list[tuple[mujoco.mjtGeom, list[float], list[float], list[float]]] = []  # type, size, pos, quat
        if feet.shape == "rounded_box":
            shapes.append((mujoco.mjtGeom.mjGEOM_BOX, [hl - r, hw - r, SOLE_THICKNESS], [cx, cy, sole + SOLE_THICKNESS], [1, 0, 0, 0]))
            for y in (hw - r, -(hw - r)):
                shapes.append((mujoco.mjtGeom.mjGEOM_CAPSULE, [r, hl - r, 0], [cx, cy + y, sole + r], _ALONG_X))
            for x in (hl - r, -(hl - r)):
                shapes.append((mujoco.mjtGeom.mjGEOM_CAPSULE, [r, hw - r, 0], [cx + x, cy, sole + r], _ALONG_Y))
        elif feet.shape == "capsules":
            ys = [hw - r, -(hw - r)] if feet.count == 2 else [hw - r, 0.0, -(hw - r)]
            for y in ys:
                shapes.append((mujoco.mjtGeom.mjGEOM_CAPSULE, [r, hl - r, 0], [cx, cy + y, sole + r], _ALONG_X))
        else:  # corner_spheres, points
            for x, y in feet.sole_points(hl, hw):
                shapes.append((mujoco.mjtGeom.mjGEOM_SPHERE, [r, 0, 0], [cx + x, cy + y, sole + r], [1, 0, 0, 0]))
        for index, (kind, size, pos, quat) in enumerate(shapes):
            body.add_geom(name=f"{contact.name}_sole_{index}", type=kind, size=size, pos=pos, quat=quat, contype=COLLISION_BIT,
                          conaffinity=COLLISION_BIT, condim=3, friction=friction, group=3, rgba=[0.8, 0.3, 0.2, 0.4])


def _mount_imu(spec: mujoco.MjSpec, variant: PlantVariant) -> None:
    if not any(variant.imu_rotation) and not any(variant.imu_offset):
        return
    site = spec.site("imu")
    if site is None:
        raise PlantMismatchError(f"plant variant {variant.name!r}: an IMU mounting error needs the robot's IMU")
    roll, pitch, yaw = np.radians(variant.imu_rotation)
    quat = np.empty(4)
    mujoco.mju_euler2Quat(quat, np.array([roll, pitch, yaw]), "XYZ")
    site.pos = np.asarray(site.pos, dtype=float) + np.asarray(variant.imu_offset)
    site.quat = quat


def contact_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Every geom that collides (feet, floor, whole-body shapes)."""
    return np.flatnonzero((model.geom_contype != 0) | (model.geom_conaffinity != 0))


def write_parameters(model: mujoco.MjModel, binding: PlantBinding, description: RobotDescription, variant: PlantVariant) -> None:
    """Write the variant's in-place parameters over ``model`` (from the description's nominal values):
    contact softness and friction, joint friction loss, damping, armature, effort limits, solver iterations."""
    names = description.joint_names
    dofs = binding.dofs
    model.dof_frictionloss[dofs] = variant.per_joint("frictionloss", names)
    model.dof_damping[dofs] = variant.per_joint("damping", names)
    model.dof_armature[dofs] = variant.per_joint("armature_scale", names) * np.array([j.armature for j in description.joints])
    effort = (variant.per_joint("effort_scale", names) * description.effort_limits)[description.actuated]
    model.actuator_forcerange[binding.actuators] = np.stack([-effort, effort], axis=1)
    geoms = contact_geoms(model)
    model.geom_solref[geoms] = variant.solref
    model.geom_solimp[geoms] = variant.solimp
    model.geom_friction[geoms] = variant.friction or (description.floor_friction, 0.005, 0.0001)
    model.opt.iterations = variant.iterations or 100
    model.opt.ls_iterations = variant.ls_iterations or 50


def actuator_dynamics(description: RobotDescription, variant: PlantVariant) -> ActuatorDynamics | None:
    """The variant's lag and torque-speed envelope over the actuated joints (None when it has neither)."""
    names, actuated = description.joint_names, description.actuated
    dynamics = ActuatorDynamics(
        variant.per_joint("lag", names)[actuated],
        (variant.per_joint("effort_scale", names) * description.effort_limits)[actuated],
        variant.per_joint("knee_speed", names)[actuated],
        variant.per_joint("no_load_speed", names)[actuated],
    )
    return dynamics if dynamics.active else None


def build_plant(description: RobotDescription, variant: PlantVariant | None = None) -> Plant:
    """The simulated plant of ``variant`` (the nominal plant without one)."""
    variant = variant or PlantVariant()
    for parameter in [*variant.joints, *variant.actuators]:
        variant.per_joint(parameter, description.joint_names)
    spec = build_mujoco_spec(description)
    _add_feet(spec, description, variant)
    _mount_imu(spec, variant)
    try:
        model = spec.compile()
    except Exception as error:
        raise PlantMismatchError(f"plant variant {variant.name!r}: MuJoCo cannot compile it: {str(error).splitlines()[0]}") from error
    binding = bind(description, model, f"plant variant {variant.name!r}")
    write_parameters(model, binding, description, variant)
    mujoco.mj_setConst(model, mujoco.MjData(model))  # armature changed: the constants MuJoCo derives at compile time
    return Plant(variant.name, model, actuator_dynamics(description, variant), variant)
