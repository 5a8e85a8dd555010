"""G1Balance: residual actions over the WBC (and the joint-PD baseline), pushes, rewards, determinism."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest

from giwbc.envs.factories import g1_balance
from giwbc.runtimes import PushConfig, SimToReal
from giwbc.tasks import InvalidActionError
from giwbc.tasks.balance import BalanceRewards

NO_PUSHES = SimToReal()


@pytest.fixture(scope="module")
def g1_model(g1):
    """The G1 MuJoCo model, built once; every env copies it."""
    return g1.build_mujoco()


@pytest.fixture
def make(g1, g1_model):
    def factory(**kwargs):
        kwargs.setdefault("sim2real", NO_PUSHES)
        return g1_balance(robot=g1, model=g1_model, **kwargs)

    return factory


def hold(env, action, steps: int):
    for _ in range(steps):
        observation, reward, terminated, truncated, info = env.step(action)
        assert not terminated, info
    return observation, reward, info


def test_wbc_stands_with_zero_residual(make) -> None:
    env = make()
    env.reset(seed=0)
    assert env.action_space.shape == (35,) and env.observation_space.shape == (99,)
    assert env.rates.physics_per_controller == 1 and env.rates.physics_per_agent == 10
    observation, reward, info = hold(env, np.zeros(35, np.float32), 75)  # 1.5 s, 750 WBC ticks
    assert env.task.controller.result.status.value == "ok"
    assert info["tilt"] < 0.02 and abs(info["base_height"] - env.task.nominal_height) < 0.02
    assert np.allclose(observation[:3], [0, 0, -1], atol=0.02)  # gravity seen by the IMU
    assert reward > 2.0  # alive + nearly all of upright, CoM and posture


def test_com_residual_moves_the_com(make) -> None:
    env = make()
    env.reset(seed=0)
    action = np.zeros(35, np.float32)
    action[0] = 1.0  # +x, a full residual = scales.com = 3 cm
    hold(env, action, 75)
    assert env.task.com_error()[0] == pytest.approx(env.task.scales.com, abs=0.01)
    assert abs(env.task.com_error()[1]) < 0.01


def test_pd_posture_residual_moves_the_joint(make, g1) -> None:
    env = make(controller="pd", controller_rate=50.0)
    env.reset(seed=0)
    assert env.action_space.shape == (29,)
    knee = g1.joint_names.index("left_knee_joint")
    action = np.zeros(29, np.float32)
    action[knee] = 1.0
    start = env.sim_robot.joint_positions()[knee]
    hold(env, action, 25)
    assert env.sim_robot.joint_positions()[knee] - start > 0.05


def test_pushes_act_on_the_pelvis(make) -> None:
    pushes = PushConfig(interval=(0.1, 0.1), duration=0.06, force=(60.0, 60.0))
    env, calm = make(sim2real=SimToReal(pushes=pushes)), make()
    env.reset(seed=2)
    calm.reset(seed=2)
    zero = np.zeros(35, np.float32)
    for _ in range(6):  # 0.12 s: the push started at 0.1 s
        _, _, _, _, info = env.step(zero)
        calm.step(zero)
    pelvis = mujoco.mj_name2id(env.sim_robot.model, mujoco.mjtObj.mjOBJ_BODY, "pelvis")
    assert info["pushes"] == 1
    assert np.linalg.norm(env.sim_robot.data.xfrc_applied[pelvis, :3]) == pytest.approx(60.0)
    assert np.linalg.norm(info["push_force"]) == pytest.approx(60.0)
    pushed = env.sim_robot.base_state().linear_velocity[:2]
    assert np.linalg.norm(pushed - calm.sim_robot.base_state().linear_velocity[:2]) > 0.02


def test_effort_and_action_rate_penalties(make) -> None:
    effort_only = make(controller="pd", controller_rate=50.0, rewards=BalanceRewards(alive=0, upright=0, com=0, posture=0, effort=1, action_rate=0))
    effort_only.reset(seed=0)
    _, reward, *_ = effort_only.step(np.zeros(29, np.float32))
    task = effort_only.task
    scaled = effort_only.sim_robot.joint_efforts() / task.effort_limits
    assert reward == pytest.approx(-np.mean(scaled**2)) and reward < 0

    rate_only = make(controller="pd", controller_rate=50.0, rewards=BalanceRewards(alive=0, upright=0, com=0, posture=0, effort=0, action_rate=1))
    rate_only.reset(seed=0)
    first, second = np.full(29, 0.2, np.float32), np.full(29, -0.3, np.float32)
    assert rate_only.step(first)[1] == pytest.approx(-0.04)  # from the zero action of the reset
    assert rate_only.step(second)[1] == pytest.approx(-0.25)
    assert rate_only.step(second)[1] == 0.0


@pytest.mark.parametrize("solver", ["proxsuite", "osqp"])
def test_same_seed_is_bit_identical_with_wbc_and_pushes(make, solver) -> None:
    """Runtime, task and WBC are deterministic with either solver (the WBC's answers come from
    its own LAPACK KKT solve, whatever the backend's last bits)."""
    knobs = SimToReal(observation_noise=0.01, action_latency=1, pushes=PushConfig(interval=(0.05, 0.1), duration=0.04, force=(30.0, 60.0)))

    def rollout():
        env, actions, record = make(sim2real=knobs, wbc_options={"solver": solver}), np.random.default_rng(1), []
        env.reset(seed=42)
        for _ in range(2):
            for _ in range(12):
                observation, reward, *_ = env.step(actions.uniform(-1, 1, 35).astype(np.float32))
                record.append(observation.tobytes() + np.float64(reward).tobytes() + env.sim_robot.data.qpos.tobytes())
            env.reset()
        return record

    assert rollout() == rollout()


def test_invalid_action_and_metadata(make, g1) -> None:
    env = make()
    env.reset(seed=0)
    action = np.zeros(35, np.float32)
    action[7] = np.nan
    with pytest.raises(InvalidActionError, match=r"indices \[7\]"):
        env.step(action)
    described = env.describe()
    assert described["joint_names"] == list(g1.joint_names)
    assert described["action_names"][:4] == ["com/x", "com/y", "com/z", "orientation/roll"]
    assert described["action_names"][6] == "posture/left_hip_pitch_joint"
    assert described["action_scale"][:6] == [0.03] * 3 + [0.1] * 3
    assert described["kp"] == g1.kp.tolist() and described["rates"]["controller_hz"] == 500.0
    assert len(described["observation_names"]) == 99


def test_task_runs_on_a_heavier_robot(g1, g1_model) -> None:
    """The same task on a G1 with 5 kg more in the pelvis: it still stands, and not identically."""
    heavy = copy.copy(g1_model)
    heavy.body_mass[mujoco.mj_name2id(heavy, mujoco.mjtObj.mjOBJ_BODY, "pelvis")] += 5.0
    heights = []
    for model in (g1_model, heavy):
        env = g1_balance(robot=g1, model=model, sim2real=NO_PUSHES)
        env.reset(seed=0)
        _, _, info = hold(env, np.zeros(35, np.float32), 25)
        heights.append(info["base_height"])
    assert heights[0] != heights[1] and min(heights) > 0.7


def test_reset_forgets_the_previous_episode(make) -> None:
    """After reset(seed), an env that already ran an episode matches a fresh one exactly (no WBC state leaks)."""
    fresh, used = make(), make()
    actions = np.random.default_rng(0).uniform(-1, 1, (6, 35)).astype(np.float32)
    used.reset(seed=5)
    for action in actions[:5]:
        used.step(action)
    results = []
    for env in (fresh, used):
        env.reset(seed=123)
        observation, reward, *_ = env.step(actions[5])
        results.append((observation.tobytes(), reward, env.sim_robot.data.qpos.tobytes()))
    assert results[0] == results[1]


def test_a_subset_of_residual_blocks(make) -> None:
    """``residuals=("com", "orientation")``: 6 actions, the posture reference stays the default pose."""
    env = make(residuals=["orientation", "com"])  # order given: the layout keeps com, orientation
    env.reset(seed=0)
    assert env.action_space.shape == (6,) and env.observation_space.shape == (3 + 3 + 2 * 29 + 6,)
    assert env.describe()["action_names"] == ["com/x", "com/y", "com/z", "orientation/roll", "orientation/pitch", "orientation/yaw"]
    action = np.zeros(6, np.float32)
    action[1] = -1.0  # -y, a full CoM residual
    hold(env, action, 75)
    task = env.task
    assert task.com_error()[1] == pytest.approx(-task.scales.com, abs=0.01)
    assert np.array_equal(task.controller.posture_reference(), task.default_positions)
    with pytest.raises(ValueError, match="residuals must be distinct names among"):
        make(residuals=["com", "gains"])
    with pytest.raises(ValueError, match="residuals must be distinct names among"):
        make(controller="pd", controller_rate=50.0, residuals=["com"])


def test_the_fall_penalty_is_paid_once_at_termination(make) -> None:
    """Only the fall term is weighted: zero on every step, ``-fall`` on the terminating one."""
    shove = SimToReal(pushes=PushConfig(interval=(0.2, 0.2), duration=0.5, force=(300.0, 300.0)))
    weights = BalanceRewards(alive=0, upright=0, com=0, posture=0, effort=0, action_rate=0, fall=7.0)
    env = make(controller="pd", controller_rate=50.0, sim2real=shove, rewards=weights)
    env.reset(seed=0)
    action = np.zeros(29, np.float32)
    rewards = []
    for _ in range(200):
        _, reward, terminated, _, _ = env.step(action)
        rewards.append(reward)
        if terminated:
            break
    assert terminated and len(rewards) > 10 and rewards[-1] == -7.0 and all(r == 0.0 for r in rewards[:-1])
