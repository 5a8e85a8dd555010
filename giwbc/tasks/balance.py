"""G1 standing balance: the policy adds residuals to a controller's references.

Two controllers can sit beneath the action (``controller=``):

- ``"wbc"`` (default): the QP whole-body balance controller of :mod:`giwbc.control.balance`, at the
  controller rate, from the measured ``(q, v)``. Action blocks: CoM offset (m), pelvis orientation
  offset (roll, pitch, yaw, rad), posture offsets (rad); ``residuals=`` keeps a subset of them
  (``("com", "orientation")``: 6 actions, much faster to learn than 35).
- ``"pd"``: the joint-PD hold of the description's gains, evaluated by the actuators. Action:
  posture offsets only. A baseline, and the fastest way to run the task.

Under domain randomization the WBC keeps the description's nominal Pinocchio model (it must be
robust to the mismatch, as on hardware) unless ``controller_model="randomized"`` asks for the
sampled one.

The residuals are the action (in [-1, 1]) times per-block scales, clipped. Observation
(proprioception only, what the real robot measures): gravity in the IMU frame, IMU angular rate,
joint positions minus the default pose, joint velocities, the previous action.
Reward: alive bonus + uprightness + CoM over its reference + posture near the reference,
minus effort and action-rate penalties, minus a fall penalty at termination. Terminates when the
pelvis drops or tilts too far.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any

import numpy as np
import pinocchio as pin
from gymnasium import spaces

from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import BaseState, ImpedanceCommand, Robot, quat_to_matrix
from giwbc.tasks.floating_base import ANGULAR_VELOCITY_SCALE, JOINT_VELOCITY_SCALE, FloatingBaseTask
from giwbc.tasks.task import ActionBlock, ResidualLayout
from giwbc.control.balance import make_balance_controller
from giwbc.randomization import Nominal, randomized_pinocchio_model



@dataclass(frozen=True)
class BalanceRewards:
    """Reward weights and widths of :class:`G1Balance` (all per agent step)."""

    alive: float = 1.0
    upright: float = 0.5
    upright_width: float = 0.1  # rad of tilt at which the term falls to 1/e
    com: float = 0.5
    com_width: float = 0.05  # m of horizontal CoM error
    posture: float = 0.25
    posture_width: float = 0.5  # rad, norm over all joints
    effort: float = 0.1  # times the mean squared effort / effort limit
    action_rate: float = 0.05  # times the mean squared action change
    fall: float = 20.0  # once, at the step that terminates the episode


@dataclass(frozen=True)
class ResidualScales:
    """Physical size of a full (±1) action entry, per block."""

    com: float = 0.03  # m
    orientation: float = 0.1  # rad
    posture: float = 0.1  # rad


def _residual_layout(description: RobotDescription, scales: ResidualScales, names: tuple[str, ...], allowed: tuple[str, ...]) -> ResidualLayout:
    """The action blocks ``names`` (a subset of ``allowed``, kept in ``allowed``'s order)."""
    unknown = sorted(set(names) - set(allowed))
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"residuals must be distinct names among {allowed}, got {list(names)}")
    labels = tuple(n for n, a in zip(description.joint_names, description.actuated) if a)
    blocks = {
        "com": ActionBlock("com", 3, scales.com, ("x", "y", "z")),
        "orientation": ActionBlock("orientation", 3, scales.orientation, ("roll", "pitch", "yaw")),
        "posture": ActionBlock("posture", len(labels), scales.posture, labels),
    }
    return ResidualLayout([blocks[name] for name in allowed if name in names])


class _JointPD:
    """Residual posture over the description's joint-PD hold (impedance evaluated by the actuators)."""

    blocks = ("posture",)

    def __init__(self, description: RobotDescription, scales: ResidualScales, residuals: tuple[str, ...]) -> None:
        self.default = description.default_positions
        self.actuated = description.actuated
        self.layout = _residual_layout(description, scales, residuals, self.blocks)
        zeros = np.zeros(description.dofs)
        self.command = ImpedanceCommand(self.default.copy(), zeros.copy(), description.kp, description.kd, zeros.copy())

    def reset(self, robot: Robot) -> None:
        self.command.q_ref[:] = self.default

    def set_residuals(self, residuals: dict[str, np.ndarray]) -> None:
        self.command.q_ref[self.actuated] = self.default[self.actuated] + residuals["posture"]

    def apply(self, robot: Robot) -> None:
        robot.set_joint_impedance(self.command)

    def posture_reference(self) -> np.ndarray:
        return self.command.q_ref


