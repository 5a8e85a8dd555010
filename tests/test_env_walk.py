"""G1Walk: velocity commands over the model-based walker, residual steps, determinism, checkers."""

from __future__ import annotations

import copy
import math
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from giwbc.envs.factories import g1_walk
from giwbc.locomotion.footsteps import rotation2
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.robot.mujoco_robot import MujocoRobot
from giwbc.tasks.walk import CommandRanges

FORWARD = {"vx": [0.3, 0.3], "vy": [0.0, 0.0], "yaw_rate": [0.0, 0.0], "standing": 0.0, "interval": [100.0, 100.0]}
NO_PUSHES = {"pushes": None}


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_mujoco()


@pytest.fixture
def make(g1, g1_model):
    def factory(**kwargs):
        kwargs.setdefault("sim2real", NO_PUSHES)
        return g1_walk(robot=g1, model=g1_model, **kwargs)

    return factory


def rollout(env, seed: int, steps: int, actions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Observations and rewards of ``steps`` agent steps from ``reset(seed)``."""
    observation, _ = env.reset(seed=seed)
    observations, rewards = [observation], []
    for i in range(steps):
        action = np.zeros(env.action_space.shape, np.float32) if actions is None else actions[i]
        observation, reward, terminated, truncated, _ = env.step(action)
        observations.append(observation)
        rewards.append(reward)
        if terminated or truncated:
            break
    return np.array(observations), np.array(rewards)


def test_passes_gymnasium_and_sb3_checkers(make) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make(residuals=["step", "com", "orientation"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, skip_render_check=True)
    sb3_check_env(env, warn=True)
    assert env.action_space.shape == (9,)
    assert len(env.task.observation_names()) == env.observation_space.shape[0]
    env.close()


def test_commands_are_seeded_and_include_standing() -> None:
    ranges = CommandRanges(standing=0.3, interval=(1.0, 2.0), horizon=100.0)
    a = ranges.draw(np.random.default_rng(3))
    b = ranges.draw(np.random.default_rng(3))
    assert a == b
    commands = np.array([c for _, c in a])
    assert np.any(np.all(commands == 0.0, axis=1)) and np.any(commands[:, 0] > 0.1)
    assert np.all((commands[:, 0] >= -0.1) & (commands[:, 0] <= 0.4))
    gaps = np.diff([t for t, _ in a])
    assert gaps.min() >= 1.0 and gaps.max() <= 2.0
    with pytest.raises(ValueError):
        CommandRanges(vx=(0.5, 0.1))


def test_zero_residual_is_the_walker_alone_bit_for_bit(make, g1, g1_model) -> None:
    """Every block in the action, all zero: the same robot states as the walker run by itself."""
    commands = {**FORWARD, "interval": [1.0, 1.0], "vy": [-0.1, 0.1], "yaw_rate": [-0.3, 0.3]}
    env = make(residuals=["step", "com", "orientation"], commands=commands)
    env.reset(seed=5)
    task = env.task
    q0, v0 = env.sim_robot.generalized_state()
    schedule = list(task.schedule)
    assert len({c for _, c in schedule[:3]}) == 3  # the command changes twice in the run
    robot = MujocoRobot(g1, copy.copy(g1_model))
    robot.reset(q0, v0)
    walker = WalkingController(g1)
    walker.reset(robot.generalized_state()[0])
    zero = np.zeros(9, np.float32)
    following = 0
    for _ in range(125):  # 2.5 s
        env.step(zero)
        for _ in range(10):
            while following < len(schedule) and schedule[following][0] <= robot.time() + 1e-9:
                walker.set_command(*schedule[following][1])
                following += 1
            walker.step(robot)
            robot.step()
        q_env, v_env = env.sim_robot.generalized_state()
        q, v = robot.generalized_state()
        assert np.array_equal(q_env, q) and np.array_equal(v_env, v)
    assert walker.state.steps >= 3 and task.walker.state.steps == walker.state.steps
    env.close()


def test_same_seed_is_bit_identical_and_a_used_env_equals_a_fresh_one(make) -> None:
    kwargs = {"residuals": ["step", "com"], "sim2real": {"pushes": {"interval": [0.5, 0.8], "duration": 0.1, "force": [40.0, 80.0]},
                                                         "observation_noise": 0.01}}
    actions = np.random.default_rng(0).uniform(-1, 1, (60, 6)).astype(np.float32)
    used = make(**kwargs)
    rollout(used, 11, 40, actions)  # another episode first
    a = rollout(used, 7, 60, actions)
    fresh = make(**kwargs)
    b = rollout(fresh, 7, 60, actions)
    c = rollout(fresh, 7, 60, actions)
    for x, y in ((a, b), (b, c)):
        assert np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
    d = rollout(fresh, 8, 60, actions)
    assert not np.array_equal(a[0][: len(d[0])], d[0][: len(a[0])])
    used.close()
    fresh.close()


def test_step_residual_moves_the_landing_foot_within_the_box(make) -> None:
    env = make(residuals=["step"], commands={**FORWARD, "vx": [0.2, 0.2]})
    env.reset(seed=1)
    walker = env.task.walker
    action = np.array([0.5, -0.4, 0.0], np.float32)  # 5 cm forward, 3.2 cm right, nominal timing
    offset = np.array([0.05, -0.032])
    landings, checked, steps = [], 0, 0
    target = None
    took_over = 0  # recovery steps and early touch-downs so far: the walker's balance, not the residual, placed those
    for _ in range(150):
        _, _, terminated, _, _ = env.step(action)
        assert not terminated
        state = walker.state
        if walker.state.steps != steps:  # a foot landed during this agent step: where it was sent?
            steps = walker.state.steps
            landed = walker.feet[state.stance]
            if target is not None and state.recovery_steps + state.early_touchdowns == took_over:
                landings.append(np.linalg.norm(landed.position - target))
            took_over = state.recovery_steps + state.early_touchdowns
        if walker.phase is Phase.SINGLE:
            stance = walker.feet[walker.state.stance]
            shift = rotation2(stance.yaw).T @ (state.target - state.planned_target)
            local = stance.to_local(state.target)
            (x_lo, x_hi), (y_lo, y_hi) = walker._landing_box(walker.next_footstep().side)
            edge = 1e-6  # a target on the box's edge (to rounding) was clipped there: not a free landing
            if x_lo + edge < local[0] < x_hi - edge and y_lo + edge < local[1] < y_hi - edge:
                np.testing.assert_allclose(shift, offset, atol=1e-9)
                checked += 1
            target = state.target.copy()
    assert checked > 20 and len(landings) >= 4
    assert max(landings) < 0.03, landings  # the foot lands where the residual sent it


def test_step_residual_is_bounded_by_the_landing_box_and_swing_times(make) -> None:
    env = make(residuals=["step"], commands={**FORWARD, "vx": [0.2, 0.2]})
    env.reset(seed=2)
    walker = env.task.walker
    config = walker.config
    durations, start = [], None
    for i in range(100):
        action = np.array([1.0, 1.0, 1.0] if i % 2 else [-1.0, -1.0, -1.0], np.float32)  # extreme, changing
        _, _, terminated, _, _ = env.step(action)
        if walker.phase is Phase.SINGLE:
            stance = walker.feet[walker.state.stance]
            local = stance.to_local(walker.state.target)
            (x_lo, x_hi), (y_lo, y_hi) = walker._landing_box(walker.next_footstep().side)
            assert x_lo - 1e-9 <= local[0] <= x_hi + 1e-9 and y_lo - 1e-9 <= local[1] <= y_hi + 1e-9
            assert config.min_swing - 1e-9 <= walker._phase_end - walker._phase_start <= config.max_swing + 1e-9
        if terminated:
            break
    with pytest.raises(ValueError):
        walker.set_step_residual(np.array([math.nan, 0.0]))


def test_duration_residual_lengthens_single_support(make) -> None:
    def single_support_ticks(action: float) -> float:
        env = make(residuals=["step"], commands={**FORWARD, "vx": [0.1, 0.1]})
        env.reset(seed=3)
        phases = []
        for _ in range(150):
            _, _, terminated, _, _ = env.step(np.array([0.0, 0.0, action], np.float32))
            assert not terminated
            phases.append(env.task.walker.phase is Phase.SINGLE)
        steps = env.task.walker.state.steps
        env.close()
        return sum(phases) / max(steps, 1)

    slow, fast = single_support_ticks(1.0), single_support_ticks(-1.0)
    assert slow > fast + 2  # agent steps of single support per step


def test_com_and_orientation_residuals_move_the_references_standing(make) -> None:
    """Standing (zero command): a full com x residual shifts the CoM forward by its scale (3 cm), a
    full pitch residual pitches the pelvis by its scale (0.1 rad), the CoM staying."""
    standing = {**FORWARD, "standing": 1.0}

    def hold(action: list[float]) -> tuple[np.ndarray, float]:
        env = make(residuals=["com", "orientation"], commands=standing)
        env.reset(seed=0)
        walker = env.task.walker
        for _ in range(20):  # settled over the middle of the feet's contact frames (0.4 s)
            env.step(np.zeros(6, np.float32))
        start = walker.state.com.copy()
        for _ in range(75):
            _, _, terminated, _, _ = env.step(np.array(action, np.float32))
            assert not terminated
        assert walker.phase is Phase.STAND and walker.state.steps == 0
        x, y, z, w = env.sim_robot.base_state().quaternion
        env.close()
        return walker.state.com - start, math.asin(2.0 * (w * y - z * x))

    moved, pitch = hold([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert moved[0] == pytest.approx(0.03, abs=0.006) and abs(moved[1]) < 0.006 and abs(pitch) < 0.03
    moved, pitch = hold([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    assert pitch == pytest.approx(0.1, abs=0.03) and np.all(np.abs(moved[:2]) < 0.015)


@pytest.mark.slow
def test_a_used_env_equals_a_fresh_one_after_falls_under_training_pushes(make) -> None:
    """The hard case of the test above (~15 s): the training run's 100–180 N pushes, episodes that
    end in falls first, then an episode whose fall sends the WBC's QPs through proxsuite where the
    polish fails (its answer then follows proxsuite's bits: they must not depend on the process's
    history, :mod:`giwbc.control.qp.proxsuite_build`). A resumed training run relies on this."""
    kwargs = {"residuals": ["step"], "sim2real": {"pushes": {"interval": [1.5, 3.0], "duration": 0.2, "force": [100.0, 180.0]}}}
    actions = np.random.default_rng(1).uniform(-1, 1, (400, 3)).astype(np.float32)
    used = make(**kwargs)
    rollout(used, 5, 400, actions)
    rollout(used, 6, 400, actions)
    guess = used.unwrapped.task.walker.balance.wbc.solver._kkt
    before = guess.polish_failures
    a = rollout(used, 7, 400, actions)
    assert guess.polish_failures > before  # the history-sensitive path was taken
    fresh = make(**kwargs)
    b = rollout(fresh, 7, 400, actions)
    assert len(a[1]) < 400  # it fell
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    used.close()
    fresh.close()


def test_an_episode_ends_where_the_deployment_safety_would_stop_the_robot(make) -> None:
    """``joint_limit_margin``: terminated (with the fall penalty) at the first agent step that ends
    with a joint beyond its limits moved inward by the margin, as ``giwbc.hal.safety`` stops a
    deployed robot; without it the same walk goes on."""
    margin = 0.2  # wide, so that walking at 0.3 m/s reaches it (the ankle rolls ~0.1 rad)
    zero = np.zeros(3, np.float32)
    env = make(residuals=["step"], commands={**FORWARD, "vx": [0.3, 0.3]}, joint_limit_margin=margin)
    env.reset(seed=1)
    lower, upper = env.task.description.position_limits
    for step in range(150):
        _, reward, terminated, _, _ = env.step(zero)
        q = env.task.robot.joint_positions()
        assert terminated == bool(np.any(q < lower + margin) or np.any(q > upper - margin))
        if terminated:
            break
    assert terminated and step > 10 and reward < -10.0  # walked first; ended as a fall
    assert env.task.base_state().position[2] > env.task.min_height and env.task.tilt() < 0.3  # upright: the limit ended it
    free = make(residuals=["step"], commands={**FORWARD, "vx": [0.3, 0.3]})
    free.reset(seed=1)
    assert not any(free.step(zero)[2] for _ in range(step + 1))
    with pytest.raises(ValueError, match="joint_limit_margin"):
        make(joint_limit_margin=-0.1)


def test_the_joint_limit_reward_costs_each_radian_beyond_the_band(make):
    """``rewards={"joint_limits": w}``: w per rad a joint is beyond ``joint_limit_band`` of its half
    range from the middle (legged_gym's dof_pos_limits), nothing inside it."""
    plain, shaped = make(commands=FORWARD), make(commands=FORWARD, rewards={"joint_limits": 10.0, "joint_limit_band": 0.8})
    rewards = []
    for env in (plain, shaped):
        env.reset(seed=0)
        task = env.task
        q, v = env.sim_robot.generalized_state()
        j = task.description.joint_names.index("left_ankle_roll_joint")
        lower, upper = task.description.position_limits
        q[7 + j] = upper[j] - 0.01  # beyond the band, inside the limit
        env.sim_robot.reset(q, v)
        task._base = task._observed = None
        rewards.append(task.get_reward())
        excess = q[7 + j] - 0.8 * upper[j]  # the ankle roll's limits are symmetric
    assert excess > 0.02
    assert rewards[0] - rewards[1] == pytest.approx(10.0 * excess, rel=1e-9)
    with pytest.raises(ValueError, match="joint_limit_band"):
        make(rewards={"joint_limit_band": 0.0})


def test_the_action_reward_costs_the_residual_itself(make):
    """``rewards={"action": w}``: w times the mean squared action (the residual; zero is the walker
    alone) on top of the action-rate term; nothing for the zero action."""
    plain, shaped = make(commands=FORWARD), make(commands=FORWARD, rewards={"action": 2.0})
    action = np.linspace(-0.8, 0.6, plain.action_space.shape[0]).astype(np.float32)
    ends = []
    for env in (plain, shaped):
        env.reset(seed=0)
        zero = env.step(np.zeros_like(action))[1]
        ends.append((zero, env.step(action)[1]))
    assert ends[0][0] == ends[1][0]  # the zero residual costs nothing
    a = action.astype(float)
    assert ends[0][1] - ends[1][1] == pytest.approx(2.0 * float(a @ a) / a.size, rel=1e-9)
    assert ends[0][1] - ends[1][1] > 0.5
    with pytest.raises(ValueError, match="action"):
        make(rewards={"action": -1.0})


def test_the_residual_gate_leaves_undisturbed_walking_to_the_walker(make):
    """``residual_gate=(start, full)``: the residual acts in proportion to the walker's DCM error
    beyond ``start`` (all of it from ``full``): undisturbed walking (DCM error under 2 cm here) is the
    walker alone whatever the policy outputs; an always-open gate lets the same actions act."""
    actions = np.random.default_rng(3).uniform(-1.0, 1.0, (60, 3)).astype(np.float32)
    gated = make(residuals=["step"], commands=FORWARD, residual_gate=[0.03, 0.08])
    observations, gates = [], []
    observation, _ = gated.reset(seed=0)
    for action in actions:
        gates.append(gated.task.gate())
        observation, *_ = gated.step(action)
        observations.append(observation)
    assert max(gates) == 0.0 and gated.task.last_action.any()
    walker_alone, _ = rollout(make(residuals=["step"], commands=FORWARD), 0, 60)
    np.testing.assert_array_equal(np.array(observations)[:, :-3], walker_alone[1:, :-3])  # all but the action echo
    open_gate, _ = rollout(make(residuals=["step"], commands=FORWARD, residual_gate=[0.0, 1e-6]), 0, 60, actions)
    assert np.abs(open_gate[1:, :-3] - walker_alone[1:, :-3]).max() > 0.1
    task = gated.task
    task.walker.state.dcm = task.walker.state.dcm_ref + np.array([0.033, 0.044])  # |error| 0.055 m: half way
    assert task.gate() == pytest.approx(0.5)
    task.walker.state.dcm = task.walker.state.dcm_ref + np.array([0.3, 0.0])
    assert task.gate() == 1.0
    for bad in ([0.05, 0.05], [-0.01, 0.05], [0.03], [0.0, math.inf]):
        with pytest.raises(ValueError, match="residual_gate"):
            make(residual_gate=bad)
