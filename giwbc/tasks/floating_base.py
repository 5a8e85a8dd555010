"""What every Task over a floating-base robot reads the same way: the base state once per robot
time, the pelvis tilt, and the fall test that reward, termination and info share."""

from __future__ import annotations

import math

from giwbc.robot.interface import BaseState
from giwbc.tasks.task import Task

__all__ = ["FloatingBaseTask"]


class FloatingBaseTask(Task):
    """A :class:`Task` with a floating base: fallen when the base is below ``min_height`` (m) or
    tilted beyond ``max_tilt`` (rad); subclasses set both and clear ``_base`` at reset."""

    min_height: float
    max_tilt: float
    _base: tuple[float, BaseState] | None = None

    def base_state(self) -> BaseState:
        """The robot's base state, read once per robot time (reward, termination and info share it)."""
        now = self.robot.time()
        if self._base is None or self._base[0] != now:
            self._base = (now, self.robot.base_state())
        return self._base[1]

    def tilt(self) -> float:
        """Angle between the pelvis z axis and the vertical (rad)."""
        x, y, _, _ = self.base_state().quaternion
        return math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (x * x + y * y))))

    def is_terminated(self) -> bool:
        return bool(self.base_state().position[2] < self.min_height or self.tilt() > self.max_tilt)
