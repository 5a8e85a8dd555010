"""Foot forces and the base velocity when legs swing hard and stance feet roll (issue 41): the
effort-based force of a leg in the air is no ground force once the legs' inertia is in it, a foot
force is never a pull, a fast-moving foot carries nothing, and a stance foot that turns is no
evidence that the base moves. Synthetic measurements from Pinocchio's own dynamics: exact, fast."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from giwbc.estimation.estimator import ANY_FEET, EstimatorConfig, Measurement, StateEstimator
from giwbc.estimation.kinematics import LegKinematics, sole_frame_name
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import ImuReading

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
DT = 0.002  # s: a 500 Hz control tick
G = 9.81


@pytest.fixture(scope="module")
def model(g1: RobotDescription) -> pin.Model:
    return g1.build_pinocchio()


def _sole_jacobians(g1: RobotDescription, kin: LegKinematics, q: np.ndarray) -> list[np.ndarray]:
    """Each sole centre's (6, nv) Jacobian, world-aligned, at ``q`` (the whole robot)."""
    data = kin.model.createData()
    pin.computeJointJacobians(kin.model, data, q)
    pin.framesForwardKinematics(kin.model, data, q)
    return [pin.getFrameJacobian(kin.model, data, kin.model.getFrameId(sole_frame_name(c.name)), LWA) for c in g1.contacts]


def test_a_leg_in_the_air_carries_no_force_once_its_inertia_is_counted(g1: RobotDescription, model: pin.Model) -> None:
    """Joint efforts that only move the legs and the base (RNEA with 200 rad/s^2 joint and 3 m/s^2
    base accelerations), plus a 300 N ground wrench on the right foot: the quasi-static estimate
    reads tens of newtons on the left foot, which is in the air; with the accelerations it reads
    none there and the right foot's wrench exactly."""
    rng = np.random.default_rng(41)
    kin = LegKinematics(g1)
    q = pin.neutral(model)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.05, -0.08, 0.3)).coeffs()
    q[7:] = g1.default_positions
    v = np.zeros(model.nv)  # the base does not translate (the kinematics' frame), it turns
    v[3:6] = (0.3, -0.5, 0.2)
    v[6:] = rng.normal(0.0, 2.0, g1.dofs)
    a = np.zeros(model.nv)
    a[:3] = (1.5, -2.0, 3.0)  # the base's linear acceleration, base frame
    a[3:6] = (4.0, -6.0, 2.0)
    a[6:] = rng.normal(0.0, 200.0, g1.dofs)
    ground = np.array([20.0, -15.0, 300.0, 3.0, -4.0, 1.0])  # on the right sole's centre, world axes
    right = [c.name for c in g1.contacts].index("right_foot") if "right_foot" in [c.name for c in g1.contacts] else 1
    jacobian = _sole_jacobians(g1, kin, q)[right]
    efforts = pin.rnea(model, model.createData(), q, v, a)[6:] - jacobian[:, 6:].T @ ground

    kin.compute(q[3:7], v[3:6], q[7:], v[6:], efforts)
    static = kin.foot_wrenches.copy()
    kin.compute(q[3:7], v[3:6], q[7:], v[6:], efforts, a[:6], a[6:])
    left = 1 - right
    assert abs(static[left, 2]) > 30.0  # the quasi-static estimate reads the swinging leg as force
    np.testing.assert_allclose(kin.foot_wrenches[left], 0.0, atol=1e-6)
    np.testing.assert_allclose(kin.foot_wrenches[right], ground, atol=1e-6)


def _standing(g1: RobotDescription, model: pin.Model, positions: np.ndarray, velocities: np.ndarray,
              accelerations: np.ndarray, loads: tuple[float, float]) -> np.ndarray:
    """Joint efforts of the robot whose base stands still and level, its legs moving as given,
    each foot pushed up by its ``loads`` (N) at the sole centre."""
    kin = LegKinematics(g1)
    q = pin.neutral(model)
    q[7:] = positions
    v = np.zeros(model.nv)
    v[6:] = velocities
    a = np.zeros(model.nv)
    a[6:] = accelerations
    efforts = pin.rnea(model, model.createData(), q, v, a)[6:]
    for jacobian, load in zip(_sole_jacobians(g1, kin, q), loads):
        efforts -= jacobian[2, 6:] * load
    return efforts


def _measurement(time: float, positions: np.ndarray, velocities: np.ndarray, efforts: np.ndarray) -> Measurement:
    """A level, still IMU (no bias) and the given joints."""
    imu = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, G]), time)
    return Measurement(imu, positions.copy(), velocities.copy(), efforts.copy())


def _swing(g1: RobotDescription, model: pin.Model, config: EstimatorConfig) -> float:
    """The left hip pitch swinging +-0.4 rad at 2 Hz (63 rad/s^2 peak) with the left foot in the air,
    the right foot carrying the weight: the largest force estimated on the left foot over 0.4 s."""
    estimator = StateEstimator(g1, config)
    names = list(g1.joint_names)
    hip = names.index("left_hip_pitch_joint")
    left = [c.name for c in g1.contacts].index("left_foot") if "left_foot" in [c.name for c in g1.contacts] else 0
    weight = g1.total_mass * G
    loads = (0.0, weight) if left == 0 else (weight, 0.0)
    largest = 0.0
    omega = 2.0 * math.pi * 2.0
    for k in range(200):
        t = k * DT
        positions = g1.default_positions.copy()
        velocities = np.zeros(g1.dofs)
        accelerations = np.zeros(g1.dofs)
        positions[hip] += 0.4 * math.sin(omega * t)
        velocities[hip] = 0.4 * omega * math.cos(omega * t)
        accelerations[hip] = -0.4 * omega * omega * math.sin(omega * t)
        efforts = _standing(g1, model, positions, velocities, accelerations, loads)
        estimate = estimator.update(_measurement(t, positions, velocities, efforts))
        if k >= 10:  # past the low-passes' start
            largest = max(largest, float(np.linalg.norm(estimate.contact_forces[left])))
    return largest


