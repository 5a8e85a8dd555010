"""Leg kinematics from encoders: where each foot is and how it moves relative to the IMU, and what
force it carries, from one Pinocchio pass (joint Jacobians + RNEA) per update.

Everything is expressed in world-aligned axes (the estimated base orientation) with the base
origin held at zero, so a stance foot's relative position and velocity are exactly the
measurements the leg Kalman filter needs.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from giwbc.robot.description import RobotDescription
from giwbc.robot.estimation.so3 import cross

__all__ = ["LegKinematics", "sole_frame_name"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def sole_frame_name(contact_name: str) -> str:
    """Name of the frame this module adds at a contact's sole centre."""
    return f"{contact_name}_sole_center"


class LegKinematics:
    """Per-foot kinematics and contact wrenches of a floating-base robot with flat feet.

    After :meth:`compute`, ``foot_positions[i]`` is foot ``i``'s sole centre minus the IMU position
    and ``foot_velocities[i]`` its velocity relative to an IMU that does not translate (both world
    axes), ``imu_offset`` the IMU position minus the base origin, and ``foot_wrenches[i]`` the
    wrench ``(force, torque)`` the ground exerts at the sole centre, estimated quasi-statically
    from the leg's joint efforts (``J_leg^T w = g(q) + C(q, v) v - tau``).
    """

    def __init__(self, description: RobotDescription, model: pin.Model | None = None) -> None:
        if not description.floating_base or not description.contacts:
            raise ValueError(f"robot {description.name!r}: leg kinematics need a floating base with contacts")
        model = pin.Model(model) if model is not None else description.build_pinocchio()
        self.contact_names = tuple(c.name for c in description.contacts)
        self._feet = []
        self._leg_joints = []
        for contact in description.contacts:
            link = model.getFrameId(contact.link)
            if link >= model.nframes:
                raise ValueError(f"contact link {contact.link!r} is not a frame of the Pinocchio model")
            parent = model.frames[link]
            placement = parent.placement * pin.SE3(np.eye(3), np.asarray(contact.center, float))
            frame = pin.Frame(sole_frame_name(contact.name), parent.parentJoint, link, placement, pin.FrameType.OP_FRAME)
            self._feet.append(model.addFrame(frame, False))
            chain = [j for j in model.supports[parent.parentJoint] if j > 1]  # skip universe and free flyer
            self._leg_joints.append(np.array([model.joints[j].idx_v - 6 for j in chain]))
        self.imu_position, self.imu_rotation = self._imu_placement(description, model)
        self.model = model
        self.data = model.createData()
        n = len(self._feet)
        self._q = pin.neutral(model)
        self._q[:3] = 0.0
        self._v = np.zeros(model.nv)
        self._zero = np.zeros(model.nv)
        self.foot_positions = np.zeros((n, 3))
        self.foot_velocities = np.zeros((n, 3))
        self.foot_wrenches = np.zeros((n, 6))
        self.imu_offset = np.zeros(3)
        self._jacobians = [np.zeros((6, model.nv)) for _ in range(n)]
        self._leg_columns = [6 + joints for joints in self._leg_joints]

    @staticmethod
    def _imu_placement(description: RobotDescription, model: pin.Model) -> tuple[np.ndarray, np.ndarray]:
        """IMU position and orientation in the base frame (rigidly attached to the base)."""
        if description.imu_frame is None:
            return np.zeros(3), np.eye(3)
        frame = model.frames[model.getFrameId(description.imu_frame)]
        if frame.parentJoint != 1:
            raise NotImplementedError(
                f"IMU frame {description.imu_frame!r} is not rigidly attached to the base {description.base_link!r}: "
                "the estimator supports base-mounted IMUs only"
            )
        return frame.placement.translation.copy(), frame.placement.rotation.copy()

    @property
    def n_feet(self) -> int:
        return len(self._feet)

    def leg_joints(self, foot: int) -> np.ndarray:
        """Indices (description joint order) of the joints between the base and foot ``foot``."""
        return self._leg_joints[foot]

    def compute(
        self,
        base_quaternion: np.ndarray,
        base_angular_velocity: np.ndarray,
        joint_positions: np.ndarray,
        joint_velocities: np.ndarray,
        joint_efforts: np.ndarray | None,
        base_rotation: np.ndarray | None = None,
    ) -> None:
        """Fill the per-foot arrays. ``base_angular_velocity`` is in the base frame; the base
        orientation (``base_rotation``: its matrix, when the caller has it) only rotates the
        results into world axes (and orients gravity)."""
        model, data, q, v = self.model, self.data, self._q, self._v
        q[3:7] = base_quaternion
        q[7:] = joint_positions
        v[3:6] = base_angular_velocity
        v[6:] = joint_velocities
        pin.computeJointJacobians(model, data, q)
        rotation = data.oMi[1].rotation if base_rotation is None else base_rotation
        self.imu_offset[:] = rotation @ self.imu_position
        imu_velocity = cross(rotation @ base_angular_velocity, self.imu_offset)
        for i, frame in enumerate(self._feet):
            self.foot_positions[i] = pin.updateFramePlacement(model, data, frame).translation
            jacobian = pin.getFrameJacobian(model, data, frame, _LWA)
            self._jacobians[i] = jacobian
            self.foot_velocities[i] = jacobian[:3] @ v
        self.foot_positions -= self.imu_offset
        self.foot_velocities -= imu_velocity
        if joint_efforts is not None:
            bias = pin.rnea(model, data, q, v, self._zero)[6:] - joint_efforts
            for i, joints in enumerate(self._leg_joints):
                leg_jacobian_t = self._jacobians[i][:, self._leg_columns[i]].T
                if len(joints) == 6:
                    *_, wrench, info = lapack.dgesv(leg_jacobian_t, bias[joints])
                    if info != 0:
                        raise np.linalg.LinAlgError(f"leg of foot {self.contact_names[i]!r} is singular")
                    self.foot_wrenches[i] = wrench
                else:
                    self.foot_wrenches[i] = np.linalg.lstsq(leg_jacobian_t, bias[joints], rcond=None)[0]
