"""A MuJoCo state round trip: ``reset(q, v)`` at a random orientation and velocity, read back through
``generalized_state()`` (Pinocchio's convention) and ``base_state()`` (world frame), each checked
against a second source that does not share the robot's conversions: MuJoCo's own kinematics
(``xpos``/``xmat``, ``mj_objectVelocity``) and Pinocchio's forward kinematics."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from giwbc.robot import MujocoRobot, RobotDescription
from giwbc.robot.interface import quat_to_matrix


def random_unit_quaternion(rng: np.random.Generator) -> np.ndarray:
    quaternion = rng.normal(size=4)
    return quaternion / np.linalg.norm(quaternion)


def mujoco_frame_velocity(robot: MujocoRobot, link: str, local: bool) -> tuple[np.ndarray, np.ndarray]:
    """(linear, angular) velocity of a body's frame origin from MuJoCo itself, world or body axes."""
    body = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_XBODY, link)
    twist = np.zeros(6)  # MuJoCo's order: rotational then linear
    mujoco.mj_objectVelocity(robot.model, robot.data, mujoco.mjtObj.mjOBJ_XBODY, body, twist, int(local))
    return twist[3:], twist[:3]


def pinocchio_link(model: pin.Model, q: np.ndarray, v: np.ndarray, link: str) -> tuple[pin.SE3, pin.Motion]:
    """A link's placement and world-aligned velocity from Pinocchio's forward kinematics of ``(q, v)``."""
    data = model.createData()
    pin.forwardKinematics(model, data, q, v)
    pin.updateFramePlacements(model, data)
    frame = model.getFrameId(link)
    return data.oMf[frame], pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED)


@pytest.fixture(scope="module")
def g1_pair(g1: RobotDescription) -> tuple[MujocoRobot, pin.Model]:
    return MujocoRobot(g1), g1.build_pinocchio()


