"""The randomizable parameters: what each means, what it applies to, and its nominal value.

Nominal values come from the robot description (the URDF's masses and centres of mass, the
robot.toml's armature, effort limits and floor friction), so a sample means the same thing on
every engine. ``physics`` parameters change the simulated model and are resampled every
``physics_every`` episodes; ``episode`` parameters (sensor noise and bias, IMU latency, pushes)
are resampled at every reset.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from giwbc.robot.description import RobotDescription
from giwbc.robot.so3 import rpy_to_matrix

STANDARD_GRAVITY = (0.0, 0.0, -9.81)
ALL_OPERATIONS = ("absolute", "scale", "add")


@dataclass(frozen=True)
class ParameterSpec:
    """One randomizable parameter: its targets (``link``, ``joint`` or ``global``), size and range."""

    name: str
    scope: str
    size: int
    group: str
    operations: tuple[str, ...]
    doc: str
    lower: float = -math.inf
    upper: float = math.inf
    integer: bool = False

    def clip(self, values: np.ndarray) -> np.ndarray:
        """Values kept in the parameter's physical range (a gaussian can draw a negative mass)."""
        values = np.clip(values, self.lower, self.upper)
        return np.rint(values) if self.integer else values


_NONZERO = ALL_OPERATIONS
_ZERO = ("absolute", "add")  # nominal 0: "scale" would do nothing
_ABSOLUTE = ("absolute",)

PARAMETERS: dict[str, ParameterSpec] = {
    spec.name: spec
    for spec in [
        ParameterSpec("link_mass", "link", 1, "physics", _NONZERO, "link mass, kg (inertia scales with it)", lower=1e-6),
        ParameterSpec("link_com", "link", 3, "physics", _NONZERO, "centre of mass in the link frame, m"),
        ParameterSpec("joint_damping", "joint", 1, "physics", _ZERO, "viscous joint damping, N m s/rad", lower=0.0),
        ParameterSpec("joint_friction", "joint", 1, "physics", _ZERO, "Coulomb joint friction, N m", lower=0.0),
        ParameterSpec("joint_armature", "joint", 1, "physics", _NONZERO, "reflected rotor inertia, kg m^2", lower=0.0),
        ParameterSpec("actuator_strength", "joint", 1, "physics", _NONZERO, "effort limit, N m", lower=0.0),
        ParameterSpec("actuator_latency", "global", 1, "physics", _ZERO, "command latency, physics steps", lower=0, integer=True),
        ParameterSpec("kp_scale", "joint", 1, "physics", _NONZERO, "factor on commanded stiffness", lower=0.0),
        ParameterSpec("kd_scale", "joint", 1, "physics", _NONZERO, "factor on commanded damping", lower=0.0),
        ParameterSpec("ground_friction", "global", 1, "physics", _NONZERO, "floor-foot sliding friction", lower=0.0),
        ParameterSpec("ground_restitution", "global", 1, "physics", _ZERO, "floor-foot restitution", lower=0.0, upper=1.0),
        ParameterSpec("gravity", "global", 3, "physics", _NONZERO, "gravity vector, m/s^2"),
        ParameterSpec("contact_timeconst", "global", 1, "physics", _NONZERO, "contact softness: solref time constant, s (MuJoCo)", lower=1e-4),
        ParameterSpec("contact_dampratio", "global", 1, "physics", _NONZERO, "contact damping ratio, solref[1] (MuJoCo)", lower=1e-3),
        ParameterSpec("solver_iterations", "global", 1, "physics", _NONZERO, "constraint solver iterations (MuJoCo)", lower=1, integer=True),
        ParameterSpec("actuator_lag", "joint", 1, "physics", _ZERO, "first-order lag of the delivered torque, s (MuJoCo)", lower=0.0),
        ParameterSpec("joint_position_noise", "joint", 1, "episode", _ZERO, "encoder noise std, rad", lower=0.0),
        ParameterSpec("joint_position_bias", "joint", 1, "episode", _ZERO, "encoder offset, rad"),
        ParameterSpec("joint_velocity_noise", "joint", 1, "episode", _ZERO, "joint velocity noise std, rad/s", lower=0.0),
        ParameterSpec("gyro_noise", "global", 1, "episode", _ZERO, "gyro noise std, rad/s", lower=0.0),
        ParameterSpec("gyro_bias", "global", 3, "episode", _ZERO, "gyro bias, rad/s"),
        ParameterSpec("accelerometer_noise", "global", 1, "episode", _ZERO, "accelerometer noise std, m/s^2", lower=0.0),
        ParameterSpec("accelerometer_bias", "global", 3, "episode", _ZERO, "accelerometer bias, m/s^2"),
        ParameterSpec("imu_orientation_noise", "global", 1, "episode", _ZERO, "IMU orientation noise std, rad", lower=0.0),
        ParameterSpec("imu_latency", "global", 1, "episode", _ZERO, "IMU latency, physics steps", lower=0, integer=True),
        ParameterSpec("imu_mounting", "global", 3, "episode", _ZERO, "IMU mounting misalignment (rotation vector), rad"),
        ParameterSpec("imu_orientation_bias", "global", 3, "episode", _ZERO, "IMU orientation output's constant error (world rotation vector), rad"),
        ParameterSpec("imu_heading_drift", "global", 1, "episode", _ZERO, "IMU orientation output's heading drift, rad/s"),
        ParameterSpec("imu_dropout", "global", 1, "episode", _ZERO, "probability an IMU sample repeats the last one", lower=0.0, upper=0.99),
        ParameterSpec("imu_timestamp_jitter", "global", 1, "episode", _ZERO, "IMU timestamp jitter std, s", lower=0.0),
        ParameterSpec("encoder_resolution", "global", 1, "episode", _ZERO, "joint encoder quantization step, rad", lower=0.0),
        ParameterSpec("push_interval", "global", 1, "episode", _ABSOLUTE, "wait before each push, s", lower=1e-6),
        ParameterSpec("push_force", "global", 1, "episode", _ABSOLUTE, "horizontal push magnitude, N", lower=0.0),
        ParameterSpec("push_duration", "global", 1, "episode", _ABSOLUTE, "push duration, s", lower=1e-6),
    ]
}
PUSH_PARAMETERS = ("push_interval", "push_force", "push_duration")
MUJOCO_ONLY = frozenset({"contact_timeconst", "contact_dampratio", "solver_iterations", "actuator_lag"})  # engine-level, MuJoCo's