class _WholeBody:
    """Residual CoM, pelvis orientation and posture references of the QP balance controller."""

    blocks = ("com", "orientation", "posture")

    def __init__(
        self, description: RobotDescription, scales: ResidualScales, residuals: tuple[str, ...], options: dict[str, Any], model: pin.Model
    ) -> None:
        self.description, self.options = description, options
        self.pin_model = model  # shared, read-only: each controller makes its own Data
        self.balance = self._new_controller()  # validates the options now
        self.default = description.default_positions
        self.actuated = description.actuated
        self.layout = _residual_layout(description, scales, residuals, self.blocks)
        self._zero = {"com": np.zeros(3), "orientation": np.zeros(3), "posture": np.zeros(int(np.count_nonzero(self.actuated)))}
        self.posture = self.default.copy()
        self.base_reference = pin.SE3.Identity()
        self.result: Any = None

    def _new_controller(self) -> Any:
        return make_balance_controller(self.description, model=self.pin_model, **self.options)

    def reset(self, robot: Robot) -> None:
        """References at the standing pose and nothing of the last episode left: the controller's
        :meth:`~giwbc.control.balance.BalanceController.reset` gives the torques of a new one, bit
        for bit. A new controller only when the model changed (``controller_model="randomized"``)."""
        if self.balance.wbc.kin.model is not self.pin_model:
            self.balance = self._new_controller()
        self.balance.reset()
        self.base_reference = pin.SE3(self.balance.base_task.reference)
        self.posture = self.default.copy()
        self.result = None

    def set_residuals(self, residuals: dict[str, np.ndarray]) -> None:
        residuals = {**self._zero, **residuals}
        self.balance.set_com_offset(residuals["com"])
        rotation = self.base_reference.rotation @ pin.rpy.rpyToMatrix(residuals["orientation"])
        self.balance.base_task.set_reference(pin.SE3(rotation, self.base_reference.translation))
        self.posture = self.default.copy()
        self.posture[self.actuated] += residuals["posture"]
        self.balance.posture_task.set_reference(self.posture)

    def apply(self, robot: Robot) -> None:
        q, v = robot.generalized_state()
        self.result = self.balance.update(q, v, robot.time())
        robot.set_joint_torques(self.result.tau)

    def failure(self) -> str | None:
        """Why the last tick fell back (see :meth:`Task.controller_failure`), or None."""
        return None if self.result is None else self.result.failure()

    def posture_reference(self) -> np.ndarray:
        return self.posture