@pytest.mark.parametrize("trial", range(4))
def test_floating_base_round_trip_at_a_random_state(g1_pair, g1: RobotDescription, trial: int) -> None:
    robot, model = g1_pair
    rng = np.random.default_rng(100 + trial)
    q = g1.default_configuration().copy()
    q[:3] = rng.uniform(-1.0, 1.0, 3) + [0.0, 0.0, 2.0]
    q[3:7] = random_unit_quaternion(rng)
    q[7:] += rng.uniform(-0.3, 0.3, g1.dofs)
    v = rng.normal(size=model.nv)  # base part in the base frame (Pinocchio)
    robot.reset(q, v)

    # 1. Pinocchio's convention back, exactly (the quaternion up to its sign).
    q_back, v_back = robot.generalized_state()
    sign = np.sign(q_back[3:7] @ q[3:7])
    np.testing.assert_allclose(q_back[:3], q[:3], atol=1e-12)
    np.testing.assert_allclose(sign * q_back[3:7], q[3:7], atol=1e-12)
    np.testing.assert_allclose(q_back[7:], q[7:], atol=1e-12)
    np.testing.assert_allclose(v_back, v, atol=1e-12)

    # 2. The base as MuJoCo itself sees it: pose of the base body, its velocity in world and body axes.
    rotation = quat_to_matrix(q[3:7])
    base = robot.base_state()
    position, mj_rotation = robot.link_pose(g1.base_link)
    np.testing.assert_allclose(mj_rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(base.rotation, mj_rotation, atol=1e-12)
    np.testing.assert_allclose(base.position, position, atol=1e-12)
    world_linear, world_angular = mujoco_frame_velocity(robot, g1.base_link, local=False)
    local_linear, local_angular = mujoco_frame_velocity(robot, g1.base_link, local=True)
    np.testing.assert_allclose(base.linear_velocity, world_linear, atol=1e-10)
    np.testing.assert_allclose(base.angular_velocity, world_angular, atol=1e-10)
    np.testing.assert_allclose(v_back[:3], local_linear, atol=1e-10)
    np.testing.assert_allclose(v_back[3:6], local_angular, atol=1e-10)

    # 3. Pinocchio's kinematics of the state read back: every contact link where MuJoCo has it.
    for link in [c.link for c in g1.contacts] + [g1.base_link]:
        placement, velocity = pinocchio_link(model, q_back, v_back, link)
        mj_position, mj_link_rotation = robot.link_pose(link)
        np.testing.assert_allclose(placement.translation, mj_position, atol=1e-9)
        np.testing.assert_allclose(placement.rotation, mj_link_rotation, atol=1e-9)
        linear, angular = mujoco_frame_velocity(robot, link, local=False)
        np.testing.assert_allclose(velocity.linear, linear, atol=1e-8)
        np.testing.assert_allclose(velocity.angular, angular, atol=1e-8)


def test_floating_base_round_trip_survives_a_physics_step(g1_pair, g1: RobotDescription) -> None:
    """After MuJoCo integrates (its own qpos/qvel, not ours), both readings still agree with MuJoCo."""
    robot, model = g1_pair
    rng = np.random.default_rng(7)
    q = g1.default_configuration().copy()
    q[2] += 1.0
    q[3:7] = random_unit_quaternion(rng)
    robot.reset(q, rng.normal(size=model.nv))
    robot.step(5)
    mujoco.mj_forward(robot.model, robot.data)  # MuJoCo's own kinematics of the integrated qpos (mj_step leaves them one step old)
    q_back, v_back = robot.generalized_state()
    base = robot.base_state()
    world_linear, world_angular = mujoco_frame_velocity(robot, g1.base_link, local=False)
    np.testing.assert_allclose(base.angular_velocity, world_angular, atol=1e-10)
    np.testing.assert_allclose(base.rotation @ v_back[3:6], world_angular, atol=1e-10)
    np.testing.assert_allclose(base.rotation @ v_back[:3], world_linear, atol=1e-10)
    placement, _ = pinocchio_link(model, q_back, v_back, g1.contacts[0].link)
    np.testing.assert_allclose(placement.translation, robot.link_pose(g1.contacts[0].link)[0], atol=1e-9)


@pytest.mark.parametrize("trial", range(3))
def test_fixed_base_round_trip(cartpole: RobotDescription, trial: int) -> None:
    robot = MujocoRobot(cartpole)
    model = cartpole.build_pinocchio()
    rng = np.random.default_rng(200 + trial)
    q, v = rng.uniform(-1.0, 1.0, model.nq), rng.normal(size=model.nv)
    robot.reset(q, v)
    q_back, v_back = robot.generalized_state()
    np.testing.assert_allclose(q_back, q, atol=1e-12)
    np.testing.assert_allclose(v_back, v, atol=1e-12)
    np.testing.assert_allclose(robot.joint_positions(), q, atol=1e-12)
    np.testing.assert_allclose(robot.joint_velocities(), v, atol=1e-12)
    # The fixed base reports its pose, in (x, y, z, w) like every quaternion of the interface, at rest.
    base = robot.base_state()
    position, rotation = robot.link_pose(cartpole.base_link)
    np.testing.assert_allclose(base.rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(base.position, position, atol=1e-12)
    assert np.linalg.norm(base.quaternion) == pytest.approx(1.0)
    np.testing.assert_array_equal(base.linear_velocity, 0.0)
    np.testing.assert_array_equal(base.angular_velocity, 0.0)
    placement, _ = pinocchio_link(model, q, v, cartpole.base_link)
    np.testing.assert_allclose(base.rotation, placement.rotation, atol=1e-12)
    # The moving link agrees with Pinocchio too (the joint state went in and came out unchanged).
    placement, velocity = pinocchio_link(model, q_back, v_back, "pole")
    np.testing.assert_allclose(placement.translation, robot.link_pose("pole")[0], atol=1e-9)
    linear, angular = mujoco_frame_velocity(robot, "pole", local=False)
    np.testing.assert_allclose(velocity.linear, linear, atol=1e-9)
    np.testing.assert_allclose(velocity.angular, angular, atol=1e-9)
