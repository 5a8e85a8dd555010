"""A MuJoCo plant checked against a robot description, and bound to it by name.

The plant is what the simulation steps: the model giwbc builds from the description, a variant of
it (:mod:`giwbc.plants`), or a model built elsewhere (a vendor's MJCF, an ``MjModel``). Whatever
its origin, it must honour this contract, checked before the first step (one
:class:`~giwbc.errors.PlantMismatchError` line naming the element at fault):

- **joints**: every joint of the description, by name, hinge or slide; no other movable joint; a
  free joint on the base link for a floating base. Their order in the plant does not matter;
- **actuators**: one per actuated joint, a torque actuator on that joint (``<motor>``: fixed gain
  1, gear 1, no activation dynamics); position, velocity or general actuators with a bias and
  geared motors are refused (giwbc sends torques and MIT impedances itself); a unit-gain actuator
  with an affine bias is giwbc's own impedance form (gains an earlier robot left), its gains cleared. giwbc turns each
  into its own form (an affine bias that holds the impedance gains; force limited by the plant's
  force range, else its control range, else the description's effort; control unlimited);
- **sensors**: ``imu_quat`` (framequat), ``imu_gyro`` (gyro), ``imu_accel`` (accelerometer) at the
  IMU, and per foot ``<foot>_force``, ``<foot>_torque`` (at the sole centre) and ``<foot>_touch``
  (a site volume around the sole);
- **keyframe 0** is the description's default pose; the **timestep** is the description's.

:func:`complete_spec` adds what an MJCF file lacks (the sensors and their sites, on the body that
carries the IMU or foot link when the plant merged it; a floor; the free joint; the default-pose
keyframe, first) and refuses what it cannot fix; a compiled ``MjModel`` is only checked
(:func:`bind`), as nothing can be added to it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from giwbc.errors import PlantMismatchError, RobotDescriptionError
from giwbc.robot.fixed_links import carrier
from giwbc.robot.mujoco_model import COLLISION_BIT, ROBOT_ONLY_BIT, SOLE_THICKNESS, foot_sensor_names, imu_sensor_names

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

IMU_SENSOR_TYPES = {
    "quaternion": mujoco.mjtSensor.mjSENS_FRAMEQUAT,
    "angular_velocity": mujoco.mjtSensor.mjSENS_GYRO,
    "linear_acceleration": mujoco.mjtSensor.mjSENS_ACCELEROMETER,
}
FOOT_SENSOR_TYPES = {"force": mujoco.mjtSensor.mjSENS_FORCE, "torque": mujoco.mjtSensor.mjSENS_TORQUE, "touch": mujoco.mjtSensor.mjSENS_TOUCH}
TOUCH_MARGIN = 0.02  # m the touch site reaches beyond the sole on every side (a plant's own feet may overhang it)
_MOVABLE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


@dataclass(frozen=True)
class PlantBinding:
    """Where each of the description's joints and actuators lives in the plant."""

    base_qpos: int  # address of the free joint's 7 qpos (-1: fixed base)
    base_dof: int
    qpos: np.ndarray  # per description joint
    dofs: np.ndarray
    actuators: np.ndarray  # per actuated description joint, in description order


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int) -> str:
    return mujoco.mj_id2name(model, kind, index) or f"#{index}"


