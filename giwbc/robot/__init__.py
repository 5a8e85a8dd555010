"""Robots: descriptions that build matching Pinocchio and MuJoCo models, and the Robot interface."""

from giwbc.robot.collision import CollisionShape
from giwbc.robot.description import (
    ContactRectangle,
    JointSpec,
    RobotDescription,
    RobotDescriptionError,
    available_robots,
    load,
)
from giwbc.robot.interface import BaseState, ContactWrench, DescribedRobot, ImpedanceCommand, ImuReading, Robot
from giwbc.robot.mujoco_robot import MujocoRobot

__all__ = [
    "BaseState",
    "CollisionShape",
    "ContactRectangle",
    "ContactWrench",
    "DescribedRobot",
    "ImpedanceCommand",
    "ImuReading",
    "JointSpec",
    "MujocoRobot",
    "Robot",
    "RobotDescription",
    "RobotDescriptionError",
    "available_robots",
    "load",
]
