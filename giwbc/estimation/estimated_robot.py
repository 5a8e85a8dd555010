"""A robot whose base state comes from a :class:`~giwbc.estimation.estimator.StateEstimator`
(:class:`EstimatedRobot`): hardware and noisy simulations measure no base; wrapped, a controller
runs unchanged on them (``giwbc deploy`` runs ``EstimatedRobot(CanRobot(...))``)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from giwbc.estimation.estimator import Estimate, StateEstimator
from giwbc.robot.interface import BaseState, ContactWrench, ImuReading, Robot, RobotWrapper, quat_to_matrix
from giwbc.robot.so3 import cross, matrix_to_quat


class EstimatedRobot(RobotWrapper):
    """A robot whose base state comes from a :class:`StateEstimator` fed by its measurements.

    Wraps a robot that does not measure its base (hardware, a :class:`~giwbc.robot.noise.NoisyRobot`);
    the estimator updates once per new ``robot.time()``, on the first read of the base state, or
    when the owner of the cycle calls :meth:`update` (the real-time runtime does after every
    exchange with the motors, so the estimator runs through start-up, whatever the task reads).
    A contact plan set with :meth:`set_contact_plan` is passed to every update.
    """

    def __init__(self, robot: Robot, estimator: StateEstimator) -> None:
        super().__init__(robot)
        self.estimator = estimator
        self._updated_at: float | None = None
        self._plan: np.ndarray | None = None
        self._latest: Estimate | None = None
        self._feet: tuple[Estimate, list[np.ndarray]] | None = None  # (estimate, foot link rotations)
        self._frames: list[int] | None = None

    @property
    def ready(self) -> bool:
        """Whether the estimator finished its start-up calibration (the estimate may be used)."""
        return self.estimate.ready

    def set_contact_plan(self, contacts: np.ndarray | None) -> None:
        """The controller's contact plan (None: detect contacts from forces)."""
        self._plan = None if contacts is None else np.asarray(contacts, dtype=bool)

    @property
    def estimate(self) -> Estimate:
        """The estimate for the robot's current time (updating the estimator if time moved)."""
        now = self.robot.time()
        if now != self._updated_at:
            self._latest = self.estimator.update_from_robot(self.robot, self._plan)
            self._updated_at = now
        return self.estimator.estimate

    def update(self, fuse: bool = True) -> Estimate | None:
        """Bring the estimate to the robot's current time now: fuse the robot's measurement when
        ``fuse`` (the caller knows a new IMU sample came), else keep the last estimate (a repeated
        sample is no new information). Reads at this time then do not update again. Returns the
        estimate of the last fused measurement (None before the first)."""
        if fuse:
            self._latest = self.estimator.update_from_robot(self.robot, self._plan)
        self._updated_at = self.robot.time()
        return self._latest

    @property
    def latest_estimate(self) -> Estimate | None:
        """The estimate of the last fused measurement (None before the first): what the run log records."""
        return self._latest

    # --- estimated ------------------------------------------------------------------------
    def base_state(self) -> BaseState:
        return self.estimate.base

    def imu(self) -> ImuReading:
        """The robot's IMU sample; from an IMU without an orientation output (an all-NaN quaternion:
        a MEMS gyro and accelerometer) its orientation is the estimate's (the base's, carried to the
        IMU frame), once the estimator is calibrated: what a task's gravity observation needs, on
        the robot as in simulation (it was NaN, and a policy's action with it)."""
        reading = self.robot.imu()
        quaternion = reading.quaternion
        if not np.isnan(quaternion).all():
            return reading
        estimate = self.estimate
        if not estimate.ready:
            return reading
        rotation = quat_to_matrix(estimate.base.quaternion) @ self.estimator.kinematics.imu_rotation
        return ImuReading(matrix_to_quat(rotation), reading.angular_velocity, reading.linear_acceleration, reading.time)

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The estimate's Pinocchio ``(q, v)`` (joints as the estimator last read them)."""
        estimate = self.estimate
        return estimate.q.copy(), estimate.v.copy()

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """A link's world pose at the estimated configuration."""
        model, data = self.estimator.kinematics.model, self.estimator.kinematics.data
        frame = model.getFrameId(link)
        if frame >= model.nframes:
            raise KeyError(f"robot {self.name!r} has no link {link!r}")
        pin.framesForwardKinematics(model, data, self.estimate.q)
        placement = data.oMf[frame]
        return placement.translation.copy(), placement.rotation.copy()

    def contact_wrench(self, link: str) -> ContactWrench:
        """The estimated ground force on a contact link (torque about the link origin from the
        force acting at the sole centre)."""
        names = [c.link for c in self.estimator.description.contacts]
        if link not in names:
            raise KeyError(f"no contact on link {link!r}; contacts are on {names}")
        index = names.index(link)
        estimate = self.estimate
        force = estimate.contact_forces[index]
        lever = self._foot_rotations(estimate)[index] @ np.asarray(self.estimator.description.contacts[index].center, float)
        return ContactWrench(force.copy(), cross(lever, force), bool(estimate.contacts[index]))

    def _foot_rotations(self, estimate: Estimate) -> list[np.ndarray]:
        """World rotations of the contact links at the estimate's configuration: one kinematics
        pass per estimate for all feet (a full pass per foot per tick was 5 % of a walking step),
        only what the lever of a contact wrench needs."""
        cached = self._feet
        if cached is not None and cached[0] is estimate:
            return cached[1]
        model, data = self.estimator.kinematics.model, self.estimator.kinematics.data
        pin.framesForwardKinematics(model, data, estimate.q)
        rotations = [data.oMf[frame].rotation.copy() for frame in self._foot_frames(model)]
        self._feet = (estimate, rotations)
        return rotations

    def _foot_frames(self, model: pin.Model) -> list[int]:
        if self._frames is None:
            self._frames = [model.getFrameId(c.link) for c in self.estimator.description.contacts]
        return self._frames


__all__ = ["EstimatedRobot"]
