"""Apply a physics sample to a :class:`~giwbc.robot.pybullet_robot.PybulletRobot`.

Every value is written from the sample (nominal where it randomized nothing), so nothing
accumulates. What PyBullet cannot do in place, and how it is done instead:

* centres of mass: PyBullet cannot move a link's inertial frame after loading, so a sample with
  ``link_com`` reloads the robot with the new inertials (~2 ms for the G1, the state is reset);
* restitution: Bullet multiplies the two bodies' coefficients; the feet hold 1, the floor the sample;
* armature: emulated on the link inertias (see :mod:`giwbc.robot.pybullet_robot`);
* joint damping: Bullet's ``jointDamping``, applied explicitly (MuJoCo's is implicit).
"""

from __future__ import annotations

import numpy as np

from giwbc.randomization.distributions import RandomizationError
from giwbc.randomization.parameters import MUJOCO_ONLY, Nominal
from giwbc.randomization.sampling import Sample
from giwbc.robot.pybullet_model import LinkInertial
from giwbc.robot.pybullet_robot import PybulletRobot


class PybulletApplier:
    """Writes physics samples into one PyBullet robot."""

    def __init__(self, robot: PybulletRobot, nominal: Nominal) -> None:
        self.robot = robot
        self.nominal = nominal
        self._armature = robot.armature.copy()
        self._effort = robot.effort_limits.copy()
        self._gravity = robot.gravity.copy()
        self._friction = robot.description.floor_friction
        self._reloaded = False

    def restore(self) -> None:
        """The nominal robot back (reloading it if a centre of mass had been moved)."""
        self.apply(None)

    def apply(self, sample: Sample | None) -> None:
        robot, nominal = self.robot, self.nominal.values
        touched = sample.randomized if sample is not None else frozenset()
        if touched & MUJOCO_ONLY:
            raise RandomizationError(f"{sorted(touched & MUJOCO_ONLY)} are MuJoCo's (engine-level) parameters; this episode runs on PyBullet")

        def value(name: str) -> np.ndarray:
            return sample[name] if name in touched else nominal[name]

        masses = value("link_mass")
        if "link_com" in touched:
            coms = sample["link_com"]
            inertials = {
                link: LinkInertial(float(m), tuple(float(x) for x in c))
                for link, m, c in zip(self.nominal.links, masses, coms)
                if m > 0
            }
            robot.reload(inertials)
            self._reloaded = True
        elif self._reloaded:
            robot.reload(None)
            self._reloaded = False
        robot.set_link_masses({link: m for link, m, m0 in zip(self.nominal.links, masses, nominal["link_mass"]) if m0 > 0})
        if "joint_armature" in touched or robot.armature.any():
            robot.set_armature(sample["joint_armature"] if "joint_armature" in touched else self._armature)
        robot.set_joint_damping(value("joint_damping"))
        robot.set_joint_friction(value("joint_friction"))
        robot.effort_limits[:] = sample["actuator_strength"] if "actuator_strength" in touched else self._effort
        robot.set_gravity(sample["gravity"] if "gravity" in touched else self._gravity)
        if robot.floor is not None:
            friction = float(sample.scalar("ground_friction")) if "ground_friction" in touched else self._friction
            restitution = float(sample.scalar("ground_restitution")) if "ground_restitution" in touched else 0.0
            robot.set_ground(friction, restitution)