@dataclass(frozen=True)
class Nominal:
    """Nominal values of every parameter for one robot description (arrays over links or joints)."""

    links: tuple[str, ...]
    joints: tuple[str, ...]
    base_link: str
    values: dict[str, np.ndarray]
    link_inertia: np.ndarray  # (links, 3, 3) rotational inertia about the CoM, link frame (URDF)

    @classmethod
    def from_description(cls, description: RobotDescription) -> "Nominal":
        links, masses, coms, inertias = urdf_inertials(description)
        dofs = description.dofs
        zeros_j = np.zeros(dofs)
        values = {
            "link_mass": masses,
            "link_com": coms,
            "joint_damping": zeros_j,
            "joint_friction": zeros_j,
            "joint_armature": np.array([j.armature for j in description.joints]),
            "actuator_strength": description.effort_limits,
            "actuator_latency": np.zeros(1),
            "kp_scale": np.ones(dofs),
            "kd_scale": np.ones(dofs),
            "ground_friction": np.array([description.floor_friction]),
            "ground_restitution": np.zeros(1),
            "gravity": np.array(STANDARD_GRAVITY),
            "contact_timeconst": np.array([0.02]),  # MuJoCo's default solref
            "contact_dampratio": np.array([1.0]),
            "solver_iterations": np.array([100.0]),  # MuJoCo's default
            "actuator_lag": zeros_j,
            "joint_position_noise": zeros_j,
            "joint_position_bias": zeros_j,
            "joint_velocity_noise": zeros_j,
            "gyro_noise": np.zeros(1),
            "gyro_bias": np.zeros(3),
            "accelerometer_noise": np.zeros(1),
            "accelerometer_bias": np.zeros(3),
            "imu_orientation_noise": np.zeros(1),
            "imu_latency": np.zeros(1),
            "imu_mounting": np.zeros(3),
            "imu_orientation_bias": np.zeros(3),
            "imu_heading_drift": np.zeros(1),
            "imu_dropout": np.zeros(1),
            "imu_timestamp_jitter": np.zeros(1),
            "encoder_resolution": np.zeros(1),
            "push_interval": np.array([math.inf]),
            "push_force": np.zeros(1),
            "push_duration": np.array([0.1]),
        }
        assert set(values) == set(PARAMETERS)
        for array in values.values():
            array.flags.writeable = False
        inertias.flags.writeable = False
        return cls(links, description.joint_names, description.base_link, values, inertias)

    def targets(self, scope: str) -> tuple[str, ...]:
        return {"link": self.links, "joint": self.joints, "global": ()}[scope]


def urdf_inertials(description: RobotDescription) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Link names (URDF order), masses (0 without ``<inertial>``), CoMs and rotational inertias (link frame)."""
    root = ET.parse(description.urdf_path).getroot()
    names, masses, coms, inertias = [], [], [], []
    for link in root.iter("link"):
        names.append(link.get("name"))
        mass = link.find("inertial/mass")
        origin = link.find("inertial/origin")
        tensor = link.find("inertial/inertia")
        masses.append(float(mass.get("value", 0.0)) if mass is not None else 0.0)
        coms.append([float(x) for x in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0, 0.0, 0.0])
        values = {k: float(tensor.get(k, 0.0)) if tensor is not None else 0.0 for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
        inertia = np.array(
            [
                [values["ixx"], values["ixy"], values["ixz"]],
                [values["ixy"], values["iyy"], values["iyz"]],
                [values["ixz"], values["iyz"], values["izz"]],
            ]
        )
        rpy = np.array([float(x) for x in origin.get("rpy", "0 0 0").split()]) if origin is not None else np.zeros(3)
        rotation = rpy_to_matrix(rpy)
        inertias.append(rotation @ inertia @ rotation.T)
    return tuple(names), np.array(masses), np.array(coms, dtype=float).reshape(-1, 3), np.array(inertias).reshape(-1, 3, 3)

