"""MujocoRobot implements the Robot interface with physically consistent readings."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.robot import ImpedanceCommand, MujocoRobot, RobotDescription
from giwbc.robot.interface import base_velocity_local, quat_to_matrix

GRAVITY = 9.81


@pytest.fixture(scope="module")
def g1_robot(g1: RobotDescription) -> MujocoRobot:
    return MujocoRobot(g1)


def pd_hold(description: RobotDescription) -> ImpedanceCommand:
    zeros = np.zeros(description.dofs)
    return ImpedanceCommand(description.default_positions, zeros, description.kp, description.kd, zeros)


def test_g1_stands_10_s_under_joint_pd(g1_robot: MujocoRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_impedance(pd_hold(g1))
    heights, tilts = [], []
    for _ in range(100):  # 10 s in 0.1 s chunks
        g1_robot.step(50)
        base = g1_robot.base_state()
        heights.append(base.position[2])
        tilts.append(np.degrees(np.arccos(np.clip(base.rotation[2, 2], -1, 1))))
    assert g1_robot.time() == pytest.approx(10.0)
    assert min(heights) > g1.default_base_position[2] - 0.03
    assert max(heights) < g1.default_base_position[2] + 0.01
    assert max(tilts) < 3.0
    assert np.linalg.norm(g1_robot.base_state().position[:2]) < 0.02


def test_standing_contact_forces_balance_weight(g1_robot: MujocoRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_impedance(pd_hold(g1))
    g1_robot.step(1000)
    wrenches = [g1_robot.contact_wrench(c.link) for c in g1.contacts]
    assert all(w.in_contact for w in wrenches)
    total = sum(w.force for w in wrenches)
    assert total[2] == pytest.approx(g1.total_mass * GRAVITY, rel=2e-3)
    assert np.linalg.norm(total[:2]) < 0.01 * total[2]
    assert not g1_robot.contact_wrench("pelvis").in_contact


def test_imu_at_rest_reads_gravity_and_base_orientation(g1_robot: MujocoRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_impedance(pd_hold(g1))
    g1_robot.step(1000)
    imu = g1_robot.imu()
    rotation = quat_to_matrix(imu.quaternion)
    # Specific force at rest is +g along world z, seen in the IMU frame.
    np.testing.assert_allclose(imu.linear_acceleration, rotation.T @ [0, 0, GRAVITY], atol=0.05)
    np.testing.assert_allclose(imu.angular_velocity, 0.0, atol=0.01)
    _, pelvis_rotation = g1_robot.link_pose("pelvis")
    np.testing.assert_allclose(rotation, pelvis_rotation, atol=1e-9)  # the IMU frame is not rotated in the pelvis
    assert imu.time == pytest.approx(g1_robot.time())


def test_torque_and_impedance_commands_are_equivalent(g1: RobotDescription) -> None:
    rng = np.random.default_rng(3)
    a, b = MujocoRobot(g1), MujocoRobot(g1)
    command = pd_hold(g1)
    command.tau_ff = rng.normal(scale=2.0, size=g1.dofs)
    a.set_joint_impedance(command)
    q, v = b.joint_positions(), b.joint_velocities()
    b.set_joint_torques(command.torque(q, v))
    a.step(1)
    b.step(1)
    np.testing.assert_allclose(a.joint_efforts(), b.joint_efforts(), atol=1e-9)
    # Same torque; the impedance path lets the implicit integrator treat kd implicitly, so the
    # next state differs by O(dt^2 kd / inertia) only.
    assert np.abs(a.joint_positions() - b.joint_positions()).max() < 2e-3


def test_efforts_are_clipped_to_limits(g1_robot: MujocoRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_torques(np.full(g1.dofs, 1e4))
    g1_robot.step(1)
    np.testing.assert_allclose(g1_robot.joint_efforts(), g1.effort_limits)


def test_generalized_state_matches_base_state(g1_robot: MujocoRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_external_wrench("pelvis", [30.0, 20.0, 0.0], [0.0, 0.0, 5.0])
    g1_robot.step(100)
    g1_robot.set_external_wrench("pelvis", np.zeros(3))
    q, v = g1_robot.generalized_state()
    base = g1_robot.base_state()
    np.testing.assert_allclose(q[:3], base.position)
    np.testing.assert_allclose(q[3:7], base.quaternion)
    np.testing.assert_allclose(v[:6], base_velocity_local(base), atol=1e-12)
    np.testing.assert_allclose(q[7:], g1_robot.joint_positions())
    assert np.linalg.norm(base.linear_velocity) > 1e-3  # the push moved the base


def test_bad_commands_are_rejected(g1_robot: MujocoRobot) -> None:
    with pytest.raises(ValueError, match="expected 29 joint torques"):
        g1_robot.set_joint_torques(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        g1_robot.set_joint_torques(np.full(29, np.nan))
    bad = ImpedanceCommand.damping(29, 1.0)
    bad.kp = -np.ones(29)
    with pytest.raises(ValueError, match=">= 0"):
        g1_robot.set_joint_impedance(bad)
    with pytest.raises(KeyError, match="no link 'tail'"):
        g1_robot.link_pose("tail")


def test_cartpole_pole_falls_and_cart_is_pushed(cartpole: RobotDescription) -> None:
    robot = MujocoRobot(cartpole)
    robot.reset(q=np.array([0.0, 0.05]))
    robot.set_joint_torques(np.array([5.0, 0.0]))
    robot.step(500)
    q = robot.joint_positions()
    assert q[0] > 0.5 * 0.5 * (5.0 / 1.2) * 0.5**2 * 0.5  # the cart moved forward under the force
    assert abs(q[1]) > 0.1  # the passive pole fell
    assert robot.joint_efforts()[1] == 0.0  # the pivot has no actuator