def bind(description: RobotDescription, model: mujoco.MjModel, where: str = "plant") -> PlantBinding:
    """Check ``model`` against the contract above and bind it by name (a compiled model is checked, not
    changed); ``where`` starts every error line."""
    if not math.isclose(model.opt.timestep, description.timestep, rel_tol=1e-9):
        raise PlantMismatchError(f"{where}: timestep {model.opt.timestep} s, the description's is {description.timestep} s")
    joints = {}
    for index in range(model.njnt):
        name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, index)
        joints[name] = index
    known = set(description.joint_names)
    base_qpos = base_dof = -1
    if description.floating_base:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, description.base_link)
        if body < 0:
            raise PlantMismatchError(f"{where}: no body {description.base_link!r} (the description's base link)")
        free = [j for j in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body])
                if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE] if model.body_jntnum[body] > 0 else []
        if not free:
            raise PlantMismatchError(f"{where}: base body {description.base_link!r} has no free joint")
        base_qpos, base_dof = int(model.jnt_qposadr[free[0]]), int(model.jnt_dofadr[free[0]])
    missing = [name for name in description.joint_names if name not in joints]
    if missing:
        raise PlantMismatchError(f"{where}: no joint {missing[0]!r}" + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    for name, index in joints.items():
        kind = int(model.jnt_type[index])
        if name in known and kind not in _MOVABLE:
            raise PlantMismatchError(f"{where}: joint {name!r} is not a hinge or slide joint")
        if name not in known and kind in _MOVABLE:
            raise PlantMismatchError(f"{where}: joint {name!r} is not in the description")
    ids = np.array([joints[name] for name in description.joint_names], dtype=int)
    actuated_names = [j.name for j in description.joints if j.actuated]
    by_joint: dict[str, int] = {}
    for a in range(model.nu):
        name = _name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            raise PlantMismatchError(f"{where}: actuator {name!r} does not act on a joint")
        joint = _name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.actuator_trnid[a, 0]))
        if joint not in actuated_names:
            raise PlantMismatchError(f"{where}: actuator {name!r} drives {joint!r}, which the description does not actuate")
        if joint in by_joint:
            raise PlantMismatchError(f"{where}: actuator {name!r} is the second on joint {joint!r}")
        _check_torque_actuator(model, a, f"{where}: actuator {name!r}")
        by_joint[joint] = a
    unactuated = [name for name in actuated_names if name not in by_joint]
    if unactuated:
        raise PlantMismatchError(f"{where}: joint {unactuated[0]!r} has no actuator")
    sensors = {_name(model, mujoco.mjtObj.mjOBJ_SENSOR, s): int(model.sensor_type[s]) for s in range(model.nsensor)}
    expected: list[tuple[str, mujoco.mjtSensor]] = []
    if description.imu_frame is not None:
        expected += [(imu_sensor_names()[k], t) for k, t in IMU_SENSOR_TYPES.items()]
    for contact in description.contacts:
        expected += [(foot_sensor_names(contact.name)[k], t) for k, t in FOOT_SENSOR_TYPES.items()]
    for name, kind in expected:
        if name not in sensors:
            raise PlantMismatchError(f"{where}: no sensor {name!r} ({kind.name[9:].lower()}); an MJCF file gets it added, a compiled model cannot")
        if sensors[name] != int(kind):
            raise PlantMismatchError(f"{where}: sensor {name!r} is not a {kind.name[9:].lower()} sensor")
    for contact in description.contacts:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, contact.link) < 0:
            raise PlantMismatchError(f"{where}: no body {contact.link!r} (foot {contact.name!r})")
    if model.nkey == 0:
        raise PlantMismatchError(f"{where}: no keyframe (keyframe 0 must be the default pose)")
    binding = PlantBinding(base_qpos, base_dof, model.jnt_qposadr[ids].copy(), model.jnt_dofadr[ids].copy(),
                           np.array([by_joint[name] for name in actuated_names], dtype=int))
    defaults = model.key_qpos[0][binding.qpos]
    off = np.flatnonzero(np.abs(defaults - description.default_positions) > 1e-6)
    if len(off):
        name = description.joint_names[off[0]]
        raise PlantMismatchError(f"{where}: keyframe 0 puts {name!r} at {defaults[off[0]]:.4g}, the default pose at {description.default_positions[off[0]]:.4g}")
    return binding


def _check_torque_actuator(model: mujoco.MjModel, a: int, where: str) -> None:
    gain, bias = model.actuator_gainprm[a], model.actuator_biasprm[a]
    unit_gain = model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED and gain[0] == 1.0
    biased = model.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_NONE and np.any(bias[:3] != 0.0)
    if biased and not unit_gain:  # <position kp>: gain kp, bias -kp q; <velocity kv>: gain kv, bias -kv qdot
        raise PlantMismatchError(f"{where} is a position/velocity actuator (gain {gain[0]:g}, bias {bias[:3].tolist()}); "
                                 "giwbc sends torques: use <motor>")
    if not unit_gain:
        raise PlantMismatchError(f"{where} is not a torque actuator (gain {gain[0]:g}); use <motor> with gear 1")
    # A unit gain with a bias is giwbc's own impedance form (gains left by an earlier robot): adopt_actuators clears them.
    if model.actuator_dyntype[a] != mujoco.mjtDyn.mjDYN_NONE:
        raise PlantMismatchError(f"{where} has activation dynamics; use <motor> (actuator lag: giwbc.plants variants)")
    if model.actuator_gear[a, 0] != 1.0 or np.any(model.actuator_gear[a, 1:] != 0.0):
        raise PlantMismatchError(f"{where} has gear {model.actuator_gear[a, 0]:g}; giwbc commands joint torques: use gear 1")


def adopt_actuators(description: RobotDescription, model: mujoco.MjModel, binding: PlantBinding) -> None:
    """Turn the bound torque actuators into giwbc's impedance form, in place (see the module docstring)."""
    acts = binding.actuators
    effort = description.effort_limits[description.actuated]
    limit = np.where(model.actuator_forcelimited[acts] == 1, model.actuator_forcerange[acts, 1],
                     np.where(model.actuator_ctrllimited[acts] == 1, model.actuator_ctrlrange[acts, 1], effort))
    model.actuator_biastype[acts] = mujoco.mjtBias.mjBIAS_AFFINE
    model.actuator_biasprm[acts] = 0.0
    model.actuator_ctrllimited[acts] = 0
    model.actuator_forcelimited[acts] = 1
    model.actuator_forcerange[acts] = np.stack([-limit, limit], axis=1)


def load_spec(path: str | os.PathLike[str]) -> mujoco.MjSpec:
    """The spec of an MJCF file (one RobotDescriptionError line when it does not parse)."""
    path = Path(path)
    if not path.is_file():
        raise RobotDescriptionError(f"plant {path}: no such MJCF file")
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as error:  # mujoco raises ValueError with the parser's message
        raise RobotDescriptionError(f"plant {path}: MuJoCo cannot parse it: {str(error).splitlines()[0]}") from error


