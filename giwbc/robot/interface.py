"""The Robot interface: what a Task and a controller read from, and write to, any robot backend.

It follows the Robot abstraction of Gym-Ignition: one interface, one implementation per backend
(MuJoCo here, CAN actuators in ``giwbc.hal``). It holds no backend types, only numpy arrays.

Conventions (shared with Pinocchio, which the controller uses):
- quaternions are ``(x, y, z, w)``;
- the base twist is expressed in the world frame (``linear_velocity`` of the base origin and
  ``angular_velocity``); :func:`base_velocity_local` converts it to Pinocchio's free-flyer
  velocity, which is expressed in the base frame;
- the IMU reports its orientation in the world frame, angular velocity and specific force
  (``linear_acceleration``, gravity included, as a real accelerometer) in the IMU frame;
- contact wrenches are ``(force, torque)`` in the world frame, torque about the link origin,
  exerted *by the environment on the link*.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from giwbc.errors import ConfigError, NonFiniteCommand

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription


def quat_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)``."""
    if type(quat_xyzw) is np.ndarray and quat_xyzw.dtype == np.float64:
        # (Python floats: the same IEEE operations as on numpy's float64 scalars, at a third of the cost.)
        x, y, z, w = quat_xyzw.tolist()
    else:
        x, y, z, w = quat_xyzw
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass(frozen=True)
class BaseState:
    """Pose and twist of the floating base (world frame); a fixed base reports its fixed pose."""

    position: np.ndarray
    quaternion: np.ndarray  # (x, y, z, w)
    linear_velocity: np.ndarray  # world frame, of the base origin
    angular_velocity: np.ndarray  # world frame

    @property
    def rotation(self) -> np.ndarray:
        return quat_to_matrix(self.quaternion)


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample: what a physical IMU would report."""

    quaternion: np.ndarray  # orientation of the IMU frame in the world, (x, y, z, w)
    angular_velocity: np.ndarray  # IMU frame, rad/s
    linear_acceleration: np.ndarray  # specific force in the IMU frame, m/s^2 (+9.81 up at rest)
    time: float = 0.0


@dataclass
class ImpedanceCommand:
    """Per-joint impedance command, the form CAN actuators in MIT mode accept.

    tau = kp * (q_ref - q) + kd * (v_ref - v) + tau_ff, evaluated by the actuator at its own rate.
    """

    q_ref: np.ndarray
    v_ref: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau_ff: np.ndarray

    @classmethod
    def damping(cls, n: int, kd: float | np.ndarray) -> "ImpedanceCommand":
        """The safe state: zero stiffness, pure damping, no feed-forward."""
        zeros = np.zeros(n)
        return cls(zeros.copy(), zeros.copy(), zeros.copy(), np.broadcast_to(kd, (n,)).astype(float), zeros.copy())

    def torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The torque this command asks for at joint state ``(q, v)``."""
        return self.kp * (self.q_ref - q) + self.kd * (self.v_ref - v) + self.tau_ff

    def validate(self, n: int) -> None:
        """Raise ``ValueError`` unless every field has ``n`` finite entries and gains are >= 0."""
        for name in ("q_ref", "v_ref", "kp", "kd", "tau_ff"):
            value = np.asarray(getattr(self, name))
            if value.shape != (n,):
                raise ValueError(f"impedance command field {name!r} has shape {value.shape}, expected ({n},)")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"impedance command field {name!r} is not finite: {value}")
        if np.any(self.kp < 0) or np.any(self.kd < 0):
            raise ValueError("impedance gains kp and kd must be >= 0")


@dataclass(frozen=True)
class ContactWrench:
    """Total wrench the environment exerts on a link, world frame, torque about the link origin."""

    force: np.ndarray
    torque: np.ndarray
    in_contact: bool = field(default=False)


