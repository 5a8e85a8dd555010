"""The estimator's outputs against MuJoCo truth where one sensor decides the answer: a gyro with a
known constant bias (the estimated bias and the bias-corrected angular velocity), and a free fall
with no stance foot (the velocity then comes from the accelerometer alone, gravity added back)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.robot import MujocoRobot, RobotDescription
from giwbc.robot.estimator import EstimatorConfig, Measurement, StateEstimator
from giwbc.robot.noise import SensorErrors, SensorModel
from giwbc.robot.standing import pd_hold_command

GYRO_BIAS = np.array([0.03, -0.02, 0.025])  # rad/s, IMU frame (the G1's IMU is not rotated in the pelvis)


@pytest.fixture(scope="module")
def g1_models(g1: RobotDescription):
    return g1.build_mujoco(), g1.build_pinocchio()


def test_estimator_learns_a_known_gyro_bias_and_removes_it_from_the_angular_velocity(g1: RobotDescription, g1_models) -> None:
    mj_model, pin_model = g1_models
    sim = MujocoRobot(g1, mj_model)
    sim.set_joint_impedance(pd_hold_command(g1))
    sensors = SensorModel(sim, SensorErrors(gyro_bias=GYRO_BIAS), np.random.default_rng(0))  # exact but for the bias
    estimator = StateEstimator(g1, EstimatorConfig(gyro_bias_gain=1.0), model=pin_model)
    dt = g1.timestep
    errors, speeds = [], []
    for k in range(int(8.0 / dt)):
        wobble = 8.0 * np.sin(2 * np.pi * 0.7 * k * dt)  # a gentle sway: the base keeps turning
        sim.set_external_wrench("pelvis", [0.3 * wobble, wobble, 0.0], [0.0, 0.0, 0.4 * wobble])
        estimate = estimator.update(Measurement.from_robot(sensors))
        if k * dt >= 7.0:  # the last second, after the bias has converged
            truth = sim.base_state()
            errors.append(estimate.base.angular_velocity - truth.angular_velocity)
            speeds.append(np.linalg.norm(truth.angular_velocity))
            np.testing.assert_allclose(estimate.base.rotation @ estimate.v[3:6], estimate.base.angular_velocity, atol=1e-12)
        sim.step()
    assert np.sqrt(np.mean(np.square(speeds))) > 0.03  # the base did turn: tracking, not a constant
    np.testing.assert_allclose(estimate.gyro_bias, GYRO_BIAS, atol=2e-3)
    # The bias is 0.044 rad/s: an estimate that kept it would be off by that much.
    error = np.linalg.norm(errors, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.004 and error.max() < 0.02, (np.sqrt(np.mean(error**2)), error.max())


def test_free_fall_velocity_comes_from_the_accelerometer_with_gravity_added_back(g1: RobotDescription, g1_models) -> None:
    """Dropped from 1 m with no foot in contact: the accelerometer reads ~0 and the estimated
    velocity must follow gravity, as the true one does."""
    mj_model, pin_model = g1_models
    sim = MujocoRobot(g1, mj_model)
    q = g1.default_configuration().copy()
    q[2] += 1.0
    sim.reset(q, np.zeros(pin_model.nv))
    sim.set_joint_impedance(pd_hold_command(g1))
    estimator = StateEstimator(g1, model=pin_model)
    airborne = np.zeros(len(g1.contacts), dtype=bool)
    start = sim.base_state().position.copy()
    estimate = estimator.update(Measurement.from_robot(sim), airborne)
    first = estimate.base.position.copy()
    for _ in range(int(0.3 / g1.timestep)):  # 0.3 s: 0.44 m down, still in the air
        sim.step()
        estimate = estimator.update(Measurement.from_robot(sim), airborne)
    truth = sim.base_state()
    assert truth.linear_velocity[2] == pytest.approx(-9.81 * 0.3, rel=0.02)  # it did fall freely
    assert not any(sim.contact_wrench(c.link).in_contact for c in g1.contacts)
    np.testing.assert_allclose(estimate.base.linear_velocity, truth.linear_velocity, atol=0.05)
    np.testing.assert_allclose(estimate.base.position - first, truth.position - start, atol=0.01)
    assert estimator.fault_counts.get("NO_STANCE_FOOT", 0) == int(0.3 / g1.timestep)  # every update said so
