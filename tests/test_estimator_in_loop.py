"""The state estimator in a simulated runtime's loop (``sim2real={"estimator": ...}``): the task walks
on the estimate of a datasheet IMU, calibrated at every reset as ``giwbc deploy`` does; reward,
termination and info stay on the truth; pushes count from the end of the calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.errors import EstimatorCalibrationError
from giwbc.envs.factories import g1_walk
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.locomotion.walker_config import DEPLOYMENT_OPTIONS
from giwbc.randomization import PerturbedRobot
from giwbc.runtimes.estimated import EstimatorInLoop
from giwbc.runtimes.sim2real import SimToReal

FORWARD = {"vx": [0.3, 0.3], "vy": [0.0, 0.0], "yaw_rate": [0.0, 0.0], "standing": 0.0, "interval": [100.0, 100.0]}
AHRS = {"imu_profile": "ahrs", "parameters": []}  # per episode: turn-on gyro bias ~0.5 deg/s per axis, noise, latency


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_mujoco()


@pytest.fixture
def make(g1, g1_model):
    def factory(estimator=True, pushes=None, walker="deployment", **kwargs):
        kwargs.setdefault("commands", FORWARD)
        kwargs.setdefault("randomization", AHRS)
        return g1_walk(robot=g1, model=g1_model, residuals=["step"], walker=walker, initial_joint_noise=0.0,
                       sim2real={"estimator": estimator, "pushes": pushes}, **kwargs)

    return factory


def test_walks_on_the_calibrated_estimate_while_reward_and_info_read_the_truth(make):
    env = make()
    observation, info = env.reset(seed=3)
    task, robot = env.task, env.sim_robot
    assert isinstance(task.robot, EstimatedRobot) and task.truth is robot and isinstance(robot, PerturbedRobot)
    estimator = task.robot.estimator
    start = task.robot.time()
    assert estimator.ready and 0.5 < start < 5.0  # the start-up calibration ran on the simulated clock
    assert task.schedule[0][0] == start  # commands count from the episode's start
    # The calibration took the turn-on gyro bias out: what is left is far below the bias itself.
    true_bias = robot.sensors.gyro_bias
    assert np.linalg.norm(true_bias) > 5e-3
    assert np.linalg.norm(estimator.estimate.gyro_bias - true_bias) < 0.25 * np.linalg.norm(true_bias)

    names = task.observation_names()
    vx = names.index("base_velocity/vx")
    start_xy = robot.base_state().position[:2].copy()
    errors = []
    for _ in range(100):  # 2 s at 0.3 m/s
        observation, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, np.float32))
        assert not terminated
        truth, estimate = robot.base_state(), task.robot.base_state()
        np.testing.assert_array_equal(info["base_xy"], truth.position[:2])  # info is the truth
        np.testing.assert_allclose(observation[vx], task.heading_velocity(estimate)[0], atol=1e-6)  # the observation the estimate
        errors.append(np.linalg.norm(truth.linear_velocity[:2] - estimate.linear_velocity[:2]))
    assert task.walker.state.steps >= 3
    assert np.linalg.norm(robot.base_state().position[:2] - start_xy) > 0.3
    assert 0.0 < np.mean(errors) < 0.1  # estimated, not the truth, and close to it


def test_same_seed_same_rollout_and_a_used_env_matches_a_fresh_one(make):
    a, b = make(), make()

    def run(env, seed):
        observation, _ = env.reset(seed=seed)
        out = [observation]
        for _ in range(15):
            out.append(env.step(np.full(env.action_space.shape, 0.3, np.float32))[0])
        return np.array(out)

    first = run(a, 11)
    run(b, 5)  # b used on another seed first
    np.testing.assert_array_equal(first, run(b, 11))
    np.testing.assert_array_equal(first, run(a, 11))


def test_the_estimate_is_bit_identical_after_a_reset_to_a_fresh_environments(make):
    """Float64 estimates, not only the float32 observations: an estimator reset must forget
    everything (its Kalman filter once kept its correction count, so P was symmetrized on other
    ticks than in a new filter: estimates 1e-19 apart after some resets)."""
    used, fresh = make(), make()

    def estimates(env, seed, steps):
        env.reset(seed=seed)
        out = [env.task.robot.estimate.q.copy()]
        for _ in range(steps):
            env.step(np.zeros(env.action_space.shape, np.float32))
            out.append(env.task.robot.estimate.q.copy())
        return np.array(out)

    estimates(used, 4, 7)  # 7 agent steps: a correction count not a multiple of 16
    np.testing.assert_array_equal(estimates(used, 11, 20), estimates(fresh, 11, 20))


def test_the_deployment_walker_lands_on_the_estimated_sole_forces(make):
    """A lateral, turning walk on the estimate (ideal sensors: the estimate's own errors only). Its
    sole forces come from the legs' efforts, and a landed foot carries little until the contact takes
    the weight: waiting for the preset's 0.35 of the weight after the planned touch-down too
    (``late_touchdown_force=None``) pressed the late foot onto its sole edge and stopped the walk on
    an ankle roll's soft limit; the preset counts 0.1 of the weight (on a sole down at the stance
    sole's height) from the planned touch-down on, and walks it."""
    command = {"vx": [0.126, 0.126], "vy": [-0.098, -0.098], "yaw_rate": [-0.188, -0.188], "standing": 0.0, "interval": [100.0, 100.0]}
    options = {"randomization": None, "commands": command, "joint_limit_margin": 0.02,
               "wbc_options": {"joint_limits": True, "joint_limit_margin": 0.04}}
    ends = []
    for walker in ("deployment", {**DEPLOYMENT_OPTIONS, "late_touchdown_force": None}):
        env = make(walker=walker, **options)
        env.reset(seed=511)
        for _ in range(190):  # 3.8 s
            _, _, terminated, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
            if terminated:
                break
        ends.append((terminated, info["steps"]))
    assert not ends[0][0] and ends[0][1] >= 6
    assert ends[1][0]  # waiting for 0.35 of the weight: stopped on the soft limit


def test_pushes_count_from_the_end_of_the_calibration(make):
    env = make(pushes={"interval": [0.5, 0.5], "duration": 0.2, "force": [40.0, 40.0]})
    _, info = env.reset(seed=0)
    start = env.task.robot.time()
    assert info["pushes"] == 0  # none during the calibration (it took longer than 0.5 s)
    assert start > 0.5
    first = None
    for _ in range(40):
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
        if first is None and info["pushes"]:
            first = env.task.robot.time() - start
    assert first is not None and 0.5 <= first <= 0.5 + 0.02 + 1e-9  # the first agent step after 0.5 s of episode


def test_a_robot_that_never_stands_still_is_an_error(make):
    env = make(estimator={"calibration_timeout": 0.3})  # shorter than any standstill window (4 blocks of 0.25 s)
    with pytest.raises(EstimatorCalibrationError, match="did not calibrate within 0.3 s"):
        env.reset(seed=0)


@pytest.mark.parametrize("bad", [
    {"startup_blocks": 1},
    {"calibration_timeout": 0.0},
    {"calibration_timeout": math.inf},
    {"gantry_damping": [-1.0, 0.0]},
    {"config": {"no_such_field": 1}},
    {"config": {"calibrate": False}},
    "yes",
])
def test_bad_estimator_options_are_refused(bad):
    with pytest.raises(ValueError):
        SimToReal.from_dict({"estimator": bad})


def test_options_parse(g1):
    assert SimToReal.from_dict({}).estimator is None
    assert SimToReal.from_dict({"estimator": False}).estimator is None
    assert SimToReal.from_dict({"estimator": True}).estimator == EstimatorInLoop()
    given = SimToReal.from_dict({"estimator": {"startup_blocks": 16, "config": {"contact_on": 0.2}}}).estimator
    assert given.startup_blocks == 16 and given.estimator(g1).config.contact_on == 0.2


def test_gymnasium_checker_passes_with_the_estimator(make):
    from gymnasium.utils.env_checker import check_env

    env = make()
    check_env(env, skip_render_check=True)
