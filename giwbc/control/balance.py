"""A ready-made standing / balance controller for any robot description with foot contacts.

Double support on every ``ContactRectangle`` of the description, and three tasks:

* **CoM** position (world), the balance task — highest weight;
* **base orientation** (the description's ``base_link``, e.g. the G1 pelvis) upright;
* **posture** towards the description's default joint positions — lowest weight, it resolves
  the redundancy (arms, waist) without fighting the other two;

plus torque limits from the description and the choices that make it stand robustly on a real
(soft, imperfect) contact, all in :class:`BalanceConfig`: a contact-force regularisation towards
the static weight split of the CoM target (the CoM gives way to a push instead of one foot
unloading), a minimum normal force per foot, foot rectangles shrunk to 85 % (a CoP margin) and
damping on the contact motion rows. Optional: joint-limit acceleration bounds, a centroidal
angular-momentum damping task.

References move at run time: :meth:`BalanceController.set_com_target` /
:meth:`~BalanceController.set_com_offset`, :meth:`~BalanceController.set_posture`,
``controller.base_task.set_reference(pin.SE3)``.

``make_balance_controller(description)`` returns a :class:`BalanceController`; the demo, the RL
task (which moves the CoM / posture references) and the deployment use the same object::

    controller = make_balance_controller(load("g1"))
    result = controller.update(q, v, t)          # Pinocchio state, seconds
    robot.set_joint_torques(result.tau)          # or robot.set_joint_impedance(result.impedance)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
import pinocchio as pin

from giwbc.control.contacts import foot_contacts
from giwbc.control.sole import RollDetector
from giwbc.control.tasks import (
    AngularMomentumTask,
    ComTask,
    ContactForceRegularization,
    FrameOrientationTask,
    PostureTask,
)
from giwbc.control.wbc import WbcResult, WholeBodyController
from giwbc.control.yaw_momentum import LimbYawMomentumTask
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import Robot


@dataclass(frozen=True)
class BalanceConfig:
    """Gains, weights and options of :class:`BalanceController` (``kd=None``: critical damping)."""

    solver: str = "proxsuite"
    solver_settings: dict = field(default_factory=dict)
    contact_model: str = "surface"  # "surface" (6D wrench cone) or "corners" (4 pyramids)
    mu: float = 0.8
    # m: the feet's yaw moment kept within torsion x normal force (None: what the sole's friction
    # allows, mu (X + Y) f_z for a rectangle); a compliant floor turns a stance foot well inside that.
    torsion: float | None = None
    # Normal-force bounds per contact (per corner for "corners"), N. Default minimum: 6 % of the
    # weight per contact, so that no foot is ever asked to carry (almost) nothing: under a push the
    # CoM then gives way instead of unloading a foot to the point where it rolls or lifts.
    min_normal_force: float | None = None
    max_normal_force: float | None = None  # default: 3 × the robot's weight
    contact_kd: float = 20.0  # damping feedback on the contact motion rows (settles foot micro-motion)
    contact_kp: float = 0.0  # pose feedback on the contact motion rows
    support_scale: float = 0.85  # foot support polygons shrunk about their centres: a CoP margin
    # A foot that rolls (sole tilted past roll_tilt_on deg since the contact was made, predicted
    # roll_lookahead s ahead from its angular velocity) stands on the edge or corner it rolled onto
    # (giwbc.control.sole), with pose feedback roll_kp back towards flat; 0 deg: not watched.
    # Off by default: on the capsule / point-foot plants (tuning seeds) standing on the rolled edge
    # did not stop the walking rock (20° either way) and point feet tracked worse (0.35 vs 0.04 m/s).
    roll_tilt_on: float = 0.0  # deg (3.0 detects a rolling foot and leaves the nominal plant's walk bit-identical)
    roll_tilt_off: float = 1.5  # deg
    roll_lookahead: float = 0.01  # s
    roll_kp: float = 0.0  # 1/s^2
    roll_supports: bool = True  # a rolled foot stands on its edge / corner (else only learning below)
    sole_learning_step: float = 0.0  # m: each roll moves the edge the foot rolled over inward by this (rectangular soles)
    com_kp: float = 100.0
    com_kd: float | None = None
    com_weight: float = 10.0
    base_kp: float = 100.0
    base_kd: float | None = None
    base_weight: float = 1.0
    posture_kp: float = 50.0
    posture_kd: float | None = None
    posture_weight: float = 0.05
    angular_momentum_weight: float = 0.0  # > 0 adds the momentum-damping task
    angular_momentum_kd: float = 10.0
    # > 0 adds the limbs' yaw momentum task (giwbc.control.yaw_momentum): the yaw momentum the joints
    # make (a swinging leg) decays at ``limb_yaw_momentum_kd`` 1/s, taken by the trunk and arms instead
    # of a yaw moment on the stance foot, which a compliant floor does not hold (the foot turns).
    limb_yaw_momentum_weight: float = 0.0
    limb_yaw_momentum_kd: float = 20.0
    # Contact-force regularisation towards the static weight split of the CoM target: large enough
    # to make the CoM compliant to pushes (the feet keep sharing the load), small enough to track
    # commanded CoM motion.
    force_weight: float = 1e-3
    torque_limit_scale: float = 1.0
    # Joint position/velocity limits as acceleration bounds: off for standing (the posture stays
    # far from the limits and the bounds cost ~25 µs a tick); turn on when references can push
    # joints towards their limits.
    joint_limits: bool = False
    joint_limit_margin: float = 0.0  # rad: the bounds keep the joints this far inside their limits
    # (zone rad, kp N m/rad, kd N m s/rad): a torque back out of the last `zone` before each joint's kept
    # limit, on top of the QP's (WholeBodyController.set_limit_spring: a foot rolling on its rim turns
    # with its ankle roll, which the QP's acceleration bounds cannot stop). None: off. Off by default:
    # (0.05, 600, 10) keeps the walking G1's ankle rolls 0.05-0.1 rad further from their limits on the
    # rounded, capsule, point and all_at_once plants and leaves the nominal walk bit-identical, but
    # standing push recovery uses the ankle roll's full range (100 N pushes, seed 20000: 8/8 -> 5/8).
    limit_spring: tuple[float, float, float] | None = None
    acceleration_regularization: float = 1e-6
    impedance_kp_scale: float = 0.0  # impedance output gains, fractions of the description's kp/kd
    impedance_kd_scale: float = 0.1
    impedance_lookahead: float = 0.0
    contact_ramp_time: float = 0.0  # s, for contacts made at construction


class BalanceController:
    """Double-support balance on a :class:`WholeBodyController` (see the module docstring).

    References: the CoM target defaults to the CoM at the first tick (or at :meth:`reset`), the
    base orientation to upright with the initial heading, the posture to the default pose.
    """

    def __init__(self, description: RobotDescription, config: BalanceConfig | None = None, model: pin.Model | None = None) -> None:
        if not description.contacts:
            raise ValueError(f"robot {description.name!r} has no foot contacts; a balance controller needs some")
        if not description.floating_base:
            raise ValueError(f"robot {description.name!r} has a fixed base; balance needs a floating base")
        self.description = description
        self.config = config = config or BalanceConfig()
        model = description.pinocchio_model if model is None else model
        weight = description.total_mass * 9.81
        self.wbc = WholeBodyController(
            model,
            dt=description.timestep,
            solver=config.solver,
            solver_settings=dict(config.solver_settings),
            torque_limits=description.effort_limits * config.torque_limit_scale,
            joint_limits=config.joint_limits,
            joint_limit_margin=config.joint_limit_margin,
            acceleration_regularization=config.acceleration_regularization,
            impedance_kp=description.kp * config.impedance_kp_scale,
            impedance_kd=description.kd * config.impedance_kd_scale,
            impedance_lookahead=config.impedance_lookahead,
            fallback_kd=description.kd,
        )
        if config.limit_spring is not None:
            self.wbc.set_limit_spring(*config.limit_spring)
        max_force = 3.0 * weight if config.max_normal_force is None else config.max_normal_force
        min_force = 0.06 * weight if config.min_normal_force is None else config.min_normal_force
        if config.contact_model == "corners" and config.min_normal_force is None:
            min_force /= 4.0
        self.contacts = foot_contacts(
            description,
            config.contact_model,
            mu=config.mu,
            min_normal_force=min_force,
            max_normal_force=max_force,
            kd=config.contact_kd,
            kp=config.contact_kp,
            scale=config.support_scale,
            roll=None if config.roll_tilt_on <= 0 else RollDetector(math.radians(config.roll_tilt_on), math.radians(config.roll_tilt_off), config.roll_lookahead),
            roll_kp=config.roll_kp,
            roll_supports=config.roll_supports,
            learn_step=config.sole_learning_step,
            torsion=config.torsion,
        )
        for contact in self.contacts:
            self.wbc.add_contact(contact, ramp_time=config.contact_ramp_time)
        self.com_task = ComTask(weight=config.com_weight, kp=config.com_kp, kd=config.com_kd)
        self.base_task = FrameOrientationTask(
            description.base_link, weight=config.base_weight, kp=config.base_kp, kd=config.base_kd
        )
        self.posture_task = PostureTask(
            reference=description.default_positions, weight=config.posture_weight, kp=config.posture_kp, kd=config.posture_kd
        )
        self.wbc.add_task(self.com_task)
        self.wbc.add_task(self.base_task)
        self.wbc.add_task(self.posture_task)
        self.momentum_task: AngularMomentumTask | None = None
        if config.angular_momentum_weight > 0:
            self.momentum_task = AngularMomentumTask(weight=config.angular_momentum_weight, kd=config.angular_momentum_kd)
            self.wbc.add_task(self.momentum_task)
        self.limb_yaw_task: LimbYawMomentumTask | None = None
        if config.limb_yaw_momentum_weight > 0:
            self.limb_yaw_task = LimbYawMomentumTask(weight=config.limb_yaw_momentum_weight, kd=config.limb_yaw_momentum_kd)
            self.wbc.add_task(self.limb_yaw_task)
        self.force_regularization = ContactForceRegularization(weight=config.force_weight)
        self.wbc.add_task(self.force_regularization)
        self.nominal_com: np.ndarray | None = None

    # --- references ------------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None) -> None:
        """Back to the freshly constructed state, references anchored at configuration ``q``
        (default: the description's standing pose): CoM target = its CoM, base upright with its
        heading, posture = default pose, no momentum reference. Nothing of past ticks survives
        (:meth:`WholeBodyController.reset`: clock, last torque, failure counts, contact ramps,
        solver warm start, active set): a used controller after ``reset(q)`` gives bit-identical
        torques to a new one."""
        q = self.description.default_configuration() if q is None else np.asarray(q, dtype=float)
        self.wbc.reset()
        for contact in self.contacts:  # as made at construction (whatever was removed or re-made since)
            self.wbc.add_contact(contact, ramp_time=self.config.contact_ramp_time)
        kin = self.wbc.kin
        kin.update(q, np.zeros(kin.nv))
        self.nominal_com = np.array(kin.com)
        self.set_com_target(self.nominal_com)
        base = kin.frame_placement(kin.frame_id(self.description.base_link))
        self.base_task.set_reference(pin.SE3(_heading(base.rotation), base.translation))
        self.posture_task.set_reference(self.description.default_positions)
        if self.momentum_task is not None:
            self.momentum_task.set_reference(np.zeros(3))

    def set_com_target(self, position: np.ndarray, velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
        """Absolute CoM target (world), with optional feed-forward velocity and acceleration."""
        self.com_task.set_reference(position, velocity, acceleration)
        self.force_regularization.set_support_point(self.com_task.position_ref)

    def set_com_offset(self, offset: np.ndarray, velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
        """CoM target relative to the nominal CoM (the one of :meth:`reset` or the first tick)."""
        if self.nominal_com is None:
            raise RuntimeError("the nominal CoM is set by reset() or the first update()")
        self.set_com_target(self.nominal_com + np.asarray(offset, dtype=float), velocity, acceleration)

    def set_posture(self, positions: np.ndarray, velocities: np.ndarray | None = None) -> None:
        """Posture target (joint positions, description order), clipped into the joint limits."""
        lower, upper = self.description.position_limits
        self.posture_task.set_reference(np.clip(np.asarray(positions, dtype=float), lower, upper), velocities)

    # --- the tick ----------------------------------------------------------------------------------
    def update(self, q: np.ndarray, v: np.ndarray, t: float | None = None) -> WbcResult:
        """One WBC tick for Pinocchio state ``(q, v)`` at time ``t`` (s)."""
        if self.nominal_com is None:
            self.reset(q)
        return self.wbc.update(q, v, t)

    def step(self, robot: Robot) -> WbcResult:
        """Read ``robot``'s state, run one tick and command its joint torques."""
        q, v = robot.generalized_state()
        result = self.update(q, v, robot.time())
        robot.set_joint_torques(result.tau)
        return result


def _heading(rotation: np.ndarray) -> np.ndarray:
    """The yaw-only rotation with the same heading as ``rotation``."""
    yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_balance_controller(
    description: RobotDescription, config: BalanceConfig | None = None, *, model: pin.Model | None = None, **overrides: object
) -> BalanceController:
    """The standing/balance controller of a description; ``overrides`` replace config fields
    (``make_balance_controller(g1, solver="osqp", com_kp=150.0)``)."""
    config = config or BalanceConfig()
    if overrides:
        config = replace(config, **overrides)  # type: ignore[arg-type]
    return BalanceController(description, config, model)


class StateEstimate(Protocol):
    """What a controller closing its loop on an estimate reads: Pinocchio ``(q, v)``."""

    q: np.ndarray
    v: np.ndarray


class BalanceOnEstimate:
    """The balance controller closing its loop on an estimate: ``(q, v)`` from the estimator, joint
    torques to the robot. Called like :class:`giwbc.robot.standing.PdHold`: ``controller(robot, estimate)``."""

    def __init__(self, description: RobotDescription, **overrides: object) -> None:
        self.controller = make_balance_controller(description, **overrides)
        self.failures = 0

    def __call__(self, robot: Robot, estimate: StateEstimate) -> None:
        result = self.controller.update(estimate.q, estimate.v, robot.time())
        self.failures = result.failures
        robot.set_joint_torques(result.tau)
