"""The second engine: registered tasks on PyBullet, the WBC standing there, engine choice per episode."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.envs import CARTPOLE_BALANCE, CARTPOLE_SWING_UP, G1_BALANCE
from giwbc.randomization import EngineChoice, RandomizationError
from giwbc.runtimes import SimulatedRuntime
from giwbc.tasks import CartPoleSwingUp

pytest.importorskip("pybullet")
from giwbc.robot.pybullet_robot import PybulletRobot  # noqa: E402

COIN = {"mujoco": 0.5, "pybullet": 0.5}


@pytest.mark.parametrize("env_id", [CARTPOLE_BALANCE, CARTPOLE_SWING_UP])
def test_cartpole_ids_pass_check_env_on_pybullet(env_id: str) -> None:
    env = gymnasium.make(env_id, engine="pybullet")
    assert isinstance(env.unwrapped.engine_robot, PybulletRobot) and env.unwrapped.describe()["engine"] == "pybullet"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_cartpole_ids_pass_check_env_with_a_random_engine_and_randomization() -> None:
    randomization = {"parameters": [{"parameter": "link_mass", "distribution": "uniform", "low": 0.8, "high": 1.2,
                                     "operation": "scale", "links": ["pole"]}]}
    env = gymnasium.make(CARTPOLE_BALANCE, engine=COIN, randomization=randomization)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)  # raises on any API violation
    engines = set()
    for seed in range(12):
        env.reset(seed=seed)
        engines.add(env.unwrapped.engine)
        assert env.unwrapped.randomization is not None  # a draw at every reset
    assert engines == {"mujoco", "pybullet"}  # the coin picked both
    env.close()


def test_a_task_runs_unchanged_on_either_engine(cartpole) -> None:
    """The same task class, actions and seed: both engines give nearly the same swing-up."""
    actions = np.random.default_rng(3).uniform(-1, 1, (25, 1))
    observations = {}
    for engine in ("mujoco", "pybullet"):
        env = SimulatedRuntime(CartPoleSwingUp(), cartpole, agent_rate=50.0, engine=engine)
        env.reset(seed=11)
        observations[engine] = np.array([env.step(action)[0] for action in actions])
        env.close()
    assert np.abs(observations["mujoco"] - observations["pybullet"]).max() < 0.02


def test_wbc_keeps_g1_standing_on_pybullet(g1) -> None:
    """G1Balance-v0 on PyBullet: 5 s under the zero residual, the WBC's QP solving every 2 ms tick."""
    env = gymnasium.make(G1_BALANCE, engine="pybullet", sim2real={"pushes": None}).unwrapped
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation) and env.describe()["engine"] == "pybullet"
    zero = np.zeros(env.action_space.shape, np.float32)
    for _ in range(250):
        observation, reward, terminated, truncated, info = env.step(zero)
        assert not terminated, info
    assert env.time == pytest.approx(5.0)
    assert env.task.controller.result.status.value == "ok"
    assert info["tilt"] < 0.05 and abs(info["base_height"] - env.task.nominal_height) < 0.03
    assert np.allclose(observation[:3], [0, 0, -1], atol=0.05) and reward > 2.0
    client = env.engine_robot.client
    env.close()
    assert not client.connected  # the runtime built it, so env.close() disconnected it
    env.close()  # closing twice is allowed


def test_engine_choice_is_drawn_per_episode_and_reproducible() -> None:
    def engines(seed: int) -> tuple[list[str], list[bytes]]:
        env = gymnasium.make(CARTPOLE_BALANCE, engine=EngineChoice(COIN)).unwrapped
        assert set(env.engines._engines) == {"mujoco"}  # built lazily: PyBullet only once drawn
        drawn, observations = [], []
        env.reset(seed=seed)
        for _ in range(12):
            observation, _ = env.reset()
            drawn.append(env.engine)
            observations.append(observation.tobytes() + env.step([0.3])[0].tobytes())
            assert type(env.engine_robot).__name__ == {"mujoco": "MujocoRobot", "pybullet": "PybulletRobot"}[env.engine]
        env.close()
        return drawn, observations

    first, second, other = engines(1), engines(1), engines(2)
    assert first == second
    assert set(first[0]) == {"mujoco", "pybullet"}
    assert first[0] != other[0]


def test_engine_options_and_errors(cartpole) -> None:
    with pytest.raises(RandomizationError, match="engine must be one of"):
        gymnasium.make(CARTPOLE_BALANCE, engine="gazebo")
    with pytest.raises(RandomizationError, match="sum to 1"):
        gymnasium.make(CARTPOLE_BALANCE, engine={"mujoco": 0.5, "pybullet": 0.6})
    with pytest.raises(RandomizationError, match="engine_options: unknown engines"):
        gymnasium.make(CARTPOLE_BALANCE, engine_options={"bullet": {}})
    with pytest.raises(ValueError, match="rendering needs the MuJoCo engine"):
        gymnasium.make(CARTPOLE_BALANCE, engine="pybullet", render_mode="rgb_array")
    with PybulletRobot(cartpole) as robot:
        with pytest.raises(RandomizationError, match="runs on its engine"):
            SimulatedRuntime(CartPoleSwingUp(), robot, agent_rate=50.0, engine="mujoco")
        env = SimulatedRuntime(CartPoleSwingUp(), robot, agent_rate=50.0)
        assert env.engine == "pybullet"
        env.close()
        assert robot.client.connected  # a robot the caller gave stays the caller's
    env = gymnasium.make(CARTPOLE_BALANCE, engine="pybullet", engine_options={"pybullet": {"solver_iterations": 7}}).unwrapped
    assert env.engine_robot.client.getPhysicsEngineParameters()["numSolverIterations"] == 7
    env.close()


def test_a_given_perturbed_robot_is_not_wrapped_twice(cartpole) -> None:
    from giwbc.randomization import PerturbedRobot

    robot = PerturbedRobot(PybulletRobot(cartpole))
    latency = {"parameters": [{"parameter": "actuator_latency", "distribution": "uniform", "low": 2.0, "high": 2.0, "operation": "absolute"}]}
    env = SimulatedRuntime(CartPoleSwingUp(), robot, agent_rate=50.0, randomizer=latency)
    assert env.engine == "pybullet" and env.sim_robot is robot and env.engine_robot is robot.robot
    env.reset(seed=0)
    assert robot.latency == 2
    robot.robot.close()