class Robot(abc.ABC):
    """Reads joints, links, base, contacts and sensors of one robot and sets its commands."""

    # --- identity -------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def name(self) -> str: ...

    @property
    @abc.abstractmethod
    def joint_names(self) -> tuple[str, ...]:
        """All joints (actuated and passive), in the description's order: the order of every joint array."""

    @property
    def dofs(self) -> int:
        return len(self.joint_names)

    @property
    @abc.abstractmethod
    def floating_base(self) -> bool: ...

    @abc.abstractmethod
    def time(self) -> float:
        """Seconds since the robot (or simulation) started."""

    # --- joints ---------------------------------------------------------------------------
    @abc.abstractmethod
    def joint_positions(self) -> np.ndarray: ...

    @abc.abstractmethod
    def joint_velocities(self) -> np.ndarray: ...

    @abc.abstractmethod
    def joint_efforts(self) -> np.ndarray:
        """Measured joint torques (N·m) or forces (N)."""

    # --- base, links, contacts, sensors -----------------------------------------------------
    @abc.abstractmethod
    def base_state(self) -> BaseState: ...

    @abc.abstractmethod
    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World position (3,) and rotation matrix (3, 3) of a link frame."""

    @abc.abstractmethod
    def contact_wrench(self, link: str) -> ContactWrench: ...

    @abc.abstractmethod
    def imu(self) -> ImuReading: ...

    # --- commands -------------------------------------------------------------------------
    def set_joint_torques(self, torques: np.ndarray) -> None:
        """Command joint torques (clipped to the effort limits by the backend).

        Checked here once for every backend (one per joint, all finite: a :class:`ConfigError` or
        :class:`NonFiniteCommand` before anything is sent), then handed to the backend's
        :meth:`_send_joint_torques`, as python-can's ``BusABC.send`` hands frames to its interface.
        """
        self._send_joint_torques(self.checked_torques(torques))

    def checked_torques(self, torques: np.ndarray) -> np.ndarray:
        """``torques`` as a new float array of one entry per joint, all finite; else a clear error."""
        array = np.array(torques, dtype=float)
        if array.shape != (self.dofs,):
            raise ConfigError(f"expected {self.dofs} joint torques, got shape {array.shape}")
        # (A finite sum of squares means every entry is finite: one BLAS call per tick, not the
        # element-wise test and numpy's ``all`` wrapper; an overflowing one is checked entry by entry.)
        if not math.isfinite(array.dot(array)) and not np.isfinite(array).all():
            raise NonFiniteCommand(f"joint torques are not finite: {array}")
        return array

    @abc.abstractmethod
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        """Backend hook: send torques already checked by :meth:`set_joint_torques` (a fresh array)."""

    @abc.abstractmethod
    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        """Command per-joint impedance, evaluated at the backend's own (physics or firmware) rate."""

    # --- derived --------------------------------------------------------------------------
    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, v)`` in Pinocchio's convention: free-flyer ``[p, quat_xyzw]`` / ``[v_local, w_local]``
        first for a floating base, then the joints in description order."""
        qj, vj = self.joint_positions(), self.joint_velocities()
        if not self.floating_base:
            return qj, vj
        base = self.base_state()
        v_base = base_velocity_local(base)
        return np.concatenate([base.position, base.quaternion, qj]), np.concatenate([v_base, vj])


class DescribedRobot(Robot):
    """A Robot built from a :class:`RobotDescription`: its identity comes from the description."""

    description: "RobotDescription"

    @property
    def name(self) -> str:
        return self.description.name

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.description.joint_names

    @property
    def dofs(self) -> int:
        return self.description.dofs

    @property
    def floating_base(self) -> bool:
        return self.description.floating_base


class RobotWrapper(Robot):
    """A Robot around another, in the manner of ``gymnasium.Wrapper``: everything is forwarded.

    The wrapped robot is :attr:`robot`, the innermost one :attr:`unwrapped`; a subclass overrides
    only what it changes (sensor noise, perturbations, an estimated base state).
    """

    def __init__(self, robot: Robot) -> None:
        if not isinstance(robot, Robot):
            raise TypeError(f"{type(self).__name__} wraps a Robot, got {type(robot).__name__}")
        self.robot = robot

    @property
    def unwrapped(self) -> Robot:
        """The innermost robot (the engine or the hardware)."""
        robot = self.robot
        return robot.unwrapped if isinstance(robot, RobotWrapper) else robot

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.robot!r})"

    # --- identity and time ------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.robot.name

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.robot.joint_names

    @property
    def dofs(self) -> int:
        return self.robot.dofs

    @property
    def floating_base(self) -> bool:
        return self.robot.floating_base

    def time(self) -> float:
        return self.robot.time()

    # --- readings -----------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        return self.robot.joint_positions()

    def joint_velocities(self) -> np.ndarray:
        return self.robot.joint_velocities()

    def joint_efforts(self) -> np.ndarray:
        return self.robot.joint_efforts()

    def base_state(self) -> BaseState:
        return self.robot.base_state()

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        return self.robot.link_pose(link)

    def contact_wrench(self, link: str) -> ContactWrench:
        return self.robot.contact_wrench(link)

    def imu(self) -> ImuReading:
        return self.robot.imu()

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.robot.generalized_state()

    # --- commands -------------------------------------------------------------------------------
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        # (Checked once, by this wrapper's set_joint_torques: the wrapped robot has the same joints,
        # so its backend gets the fresh, checked array without a second check.)
        self.robot._send_joint_torques(torques)

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        self.robot.set_joint_impedance(command)


def base_velocity_local(base: BaseState) -> np.ndarray:
    """The base twist in the base frame, ``[v_local, w_local]``: Pinocchio's free-flyer velocity."""
    rotation_t = base.rotation.T
    return np.concatenate([rotation_t @ base.linear_velocity, rotation_t @ base.angular_velocity])
