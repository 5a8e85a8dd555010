"""Build the MuJoCo model of a robot description from the same URDF as the Pinocchio model.

What the builder adds to the URDF (through ``mujoco.MjSpec``): a free joint for a floating base,
a floor, one impedance actuator per actuated joint (force = ctrl + bias, the bias holding
``-kp q - kd qdot`` so torque and MIT-style impedance commands share one actuator and the implicit
integrator sees the damping), box collision geometry for the feet and the description's primitive
whole-body shapes (meshes stay visual only), self-collision exclusions between adjacent collision
bodies, IMU sensors at the IMU frame, and force/torque/touch sensors at each foot.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from giwbc.errors import RobotDescriptionError
from giwbc.robot.collision import CollisionShape

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

SOLE_THICKNESS = 0.01  # half-height of a foot collision box below... above the sole plane, m
MUJOCO_COMPILER = '<mujoco><compiler fusestatic="false" discardvisual="false" strippath="false" balanceinertia="false"/></mujoco>'
COLLISION_BIT = 1  # every colliding geom, as MuJoCo's defaults (contype = conaffinity = 1)
ROBOT_ONLY_BIT = 2  # the robot's contype when self-collision is off: it then meets the floor (affinity 1|2), not itself
GEOM_TYPES = {"box": mujoco.mjtGeom.mjGEOM_BOX, "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}


def imu_sensor_names() -> dict[str, str]:
    """MuJoCo sensor names of the IMU channels."""
    return {"quaternion": "imu_quat", "angular_velocity": "imu_gyro", "linear_acceleration": "imu_accel"}


def foot_sensor_names(contact_name: str) -> dict[str, str]:
    return {"force": f"{contact_name}_force", "torque": f"{contact_name}_torque", "touch": f"{contact_name}_touch"}


def _inject_compiler(urdf: str) -> str:
    match = re.search(r"<robot\b[^>]*>", urdf)
    if match is None:
        raise RobotDescriptionError("URDF has no <robot> element")
    return urdf[: match.end()] + MUJOCO_COMPILER + urdf[match.end():]


def _spec_from_description(description: RobotDescription) -> mujoco.MjSpec:
    try:
        spec = mujoco.MjSpec.from_string(_inject_compiler(description.urdf_text()))
    except Exception as error:  # mujoco raises ValueError/RuntimeError with the parser's message
        raise RobotDescriptionError(f"{description.urdf_path}: MuJoCo cannot parse the URDF: {error}") from error
    spec.modelname = description.name
    spec.option.timestep = description.timestep
    spec.option.integrator = {
        "euler": mujoco.mjtIntegrator.mjINT_EULER,
        "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
        "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
        "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    }[description.integrator]
    return spec


def _disable_urdf_collisions(spec: mujoco.MjSpec) -> None:
    """URDF geoms stay visual; collisions come from the primitives added here."""
    for geom in spec.geoms:
        geom.contype = 0
        geom.conaffinity = 0
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
            geom.group = 2  # visual group


def _add_world(spec: mujoco.MjSpec, description: RobotDescription) -> None:
    world = spec.worldbody
    world.add_light(name="sun", pos=[0, 0, 3], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    if description.floating_base:
        world.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[0, 0, 0.05],
            friction=[description.floor_friction, 0.005, 0.0001],
            contype=COLLISION_BIT,
            conaffinity=COLLISION_BIT | ROBOT_ONLY_BIT,
            rgba=[0.45, 0.5, 0.55, 1],
        )


def _add_feet(spec: mujoco.MjSpec, description: RobotDescription) -> None:
    for contact in description.contacts:
        body = spec.body(contact.link)
        center = np.asarray(contact.center, dtype=float)
        body.add_geom(
            name=f"{contact.name}_sole",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[contact.half_length, contact.half_width, SOLE_THICKNESS],
            pos=center + [0, 0, SOLE_THICKNESS],
            contype=COLLISION_BIT,
            conaffinity=COLLISION_BIT,
            condim=3,
            friction=[description.floor_friction, 0.005, 0.0001],
            group=3,
            rgba=[0.8, 0.3, 0.2, 0.4],
        )
        # Touch needs a site volume; force/torque sensors sit at the sole center.
        body.add_site(
            name=f"{contact.name}_touch_site",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[contact.half_length + 0.005, contact.half_width + 0.005, SOLE_THICKNESS + 0.005],
            pos=center + [0, 0, SOLE_THICKNESS],
            group=4,
        )
        body.add_site(name=f"{contact.name}_sole_site", pos=center, group=4)
        names = foot_sensor_names(contact.name)
        for kind, sensor_type, site in [
            ("force", mujoco.mjtSensor.mjSENS_FORCE, f"{contact.name}_sole_site"),
            ("torque", mujoco.mjtSensor.mjSENS_TORQUE, f"{contact.name}_sole_site"),
            ("touch", mujoco.mjtSensor.mjSENS_TOUCH, f"{contact.name}_touch_site"),
        ]:
            spec.add_sensor(name=names[kind], type=sensor_type, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site)


def _add_body_shapes(spec: mujoco.MjSpec, description: RobotDescription) -> None:
    """Primitive whole-body collision geoms, and exclusions for adjacent collision bodies."""
    friction = [description.floor_friction, 0.005, 0.0001]
    for shape in description.collision:
        _add_shape(spec, shape, friction)
    if not description.self_collision:
        for geom in spec.geoms:
            if geom.contype & COLLISION_BIT and geom.name != "floor":
                geom.contype = ROBOT_ONLY_BIT
        return
    for a, b in sorted(description.self_collision_exclusions):
        spec.add_exclude(bodyname1=a, bodyname2=b)


def _add_shape(spec: mujoco.MjSpec, shape: CollisionShape, friction: list[float]) -> None:
    try:
        body = spec.body(shape.link)
    except Exception:
        body = None
    if body is None:
        raise RobotDescriptionError(f"collision shape {shape.name!r}: MuJoCo model has no body {shape.link!r}")
    size = list(shape.size) + [0.0] * (3 - len(shape.size))
    body.add_geom(
        name=shape.name,
        type=GEOM_TYPES[shape.kind],
        size=size,
        pos=list(shape.position),
        quat=list(shape.quaternion),
        contype=COLLISION_BIT,
        conaffinity=COLLISION_BIT,
        condim=3,
        friction=friction,
        group=3,
        rgba=[0.3, 0.5, 0.8, 0.4],
    )


def _add_imu(spec: mujoco.MjSpec, description: RobotDescription) -> None:
    if description.imu_frame is None:
        return
    spec.body(description.imu_frame).add_site(name="imu", group=4)
    names = imu_sensor_names()
    for kind, sensor_type in [
        ("quaternion", mujoco.mjtSensor.mjSENS_FRAMEQUAT),
        ("angular_velocity", mujoco.mjtSensor.mjSENS_GYRO),
        ("linear_acceleration", mujoco.mjtSensor.mjSENS_ACCELEROMETER),
    ]:
        spec.add_sensor(name=names[kind], type=sensor_type, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")


def _configure_joints(spec: mujoco.MjSpec, description: RobotDescription) -> None:
    for joint_spec in description.joints:
        joint = spec.joint(joint_spec.name)
        joint.armature = joint_spec.armature
        joint.damping = np.zeros(3)
        joint.frictionloss = 0.0
        if joint_spec.unbounded:
            joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        if joint_spec.actuated:
            spec.add_actuator(
                name=joint_spec.name,
                target=joint_spec.name,
                trntype=mujoco.mjtTrn.mjTRN_JOINT,
                gaintype=mujoco.mjtGain.mjGAIN_FIXED,
                gainprm=[1.0] + [0.0] * 9,
                biastype=mujoco.mjtBias.mjBIAS_AFFINE,
                biasprm=[0.0] * 10,
                forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
                forcerange=[-joint_spec.effort, joint_spec.effort],
                ctrllimited=mujoco.mjtLimited.mjLIMITED_FALSE,
            )


def build_mujoco_spec(description: RobotDescription) -> mujoco.MjSpec:
    """The editable MuJoCo spec (before compilation) of a robot description."""
    spec = _spec_from_description(description)
    _disable_urdf_collisions(spec)
    try:
        root = spec.body(description.base_link)
    except Exception:
        root = None
    if root is None:
        raise RobotDescriptionError(f"{description.urdf_path}: MuJoCo model has no body {description.base_link!r}")
    if description.floating_base:
        root.add_freejoint(name="floating_base")
        root.pos = description.default_base_position
    _add_world(spec, description)
    _add_feet(spec, description)
    _add_body_shapes(spec, description)
    _add_imu(spec, description)
    _configure_joints(spec, description)
    spec.worldbody.add_camera(
        name="track", mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, pos=[0.0, -3.0, 1.0], xyaxes=[1, 0, 0, 0, 0.3, 1]
    )
    qpos = np.concatenate([description.default_base_position, [1, 0, 0, 0]]) if description.floating_base else []
    spec.add_key(name="default", qpos=np.concatenate([qpos, description.default_positions]).tolist())
    return spec


def build_mujoco_model(description: RobotDescription) -> mujoco.MjModel:
    """Compile the MuJoCo model and check its joints follow the description's order."""
    spec = build_mujoco_spec(description)
    try:
        model = spec.compile()
    except Exception as error:
        raise RobotDescriptionError(f"{description.urdf_path}: MuJoCo cannot compile the model: {error}") from error
    first = 1 if description.floating_base else 0
    names = tuple(model.joint(i).name for i in range(first, model.njnt))
    if names != description.joint_names:
        raise RobotDescriptionError(
            f"{description.folder / 'robot.toml'}: joint order differs from the MuJoCo model's; list the joints as {list(names)}"
        )
    supported = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    if any(int(model.jnt_type[i]) not in supported for i in range(first, model.njnt)):
        raise RobotDescriptionError(f"{description.urdf_path}: only hinge and slide joints are supported")
    assert math.isclose(model.opt.timestep, description.timestep)
    return model
