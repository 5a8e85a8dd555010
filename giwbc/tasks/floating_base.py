"""What every Task over a floating-base robot reads the same way: the base state once per robot
time, the pelvis tilt, and the fall test that reward, termination and info share (on the true
base where a simulation estimates the one the task observes: :attr:`Task.truth`)."""

from __future__ import annotations

import math
from typing import Any

from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import BaseState
from giwbc.tasks.task import ResidualLayout, Task

__all__ = ["ANGULAR_VELOCITY_SCALE", "JOINT_VELOCITY_SCALE", "FloatingBaseTask"]

ANGULAR_VELOCITY_SCALE = 0.25  # observation scalings of the residual tasks: keep entries of order 1
JOINT_VELOCITY_SCALE = 0.05


class FloatingBaseTask(Task):
    """A :class:`Task` with a floating base: fallen when the base is below ``min_height`` (m) or
    tilted beyond ``max_tilt`` (rad); subclasses set both and clear ``_base`` at reset."""

    min_height: float
    max_tilt: float
    description: RobotDescription
    layout: ResidualLayout
    _base: tuple[float, BaseState] | None = None
    _observed: tuple[float, BaseState] | None = None

    def base_state(self) -> BaseState:
        """The true base state, read once per robot time (reward, termination and info share it)."""
        now = self.robot.time()
        if self._base is None or self._base[0] != now:
            self._base = (now, self.truth.base_state())
        return self._base[1]

    def observed_base_state(self) -> BaseState:
        """The base state the robot reports (estimated, on hardware or with an estimator in a
        simulation's loop), read once per robot time: what observations and controllers use."""
        if self._truth is None:
            return self.base_state()
        now = self.robot.time()
        if self._observed is None or self._observed[0] != now:
            self._observed = (now, self.robot.base_state())
        return self._observed[1]

    def tilt(self) -> float:
        """Angle between the pelvis z axis and the vertical (rad)."""
        x, y, _, _ = self.base_state().quaternion
        return math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (x * x + y * y))))

    def is_terminated(self) -> bool:
        return bool(self.base_state().position[2] < self.min_height or self.tilt() > self.max_tilt)

    def residual_description(self, controller: str) -> dict[str, Any]:
        """What a deployed residual policy needs beside its weights (ONNX metadata): the
        controller beneath it, the action layout and scales, the joints' defaults and gains, and
        the observation scalings."""
        d = self.description
        return {
            **super().describe(),
            "controller": controller,
            "action_layout": self.layout.describe(),
            "action_scale": self.layout.scales.tolist(),
            "default_joint_positions": d.default_positions.tolist(),
            "kp": d.kp.tolist(),
            "kd": d.kd.tolist(),
            "effort_limits": d.effort_limits.tolist(),
            "observation_scales": {"angular_velocity": ANGULAR_VELOCITY_SCALE, "joint_velocity": JOINT_VELOCITY_SCALE},
        }
