"""G1Walk's 'torque' residual block: bounded joint torques added to the WBC's on the leg joints, off by default."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the ids)
from giwbc.tasks.walk import WalkScales, torque_joints


def _knee_actuator(model) -> int:
    joint = model.joint("left_knee_joint").id
    return int(np.flatnonzero(model.actuator_trnid[:, 0] == joint)[0])


def test_torque_block_adds_its_bounded_torque_to_the_wbc_output():
    env = gymnasium.make("giwbc/G1Walk-v0", residuals=["step", "torque"])
    try:
        task = env.unwrapped.task
        names = task.action_names()
        legs = [n.split("/", 1)[1] for n in names if n.startswith("torque/")]
        assert len(legs) == 12 and all(("hip" in n or "knee" in n or "ankle" in n) for n in legs)
        assert "waist_yaw_joint" not in legs
        env.reset(seed=3)
        action = np.zeros(env.action_space.shape, dtype=np.float32)
        action[names.index("torque/left_knee_joint")] = 3.0  # beyond the bound: clipped to 1 (5 % of 139 N m)
        env.step(action)
        robot = env.unwrapped.engine_robot
        knee = env.unwrapped.task.description.joint_names.index("left_knee_joint")
        sent = robot.data.ctrl[_knee_actuator(robot.model)]
        assert sent - task.result.tau[knee] == pytest.approx(0.05 * 139.0, abs=1e-9)
        # every other joint gets the WBC's torque unchanged
        others = [i for i in range(robot.model.nu) if i != _knee_actuator(robot.model)]
        joint_of = {int(robot.model.actuator_trnid[i, 0]): i for i in range(robot.model.nu)}
        for i, name in enumerate(task.description.joint_names):
            actuator = joint_of[robot.model.joint(name).id]
            if actuator in others:
                assert robot.data.ctrl[actuator] == task.result.tau[i]
    finally:
        env.close()


def test_torque_block_is_off_by_default_and_validated():
    env = gymnasium.make("giwbc/G1Walk-v0")
    assert not any(n.startswith("torque/") for n in env.unwrapped.task.action_names())
    description = env.unwrapped.task.description
    env.close()
    assert len(torque_joints(description)) == 12
    with pytest.raises(ValueError, match="fraction of the effort limit"):
        WalkScales(torque=0.5)


def test_deployed_walk_policy_task_puts_the_torque_block_on_the_feed_forward():
    """giwbc deploy's WalkPolicyTask (impedance commands): the torque residual reaches the actuators
    as feed-forward torque, exactly as much as in the simulation."""
    from giwbc.apps.deploy_walk import WalkPolicyTask
    from giwbc.robot import load
    from giwbc.robot.mujoco_robot import MujocoRobot
    from giwbc.tasks.rates import Rates

    g1 = load("g1")
    sent = []
    for knee in (0.0, 1.0):
        task = WalkPolicyTask(g1, residuals=["step", "torque"], walker="deployment")
        robot = MujocoRobot(g1)
        task.bind(robot, Rates.from_timestep(float(robot.model.opt.timestep), 50.0, 500.0))
        task.np_random = np.random.default_rng(0)
        robot.reset(*task.initial_state())
        task.reset_task()
        action = np.zeros(task.layout.size)
        action[list(task.action_names()).index("torque/left_knee_joint")] = knee
        task.set_action(action)
        task.apply_command()
        sent.append(robot.data.ctrl.copy())
    difference = sent[1] - sent[0]
    knee_actuator = _knee_actuator(robot.model)
    assert difference[knee_actuator] == pytest.approx(0.05 * 139.0, abs=1e-9)
    assert np.count_nonzero(difference) == 1