class G1Balance(FloatingBaseTask):
    """Stand under pushes: residual actions over a balance controller (see the module docstring)."""

    def __init__(
        self,
        description: RobotDescription,
        *,
        controller: str = "wbc",
        residuals: Sequence[str] | None = None,
        scales: ResidualScales | dict[str, float] | None = None,
        rewards: BalanceRewards | dict[str, float] | None = None,
        initial_joint_noise: float = 0.02,
        min_height_ratio: float = 0.7,
        max_tilt: float = 0.7,
        wbc_options: dict[str, Any] | None = None,
        controller_model: str = "nominal",
    ) -> None:
        super().__init__()
        if controller_model not in ("nominal", "randomized"):
            raise ValueError(f"controller_model must be 'nominal' or 'randomized', got {controller_model!r}")
        if controller_model == "randomized" and controller != "wbc":
            raise ValueError("controller_model='randomized' gives the WBC the sampled dynamics: it needs controller='wbc'")
        self.controller_model = controller_model
        if not description.floating_base or not description.contacts:
            raise ValueError(f"G1Balance needs a floating-base robot with feet, got {description.name!r}")
        self.description = description
        self.scales = ResidualScales(**scales) if isinstance(scales, dict) else scales or ResidualScales()
        self.rewards = BalanceRewards(**rewards) if isinstance(rewards, dict) else rewards or BalanceRewards()
        self.initial_joint_noise = float(initial_joint_noise)
        self.max_tilt = float(max_tilt)
        self._pin_model = description.pinocchio_model
        self._pin_data = self._pin_model.createData()
        if controller not in ("wbc", "pd"):
            raise ValueError(f"controller must be 'wbc' or 'pd', got {controller!r}")
        if controller == "pd":
            self.controller: Any = _JointPD(description, self.scales, tuple(residuals or _JointPD.blocks))
        else:
            blocks = tuple(residuals or _WholeBody.blocks)
            self.controller = _WholeBody(description, self.scales, blocks, dict(wbc_options or {}), self._pin_model)
        self.controller_name = controller
        self.layout: ResidualLayout = self.controller.layout
        self._nominal: Any = None  # randomization nominal values, for controller_model="randomized"
        self.q0 = description.default_configuration()
        self.nominal_height = float(self.q0[2])
        self.min_height = min_height_ratio * self.nominal_height
        self.effort_limits = description.effort_limits
        self.default_positions = description.default_positions
        self._base: tuple[float, BaseState] | None = None
        self._effort_scale = np.where(self.effort_limits > 0, 1.0 / np.maximum(self.effort_limits, 1e-9), 0.0)
        self._feet = [(self._pin_model.getFrameId(c.link), np.asarray(c.center, dtype=float)) for c in description.contacts]
        self.nominal_com_offset = self._com_offset(self.q0)
        self.last_action = np.zeros(self.layout.size)
        self.previous_action = np.zeros(self.layout.size)

    # --- spaces ---------------------------------------------------------------------------
    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        if tuple(self.robot.joint_names) != self.description.joint_names:
            raise ValueError(f"robot joints {self.robot.joint_names} differ from the description's")
        n, m = self.robot.dofs, self.layout.size
        high = np.concatenate([np.ones(3), np.full(3 + 2 * n, 10.0), np.ones(m)]).astype(np.float32)
        return self.layout.space(), spaces.Box(-high, high, dtype=np.float32)

    def observation_names(self) -> tuple[str, ...]:
        joints = self.description.joint_names
        return (
            *(f"gravity_imu/{a}" for a in "xyz"),
            *(f"angular_velocity_imu/{a}" for a in "xyz"),
            *(f"joint_position_offset/{j}" for j in joints),
            *(f"joint_velocity/{j}" for j in joints),
            *(f"last_action/{name}" for name in self.layout.entry_names()),
        )

    def action_names(self) -> tuple[str, ...]:
        return self.layout.entry_names()

    # --- episode --------------------------------------------------------------------------
    def randomized(self, drawn: Any) -> None:
        """With ``controller_model="randomized"``, give the WBC the sampled masses, CoMs and armature
        (an oracle, for studies); by default it keeps the nominal model, as on hardware."""
        if self.controller_model != "randomized" or not drawn.resampled:
            return
        if self._nominal is None:
            self._nominal = Nominal.from_description(self.description)
        self.controller.pin_model = randomized_pinocchio_model(self._pin_model, drawn.physics, self._nominal)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        q = self.q0.copy()
        noise = self.np_random.uniform(-self.initial_joint_noise, self.initial_joint_noise, self.robot.dofs)
        q[7:] += noise
        return q, np.zeros(self._pin_model.nv)

    def reset_task(self) -> None:
        self._base = self._observed = None
        self.last_action = np.zeros(self.layout.size)
        self.previous_action = np.zeros(self.layout.size)
        self.controller.reset(self.robot)
        self.controller.set_residuals(self.layout.split(self.last_action))

    def set_action(self, action: np.ndarray) -> None:
        self.previous_action = self.last_action
        self.last_action = np.array(action, dtype=float)
        self.controller.set_residuals(self.layout.split(self.last_action))

    def apply_command(self) -> None:
        self.controller.apply(self.robot)

    def controller_failure(self) -> str | None:
        failure = getattr(self.controller, "failure", None)
        return failure() if failure is not None else None

    # --- outputs --------------------------------------------------------------------------
    def get_observation(self) -> np.ndarray:
        robot = self.robot
        imu = robot.imu()
        up = quat_to_matrix(imu.quaternion)[2]  # the world z axis in the IMU frame
        q, v = robot.joint_positions(), robot.joint_velocities()
        return np.concatenate([
            -up,  # gravity direction in the IMU frame: (0, 0, -1) when level
            ANGULAR_VELOCITY_SCALE * imu.angular_velocity,
            q - self.default_positions,
            JOINT_VELOCITY_SCALE * v,
            self.last_action,
        ]).astype(np.float32)

    def com_error(self) -> np.ndarray:
        """Horizontal CoM error (m): the CoM relative to the feet, minus the same at the standing pose."""
        return self._com_offset(self.robot.generalized_state()[0]) - self.nominal_com_offset

    def _com_offset(self, q: np.ndarray) -> np.ndarray:
        """Horizontal CoM position relative to the centre of the feet soles."""
        model, data = self._pin_model, self._pin_data
        com = pin.centerOfMass(model, data, q, False)  # also places every joint
        center = np.zeros(3)
        for frame, sole_center in self._feet:
            placement = pin.updateFramePlacement(model, data, frame)
            center += placement.rotation @ sole_center + placement.translation
        return com[:2] - center[:2] / len(self._feet)

    def get_reward(self) -> float:
        w = self.rewards
        tilt = self.tilt()
        com_error = self.com_error()
        posture_error = self.robot.joint_positions() - self.controller.posture_reference()
        effort = self.robot.joint_efforts() * self._effort_scale
        change = self.last_action - self.previous_action
        return float(
            w.alive
            + w.upright * math.exp(-((tilt / w.upright_width) ** 2))
            + w.com * math.exp(-float(com_error @ com_error) / w.com_width**2)
            + w.posture * math.exp(-float(posture_error @ posture_error) / w.posture_width**2)
            - w.effort * float(effort @ effort) / effort.size
            - w.action_rate * float(change @ change) / change.size
            - (w.fall if self.is_terminated() else 0.0)
        )

    def get_info(self) -> dict[str, Any]:
        return {"base_height": float(self.base_state().position[2]), "tilt": self.tilt()}

    def describe(self) -> dict[str, Any]:
        return self.residual_description(self.controller_name)