def test_a_swinging_leg_is_read_as_no_ground_force(g1: RobotDescription, model: pin.Model) -> None:
    """The estimator with the legs' inertia (accelerations from the joint velocities, low-passed):
    a leg swinging at 63 rad/s^2 in the air reads under 25 N (the walker's touch-down threshold is
    0.15-0.35 of the weight, 50-120 N; what is left is the 5 ms low-pass's lag); quasi-statically it
    reads over 100 N."""
    config = EstimatorConfig(calibrate=False, force_inertia=True)
    assert _swing(g1, model, config) < 25.0
    assert _swing(g1, model, EstimatorConfig(calibrate=False)) > 100.0


def test_a_foot_force_is_never_a_pull(g1: RobotDescription, model: pin.Model) -> None:
    """Efforts that would pull the feet down onto the floor (the ground cannot): the reported
    force is zero, never negative, while the leg's raw estimate is a pull."""
    estimator = StateEstimator(g1, EstimatorConfig(calibrate=False))
    weight = g1.total_mass * G
    efforts = _standing(g1, model, g1.default_positions, np.zeros(g1.dofs), np.zeros(g1.dofs), (-0.3 * weight, 0.5 * weight))
    estimate = estimator.update(_measurement(0.0, g1.default_positions, np.zeros(g1.dofs), efforts))
    assert estimator.kinematics.foot_wrenches[0, 2] < -50.0
    np.testing.assert_array_equal(estimate.contact_forces[0], 0.0)
    assert estimate.contact_forces[1, 2] > 0.4 * weight


def test_a_foot_moving_fast_carries_no_force(g1: RobotDescription, model: pin.Model) -> None:
    """``force_max_speed``: the same loaded efforts, the foot's sole centre moving at 1.5 times the
    limit (its ankle turning fast): no force; still: its full force."""
    config = EstimatorConfig(calibrate=False, force_max_speed=1.0)
    weight = g1.total_mass * G
    positions, still = g1.default_positions, np.zeros(g1.dofs)
    efforts = _standing(g1, model, positions, still, still, (0.5 * weight, 0.5 * weight))
    estimator = StateEstimator(g1, config)
    standing = estimator.update(_measurement(0.0, positions, still, efforts))
    assert standing.contact_forces[0, 2] == pytest.approx(0.5 * weight, rel=0.02)
    moving = still.copy()
    knee = list(g1.joint_names).index("left_knee_joint")
    moving[knee] = 8.0  # rad/s: the foot ~0.3 m below the knee, ~2 m/s
    speed = np.linalg.norm(StateEstimator(g1, config).kinematics.foot_velocities[0])  # (zeros: not computed yet)
    assert speed == 0.0
    estimate = estimator.update(_measurement(DT, positions, moving, efforts))
    assert np.linalg.norm(estimator.kinematics.foot_velocities[0]) > 1.5
    np.testing.assert_array_equal(estimate.contact_forces[0], 0.0)
    assert estimate.contact_forces[1, 2] == pytest.approx(0.5 * weight, rel=0.05)


def _rolling_foot_velocity(g1: RobotDescription, model: pin.Model, overrides: dict) -> float:
    """Standing still 0.2 s, then the left ankle rolling at 5 rad/s for 40 ms (the foot rocking onto
    its rim) while the IMU feels no acceleration: the base's estimated speed at the end."""
    estimator = StateEstimator(g1, EstimatorConfig(**{"calibrate": False, **overrides}))
    weight = g1.total_mass * G
    roll = list(g1.joint_names).index("left_ankle_roll_joint")
    positions, velocities = g1.default_positions.copy(), np.zeros(g1.dofs)
    for k in range(120):
        if k >= 100:
            velocities[roll] = 5.0
            positions[roll] += 5.0 * DT
        efforts = _standing(g1, model, positions, velocities, np.zeros(g1.dofs), (0.5 * weight, 0.5 * weight))
        estimate = estimator.update(_measurement(k * DT, positions, velocities, efforts))
    return float(np.linalg.norm(estimate.base.linear_velocity))


def test_a_rolling_stance_foot_is_no_evidence_that_the_base_moves(g1: RobotDescription, model: pin.Model) -> None:
    """A loaded foot turning at 5 rad/s, the IMU at rest: with ``roll_velocity_rate`` (ANY_FEET)
    the base's speed stays under 2 cm/s; taking the turning foot's velocity and position as a
    still foot's, the base is estimated to move several times faster."""
    rolling = _rolling_foot_velocity(g1, model, dict(ANY_FEET))
    trusted = _rolling_foot_velocity(g1, model, {**ANY_FEET, "roll_velocity_rate": 0.0})
    assert rolling < 0.02
    assert trusted > 3.0 * rolling and trusted > 0.03
