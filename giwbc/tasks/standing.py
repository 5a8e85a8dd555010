"""The deployment task when no policy is given: a controller holds the robot (:class:`StandingTask`)."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from gymnasium import spaces

from giwbc.robot.interface import ImpedanceCommand, Robot, quat_to_matrix
from giwbc.tasks.task import Task


class Controller(Protocol):
    """Anything mapping the robot's state to the next impedance command."""

    def __call__(self, robot: Robot) -> ImpedanceCommand: ...


class StandingTask(Task):
    """A task with no action: a controller holds the robot, the observation is proprioception.

    The deployment task when no policy is given. Observation: gravity in the IMU frame, IMU
    angular rate, joint positions minus the default pose, joint velocities.
    """

    def __init__(self, controller: Controller, default_positions: np.ndarray) -> None:
        super().__init__()
        self.controller = controller
        self.default_positions = np.asarray(default_positions, dtype=float)

    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        n = self.robot.dofs
        high = np.concatenate([np.ones(3), np.full(3 + 2 * n, np.inf)]).astype(np.float32)
        return spaces.Box(-1.0, 1.0, shape=(0,), dtype=np.float32), spaces.Box(-high, high, dtype=np.float32)

    def reset_task(self) -> None:
        reset = getattr(self.controller, "reset", None)
        if callable(reset):
            reset()

    def set_action(self, action: np.ndarray) -> None:
        pass

    def apply_command(self) -> None:
        self.robot.set_joint_impedance(self.controller(self.robot))

    def controller_failure(self) -> str | None:
        """The controller's ``failure()`` (a WBC that fell back), if it has one."""
        failure = getattr(self.controller, "failure", None)
        return failure() if failure is not None else None

    def get_observation(self) -> np.ndarray:
        robot = self.robot
        imu = robot.imu()
        return np.concatenate([
            -quat_to_matrix(imu.quaternion)[2], imu.angular_velocity,
            robot.joint_positions() - self.default_positions, robot.joint_velocities(),
        ]).astype(np.float32)  # fmt: skip

    def get_reward(self) -> float:
        return 0.0

    def is_terminated(self) -> bool:
        return False


__all__ = ["Controller", "StandingTask"]
