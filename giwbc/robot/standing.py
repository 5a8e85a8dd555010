"""A joint-PD standing hold: the simplest controller, and the baseline the WBC must beat."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import ImpedanceCommand, Robot


def pd_hold_command(description: RobotDescription) -> ImpedanceCommand:
    """Impedance command holding the default pose with the description's gains."""
    zeros = np.zeros(description.dofs)
    return ImpedanceCommand(description.default_positions, zeros.copy(), description.kp, description.kd, zeros.copy())


class PdHold:
    """The joint-PD hold of the default pose as a controller; the actuators evaluate it.

    One class for both controller shapes of the project: the first call sends the hold to
    ``robot`` (a loop that calls ``controller(robot, estimate)`` and expects it to command the
    robot: the actuators then hold it, nothing more is sent), and every call returns it (a loop
    that sends what ``controller(robot)`` returns, as :class:`~giwbc.tasks.standing.StandingTask`).
    """

    def __init__(self, description: RobotDescription) -> None:
        self.command = pd_hold_command(description)
        self._sent = False

    def __call__(self, robot: Robot, estimate: object = None) -> ImpedanceCommand:
        if not self._sent:
            robot.set_joint_impedance(self.command)
            self._sent = True
        return self.command


@dataclass(frozen=True)
class StandingSummary:
    """What a standing run did, in numbers a person can check."""

    seconds: float
    wall_seconds: float
    min_base_height: float
    max_base_height: float
    max_tilt_deg: float
    base_drift_m: float
    vertical_contact_force: float
    weight: float
    floating_base: bool = True

    @property
    def real_time_factor(self) -> float:
        return self.seconds / self.wall_seconds

    @property
    def stood(self) -> bool:
        """A floating base stood if it stayed upright; a fixed base cannot fall."""
        if not self.floating_base:
            return True
        return self.max_tilt_deg < 10.0 and self.min_base_height > 0.5 * self.max_base_height


def base_tilt_deg(robot: Robot) -> float:
    """Angle between the base z axis and the world z axis."""
    return float(np.degrees(np.arccos(np.clip(robot.base_state().rotation[2, 2], -1.0, 1.0))))
