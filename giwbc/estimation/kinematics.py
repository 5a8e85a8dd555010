"""Leg kinematics from encoders: where each foot is and how it moves relative to the IMU, and what
force it carries, from one compiled pass per update (forward kinematics, frame Jacobians and the
legs' RNEA in :func:`giwbc.estimation.kernels.leg_kinematics`, over tables read from the Pinocchio
model once; the tests check it against Pinocchio's own algorithms).

Everything is expressed in world-aligned axes (the estimated base orientation) with the base
origin held at zero, so a stance foot's relative position and velocity are exactly the
measurements the leg Kalman filter needs. The IMU is one more frame of the pass: its position and
velocity come out with the feet's, and the feet's are taken relative to it. The pass runs on a
model of the base and the legs only (the other joints locked): neither the feet's motion nor the
legs' RNEA torques depend on the rest, which would only cost time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from giwbc.estimation import kernels
from giwbc.robot.description import RobotDescription

__all__ = ["LegKinematics", "sole_frame_name"]

IMU_FRAME = "estimator_imu"  # the frame this module adds at the IMU (the base origin without one)


def sole_frame_name(contact_name: str) -> str:
    """Name of the frame this module adds at a contact's sole centre."""
    return f"{contact_name}_sole_center"


class LegKinematics:
    """Per-foot kinematics and contact wrenches of a floating-base robot with flat feet.

    After :meth:`compute`, ``foot_positions[i]`` is foot ``i``'s sole centre minus the IMU position
    and ``foot_velocities[i]`` its velocity relative to an IMU that does not translate (both world
    axes), ``imu_offset`` the IMU position minus the base origin, and ``foot_wrenches[i]``
    the wrench ``(force, torque)`` the ground exerts at the sole centre, estimated from the leg's
    joint efforts (``J_leg^T w = M(q) a + g(q) + C(q, v) v - tau``: quasi-statically, ``a = 0``,
    unless :meth:`compute` is given the base's and the joints' accelerations; without them a
    swinging leg's own inertia and the base's acceleration read as ground force, 50-200 N on the
    G1), ``foot_rotations[i]`` the sole's orientation in world axes at the given base orientation.
    """

    def __init__(self, description: RobotDescription, model: pin.Model | None = None) -> None:
        if not description.floating_base or not description.contacts:
            raise ValueError(f"robot {description.name!r}: leg kinematics need a floating base with contacts")
        model = pin.Model(model) if model is not None else description.build_pinocchio()
        self.contact_names = tuple(c.name for c in description.contacts)
        soles, chains = _add_sole_frames(model, description)
        self._leg_joints = [np.array([model.joints[j].idx_v - 6 for j in chain]) for chain in chains]
        self.imu_position, self.imu_rotation = self._imu_placement(description, model)
        base_frame = model.getFrameId(description.base_link)
        base_frame = base_frame if base_frame < model.nframes else 0
        imu = pin.Frame(IMU_FRAME, 1, base_frame, pin.SE3(self.imu_rotation, self.imu_position), pin.FrameType.OP_FRAME)
        model.addFrame(imu, False)
        self.model = model  # the whole robot, with the sole and IMU frames
        self.data = model.createData()
        # Per update, only the legs move the feet and carry their load: the other joints are
        # locked in a reduced model, which gives the same foot kinematics and leg torques (a
        # joint's RNEA torque depends on the bodies it carries only) at about half the cost.
        leg_set = set().union(*chains)
        legs = model if len(leg_set) == model.njoints - 2 else _legs_only(model, leg_set)
        self._legs = legs
        self._frames = tuple(legs.getFrameId(name) for name in (*soles, IMU_FRAME))  # the feet, then the IMU
        # Index maps: description joint order -> the reduced model's joints, and each leg's
        # joints -> columns of the reduced model's velocity (slices where contiguous).
        description_index = {model.names[j]: model.joints[j].idx_v - 6 for j in range(2, model.njoints)}
        self._leg_model_joints = _as_index([description_index[legs.names[j]] for j in range(2, legs.njoints)])
        leg_v = {legs.names[j]: legs.joints[j].idx_v for j in range(2, legs.njoints)}
        self._leg_columns = [_as_index([leg_v[model.names[j]] for j in chain]) for chain in chains]
        self._leg_rows = [_as_index([leg_v[model.names[j]] - 6 for j in chain]) for chain in chains]
        # Legs of 6 joints each, none shared: together, their J_leg^T w = tau systems are one
        # square system (a foot's Jacobian is zero on the other legs' joints), solved in one call.
        self._block_legs = all(len(c) == 6 for c in chains) and sum(map(len, chains)) == len(leg_set) == legs.nv - 6
        n = len(chains)
        # The compiled pass's tables and index arrays (kernels.leg_kinematics)
        self._tables = kernels.joint_tables(legs, list(self._frames))
        self._gravity = np.array(legs.gravity.linear, dtype=float)
        self._index = np.array([description_index[legs.names[j]] for j in range(2, legs.njoints)], dtype=np.int64)
        self._leg_column_table = (np.array([[leg_v[model.names[j]] for j in chain] for chain in chains], dtype=np.int64)
                                  if self._block_legs else np.zeros((n, 6), dtype=np.int64))
        self._bias = np.zeros(legs.nv - 6)  # RNEA torques less the efforts, the reduced model's joint order
        self._no_joint_values = np.zeros(len(description_index))
        self._q = pin.neutral(legs)
        self._q[:3] = 0.0
        self._v = np.zeros(legs.nv)
        self._zero = np.zeros(legs.nv)
        self._a = np.zeros(legs.nv)  # the accelerations of the inertial term, when given
        self._jacobians = np.zeros((n + 1, 6, legs.nv))  # LOCAL_WORLD_ALIGNED, of the feet then the IMU
        self._frame_motion = np.zeros((n + 1, 6))  # their world position and velocity (base at 0, not translating)
        self._relative_motion = np.zeros((n, 6))  # the feet's minus the IMU's
        self.foot_positions = self._relative_motion[:, :3]  # views: updated by compute
        self.foot_velocities = self._relative_motion[:, 3:]
        self.imu_offset = self._frame_motion[n, :3]
        self.foot_wrenches = np.zeros((n, 6))
        self.foot_rotations = np.zeros((n, 3, 3))  # each sole frame in world axes (at the estimated base orientation)
        self.foot_angular_velocities = np.zeros((n, 3))  # each sole's, world axes: gyro plus leg joint rates (a rolling foot)
        self._pose_q, self._pose_data = self._q.copy(), legs.createData()  # for sole_rotations (compute's own stay untouched)

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

    def sole_rotations(self, joint_positions: np.ndarray) -> np.ndarray:
        """Each sole's orientation in the base frame (n, 3, 3) at ``joint_positions``."""
        model, data, q = self._legs, self._pose_data, self._pose_q
        q[3:7] = (0.0, 0.0, 0.0, 1.0)
        q[7:] = np.asarray(joint_positions, float)[self._leg_model_joints]
        pin.framesForwardKinematics(model, data, q)
        return np.array([data.oMf[frame].rotation for frame in self._frames[: self.n_feet]])

    @property
    def n_feet(self) -> int:
        return len(self._leg_joints)

    def leg_joints(self, foot: int) -> np.ndarray:
        """Indices (description joint order) of the joints between the base and foot ``foot``."""
        return self._leg_joints[foot]

    def compute(
        self,
        base_quaternion: Sequence[float],
        base_angular_velocity: Sequence[float],
        joint_positions: np.ndarray,
        joint_velocities: np.ndarray,
        joint_efforts: np.ndarray | None,
        base_acceleration: Sequence[float] | None = None,
        joint_accelerations: np.ndarray | None = None,
    ) -> None:
        """Fill the per-foot arrays. ``base_angular_velocity`` is in the base frame; the base
        orientation only rotates the results into world axes (and orients gravity).

        ``base_acceleration`` (base frame: the base origin's linear acceleration, gravity not
        included, then the angular acceleration) and ``joint_accelerations`` (description order),
        given together, add the legs' inertial term to the wrenches (each None: quasi-static)."""
        q, v, n = self._q, self._v, self.n_feet
        q[3:7] = base_quaternion
        v[3:6] = base_angular_velocity
        a, mode = self._zero, 0
        if joint_efforts is not None:
            mode = kernels.DYNAMICS | (kernels.SOLVE if self._block_legs else 0)
            if base_acceleration is not None and joint_accelerations is not None:
                a = self._a
                a[:6] = base_acceleration
                mode |= kernels.INERTIAL
        none = self._no_joint_values
        singular = kernels.leg_kinematics(
            *self._tables, self._gravity, self._leg_column_table, self._index, q, v, a, joint_positions, joint_velocities,
            none if joint_efforts is None else joint_efforts, none if joint_accelerations is None else joint_accelerations, mode,
            self._jacobians, self._frame_motion, self._relative_motion, self.foot_rotations, self.foot_angular_velocities,
            self._bias, self.foot_wrenches,
        )
        if singular:
            raise np.linalg.LinAlgError(f"leg of foot {self.contact_names[singular - 1]!r} is singular")
        if joint_efforts is not None and not self._block_legs:
            for i in range(n):
                self.foot_wrenches[i] = self._leg_wrench(i, self._bias)

    def _leg_wrench(self, foot: int, bias: np.ndarray) -> np.ndarray:
        """The wrench at ``foot`` that its leg's ``bias`` torques (RNEA minus efforts) balance."""
        leg_jacobian_t = self._jacobians[foot][:, self._leg_columns[foot]].T
        rows = bias[self._leg_rows[foot]]
        if leg_jacobian_t.shape[1] != 6:
            return np.linalg.lstsq(leg_jacobian_t, rows, rcond=None)[0]
        *_, wrench, info = lapack.dgesv(leg_jacobian_t, rows)
        if info != 0:
            raise np.linalg.LinAlgError(f"leg of foot {self.contact_names[foot]!r} is singular")
        return wrench