def _has(items: object, name: str) -> bool:
    return any(item.name == name for item in items)  # type: ignore[attr-defined]


def complete_spec(description: RobotDescription, spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """Add to a plant's spec what the contract needs and it lacks (in place; returns it)."""
    bodies = {body.name for body in spec.bodies}
    if description.floating_base:
        if description.base_link not in bodies:
            raise PlantMismatchError(f"plant: no body {description.base_link!r} (the description's base link)")
        root = spec.body(description.base_link)
        if not any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in root.joints):
            root.add_freejoint(name="floating_base")
        if not any(g.type == mujoco.mjtGeom.mjGEOM_PLANE for g in spec.worldbody.geoms):
            spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05],
                                    friction=[description.floor_friction, 0.005, 0.0001],
                                    contype=COLLISION_BIT, conaffinity=COLLISION_BIT | ROBOT_ONLY_BIT)
    sensors = spec.sensors
    if description.imu_frame is not None:
        names = imu_sensor_names()
        if not all(_has(sensors, names[k]) for k in IMU_SENSOR_TYPES):
            site = "imu"
            if not _has(spec.sites, site):
                held = carrier(description.urdf_path, frozenset(bodies), description.imu_frame)
                quat = np.empty(4)
                mujoco.mju_mat2Quat(quat, held.rotation.flatten())
                spec.body(held.body).add_site(name=site, pos=held.position, quat=quat, group=4)
            for kind, sensor_type in IMU_SENSOR_TYPES.items():
                if not _has(sensors, names[kind]):
                    spec.add_sensor(name=names[kind], type=sensor_type, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site)
    for contact in description.contacts:
        names = foot_sensor_names(contact.name)
        if all(_has(sensors, names[k]) for k in FOOT_SENSOR_TYPES):
            continue
        if contact.link not in bodies:
            raise PlantMismatchError(f"plant: no body {contact.link!r} (foot {contact.name!r})")
        body, center = spec.body(contact.link), np.asarray(contact.center, dtype=float)
        touch_site, sole_site = f"{contact.name}_touch_site", f"{contact.name}_sole_site"
        if not _has(spec.sites, touch_site):
            body.add_site(name=touch_site, type=mujoco.mjtGeom.mjGEOM_BOX, pos=center + [0, 0, SOLE_THICKNESS], group=4,
                          size=[contact.half_length + TOUCH_MARGIN, contact.half_width + TOUCH_MARGIN, SOLE_THICKNESS + TOUCH_MARGIN])
        if not _has(spec.sites, sole_site):
            body.add_site(name=sole_site, pos=center, group=4)
        for kind, sensor_type in FOOT_SENSOR_TYPES.items():
            if not _has(sensors, names[kind]):
                site = touch_site if kind == "touch" else sole_site
                spec.add_sensor(name=names[kind], type=sensor_type, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site)
    _default_key_first(description, spec)
    return spec


def _default_key_first(description: RobotDescription, spec: mujoco.MjSpec) -> None:
    """Keyframe 0 := the description's default pose (the plant's own keyframes follow it)."""
    try:
        model = spec.compile()
    except Exception as error:
        raise PlantMismatchError(f"plant: MuJoCo cannot compile it: {str(error).splitlines()[0]}") from error
    qpos = model.qpos0.copy()
    if description.floating_base:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, description.base_link)
        adr = int(model.jnt_qposadr[model.body_jntadr[body]])
        qpos[adr: adr + 7] = np.concatenate([description.default_base_position, [1.0, 0.0, 0.0, 0.0]])
    for name, value in zip(description.joint_names, description.default_positions):
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if joint < 0:
            raise PlantMismatchError(f"plant: no joint {name!r}")
        qpos[model.jnt_qposadr[joint]] = value
    old = [(key.name, np.array(key.qpos), np.array(key.qvel), np.array(key.ctrl)) for key in spec.keys]
    for key in list(spec.keys):
        spec.delete(key)
    spec.add_key(name="giwbc_default", qpos=qpos.tolist())
    for name, key_qpos, key_qvel, key_ctrl in old:
        key = spec.add_key(name=name or "")
        if len(key_qpos):
            key.qpos = key_qpos.tolist()
        if len(key_qvel):
            key.qvel = key_qvel.tolist()
        if len(key_ctrl):
            key.ctrl = key_ctrl.tolist()


def compile_plant(description: RobotDescription, spec: mujoco.MjSpec, where: str) -> mujoco.MjModel:
    """Compile a completed spec with one clear line on failure."""
    try:
        return spec.compile()
    except Exception as error:
        raise PlantMismatchError(f"plant {where}: MuJoCo cannot compile it: {str(error).splitlines()[0]}") from error


def plant_from_file(description: RobotDescription, path: str | os.PathLike[str]) -> mujoco.MjModel:
    """An MJCF file completed (:func:`complete_spec`) and compiled; checked when a robot binds it."""
    spec = complete_spec(description, load_spec(path))
    return compile_plant(description, spec, str(path))
