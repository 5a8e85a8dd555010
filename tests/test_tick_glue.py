"""The per-tick glue's shortcuts (issue 37) against the general paths they skip: the same numbers, bit
for bit, and the same errors."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import giwbc.envs
from giwbc.locomotion.footsteps import other_side
from giwbc.robot.conventions import wxyz_to_xyzw
from giwbc.robot.interface import quat_to_matrix
from giwbc.tasks.task import ActionBlock, ResidualLayout


def _unit_quaternions(count: int, seed: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(count, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quat_to_matrix_on_python_floats_is_the_numpy_scalar_arithmetic_bit_for_bit() -> None:
    for quat in _unit_quaternions(300, 37):
        fast = quat_to_matrix(quat)  # a float64 array: the Python-float path
        scalars = quat_to_matrix([np.float64(x) for x in quat])  # the general path: numpy scalars
        assert fast.dtype == np.float64 and fast.tobytes() == scalars.tobytes()
        # a rotation: orthonormal, right-handed
        assert np.allclose(fast @ fast.T, np.eye(3), atol=1e-14) and np.linalg.det(fast) == pytest.approx(1.0, abs=1e-14)
    single = quat_to_matrix(_unit_quaternions(1, 3)[0].astype(np.float32))  # other dtypes keep their arithmetic
    assert single.dtype == np.float32


def test_wxyz_to_xyzw_gathers_a_new_array_with_the_list_path_entries() -> None:
    for quat in _unit_quaternions(20, 38):
        fast = wxyz_to_xyzw(quat)
        assert fast.tobytes() == wxyz_to_xyzw(list(quat)).tobytes()
        assert fast[3] == quat[0] and np.array_equal(fast[:3], quat[1:])
        fast[0] = 99.0
        assert quat[1] != 99.0  # a copy, not a view of the input
    assert wxyz_to_xyzw(np.ones(4, dtype=np.float32)).dtype == np.float32


def test_a_torque_command_is_held_apart_from_the_callers_array() -> None:
    env = gymnasium.make(giwbc.envs.CARTPOLE_BALANCE).unwrapped
    env.reset(seed=1)
    robot = env.sim_robot
    torques = np.full(robot.dofs, 0.5)
    robot.set_joint_torques(torques)
    held = robot.data.ctrl.copy()
    torques[:] = 7.0  # the caller reuses its buffer: the held command must not change
    robot.step(3)
    assert np.array_equal(robot.data.ctrl, held) and np.all(held[: robot.dofs] == 0.5)
    env.close()


def test_other_side() -> None:
    assert other_side("left") == "right" and other_side("right") == "left"
    with pytest.raises(ValueError, match="side must be 'left' or 'right', got 'up'"):
        other_side("up")


def test_residual_split_clips_as_np_clip_bit_for_bit() -> None:
    layout = ResidualLayout([ActionBlock("com", 3, 0.05), ActionBlock("posture", 4, (0.1, 0.2, 0.3, 0.4))])
    rng = np.random.default_rng(39)
    actions = rng.uniform(-3.0, 3.0, (200, 7))
    actions[0] = [1.0, -1.0, 0.0, -0.0, 1.0 + 1e-16, np.nextafter(1.0, 2.0), np.nextafter(-1.0, -2.0)]  # edges
    for action in actions:
        split = layout.split(action)
        expected = np.clip(action, -1.0, 1.0) * layout.scales
        assert np.concatenate([split["com"], split["posture"]]).tobytes() == expected.tobytes()
        assert np.all(np.abs(split["com"]) <= 0.05)  # within each entry's scale
    assert layout.split([2.0, 0.5, -2.0, 0.0, 0.0, 0.0, 0.0])["com"].tolist() == [0.05, 0.025, -0.05]  # a list, clipped


def test_mujoco_imu_and_efforts_read_what_their_general_paths_read(g1) -> None:
    from giwbc.robot import MujocoRobot
    from giwbc.robot.mujoco_model import imu_sensor_names

    robot = MujocoRobot(g1)
    robot.reset()
    robot.set_joint_torques(np.random.default_rng(40).uniform(-5.0, 5.0, robot.dofs))
    robot.step(20)  # moving: every channel non-trivial
    names = imu_sensor_names()
    reading = robot.imu()
    quaternion = robot.sensor(names["quaternion"])
    assert reading.quaternion.tobytes() == np.array([*quaternion[1:], quaternion[0]]).tobytes()
    assert reading.angular_velocity.tobytes() == robot.sensor(names["angular_velocity"]).tobytes()
    assert reading.linear_acceleration.tobytes() == robot.sensor(names["linear_acceleration"]).tobytes()
    assert reading.time == robot.time() == pytest.approx(0.04) and np.linalg.norm(reading.quaternion) == pytest.approx(1.0)
    reading.angular_velocity[:] = 1e9  # copies: the next reading is unaffected
    assert robot.imu().angular_velocity.tobytes() == robot.sensor(names["angular_velocity"]).tobytes()
    efforts = np.zeros(robot.dofs)
    efforts[g1.actuated] = robot.data.actuator_force[: int(g1.actuated.sum())]
    assert robot.joint_efforts().tobytes() == efforts.tobytes() and np.any(efforts != 0.0)