def _add_sole_frames(model: pin.Model, description: RobotDescription) -> tuple[list[str], list[list[int]]]:
    """Add a frame at each contact's sole centre to ``model``. Returns the frames' names and, per
    contact, the joints between the base and its link (the leg, without the free flyer)."""
    names, chains = [], []
    for contact in description.contacts:
        link = model.getFrameId(contact.link)
        if link >= model.nframes:
            raise ValueError(f"contact link {contact.link!r} is not a frame of the Pinocchio model")
        parent = model.frames[link]
        placement = parent.placement * pin.SE3(np.eye(3), np.asarray(contact.center, float))
        names.append(sole_frame_name(contact.name))
        model.addFrame(pin.Frame(names[-1], parent.parentJoint, link, placement, pin.FrameType.OP_FRAME), False)
        chains.append([j for j in model.supports[parent.parentJoint] if j > 1])  # skip universe and free flyer
    return names, chains


def _legs_only(model: pin.Model, legs: set[int]) -> pin.Model:
    """``model`` with every joint but the free flyer and ``legs`` locked (at the neutral pose)."""
    locked = [j for j in range(2, model.njoints) if j not in legs]
    return pin.buildReducedModel(model, locked, pin.neutral(model))


def _as_index(indices: list[int]) -> slice | np.ndarray:
    """``indices`` as a slice when they are consecutive (a view instead of a gather), else an array."""
    if indices and indices == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return np.array(indices, dtype=int)
