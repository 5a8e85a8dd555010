"""Tasks and the simulated runtime on the cart-pole: rates, determinism, sim-to-real knobs, robot-agnostic tasks."""

from __future__ import annotations

import time

import gymnasium
import mujoco
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.robot import MujocoRobot
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, ImuReading, Robot
from giwbc.runtimes import PushConfig, RateError, Rates, SimToReal, SimulatedRuntime
from giwbc.tasks import ActionBlock, CartPoleBalance, CartPoleSwingUp, InvalidActionError, ResidualLayout
from giwbc.testing.analytic import CartPole

BALANCE = "giwbc/CartPoleBalance-v0"


def make(env_id: str = BALANCE, **kwargs) -> SimulatedRuntime:
    """The bare runtime (no gymnasium wrappers), to reach its robot and timings."""
    return gymnasium.make(env_id, **kwargs).unwrapped


class AnalyticCartPoleRobot(Robot):
    """A cart-pole that is not MuJoCo: the hand-derived dynamics of ``giwbc.testing``, semi-implicit Euler."""

    name = "analytic-cartpole"
    joint_names = ("linear", "pivot")
    floating_base = False
    timestep = 0.001

    def __init__(self, params: CartPole = CartPole.from_urdf_parameters()) -> None:
        self.params = params
        self.reset()

    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        self.q = np.zeros(2) if q is None else np.array(q, float)
        self.v = np.zeros(2) if v is None else np.array(v, float)
        self.tau, self.t = np.zeros(2), 0.0

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.v = self.v + self.timestep * self.params.forward_dynamics(self.q, self.v, self.tau)
            self.q = self.q + self.timestep * self.v
            self.t += self.timestep

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None:
        raise NotImplementedError

    def time(self) -> float:
        return self.t

    def joint_positions(self) -> np.ndarray:
        return self.q.copy()

    def joint_velocities(self) -> np.ndarray:
        return self.v.copy()

    def joint_efforts(self) -> np.ndarray:
        return self.tau.copy()

    def base_state(self) -> BaseState:
        return BaseState(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        raise KeyError(link)

    def contact_wrench(self, link: str) -> ContactWrench:
        return ContactWrench(np.zeros(3), np.zeros(3))

    def imu(self) -> ImuReading:
        raise NotImplementedError

    def _send_joint_torques(self, torques: np.ndarray) -> None:
        self.tau = np.array(torques, float)

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        raise NotImplementedError


# --- rates ------------------------------------------------------------------------------------
def test_rates_integer_ratios() -> None:
    rates = Rates.from_timestep(0.002, agent=50.0, controller=500.0)
    assert (rates.physics, rates.physics_per_agent, rates.physics_per_controller) == (500.0, 10, 1)
    assert rates.agent_dt == pytest.approx(0.02) and rates.controller_dt == pytest.approx(0.002)
    assert Rates.from_timestep(0.001, agent=50.0).physics_per_controller == 20  # controller defaults to agent


@pytest.mark.parametrize(
    ("agent", "controller", "message"),
    [
        (30.0, None, r"physics rate 1000 Hz / agent rate 30 Hz = 33\.3333 is not an integer; nearest valid agent rates: 29\.4118 Hz \(34 physics steps\) or 30\.303 Hz \(33"),
        (40.0, 300.0, r"physics rate 1000 Hz / controller rate 300 Hz"),
        (40.0, 100.0, r"controller rate 100 Hz / agent rate 40 Hz = 2\.5 is not an integer"),
        (50.0, 2000.0, r"controller rate 2000 Hz is faster than the physics rate 1000 Hz"),
        (0.0, None, r"agent rate must be a positive finite number"),
        (float("nan"), None, r"agent rate must be a positive finite number"),
    ],
)
def test_rate_ratio_errors(agent: float, controller: float | None, message: str) -> None:
    with pytest.raises(RateError, match=message):
        Rates.from_timestep(0.001, agent=agent, controller=controller)


def test_runtime_refuses_bad_rates() -> None:
    with pytest.raises(RateError, match="agent rate 30 Hz"):
        make(agent_rate=30.0)


# --- determinism --------------------------------------------------------------------------
# Every random path on: initial state, observation noise, pushes, plus latency and delay lines.
KNOBS = {"observation_noise": 0.01, "action_latency": 3, "actuator_delay": 2,
         "pushes": {"interval": [0.05, 0.2], "duration": 0.03, "force": [1.0, 5.0], "link": "cart"}}


def rollout(env: SimulatedRuntime, seed: int, episodes: int, steps: int) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """Observations, rewards and MuJoCo qpos/qvel/time, step by step over several episodes."""
    actions = np.random.default_rng(7)
    record = []
    observation, _ = env.reset(seed=seed)
    data = env.sim_robot.data
    for _ in range(episodes):
        record.append((observation, 0.0, np.concatenate([data.qpos, data.qvel, [data.time]])))
        for _ in range(steps):
            observation, reward, terminated, _, _ = env.step(actions.uniform(-1, 1, 1).astype(np.float32))
            record.append((observation, reward, np.concatenate([data.qpos, data.qvel, data.xfrc_applied.ravel(), [data.time]])))
            if terminated:
                break
        observation, _ = env.reset()
    return record


@pytest.mark.parametrize("env_id", [BALANCE, "giwbc/CartPoleSwingUp-v0"])
def test_same_seed_is_bit_identical(env_id: str) -> None:
    first = rollout(make(env_id, sim2real=KNOBS), seed=42, episodes=5, steps=40)
    second = rollout(make(env_id, sim2real=KNOBS), seed=42, episodes=5, steps=40)
    assert len(first) == len(second) > 5 * 10
    for (obs_a, reward_a, state_a), (obs_b, reward_b, state_b) in zip(first, second):
        assert obs_a.tobytes() == obs_b.tobytes()
        assert reward_a == reward_b
        assert state_a.tobytes() == state_b.tobytes()
    other = rollout(make(env_id, sim2real=KNOBS), seed=43, episodes=1, steps=5)
    assert other[0][0].tobytes() != first[0][0].tobytes()


# --- actions ------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [[np.nan], [np.inf], [-np.inf], np.zeros(2), np.zeros((1, 1)), ["a"]])
def test_invalid_action_raises_and_loses_nothing(bad: object) -> None:
    env, reference = make(), make()
    env.reset(seed=5)
    reference.reset(seed=5)
    env.step([0.3])
    reference.step([0.3])
    before = env.sim_robot.data.qpos.copy(), env.time
    with pytest.raises(InvalidActionError):
        env.step(bad)
    assert np.array_equal(env.sim_robot.data.qpos, before[0]) and env.time == before[1]
    # The episode continues exactly as if the bad action had never been sent.
    obs, reward, *_ = env.step([-0.2])
    obs_ref, reward_ref, *_ = reference.step([-0.2])
    assert obs.tobytes() == obs_ref.tobytes() and reward == reward_ref


def test_out_of_range_action_is_clipped() -> None:
    env, reference = make(), make()
    env.reset(seed=1)
    reference.reset(seed=1)
    assert env.step([7.0])[0].tobytes() == reference.step([1.0])[0].tobytes()
    assert env.task.force == env.task.max_force


def test_residual_layout_scales_and_clips() -> None:
    layout = ResidualLayout([ActionBlock("com", 3, 0.05, ("x", "y", "z")), ActionBlock("posture", 2, (0.1, 0.2))])
    residuals = layout.split(np.array([1.0, -0.5, 0.0, 3.0, -1.0]))
    assert np.allclose(residuals["com"], [0.05, -0.025, 0.0]) and np.allclose(residuals["posture"], [0.1, -0.2])
    assert layout.entry_names()[:2] == ("com/x", "com/y") and layout.space().shape == (5,)
    with pytest.raises(ValueError, match="disagree"):
        ActionBlock("bad", 2, (1.0, 2.0, 3.0))


# --- sim-to-real knobs --------------------------------------------------------------------
def _first_step_qpos(**knobs) -> np.ndarray:
    env = make(controller_rate=50.0, sim2real=knobs, initial_spread=0.0)
    env.reset(seed=0)
    env.step([0.5])
    return env.sim_robot.data.qpos.copy()


def test_action_latency_and_actuator_delay_hold_the_old_command() -> None:
    """Latency L (or delay L) = L physics steps of the previous (zero) force, then the new one."""
    latency = 7
    robot = MujocoRobot(make().sim_robot.description)
    robot.reset(np.zeros(2), np.zeros(2))
    robot.step(latency)
    robot.set_joint_torques(np.array([0.5 * 20.0, 0.0]))
    robot.step(20 - latency)
    expected = robot.data.qpos.copy()
    assert _first_step_qpos(action_latency=latency).tobytes() == expected.tobytes()
    assert _first_step_qpos(actuator_delay=latency).tobytes() == expected.tobytes()
    assert _first_step_qpos().tobytes() != expected.tobytes()


def test_latency_longer_than_an_agent_step() -> None:
    env = make(sim2real={"action_latency": 30})
    env.reset(seed=0)
    env.step([1.0])
    assert env.task.force == 0.0  # still in flight after 20 physics steps
    env.step([0.5])
    assert env.task.force == 20.0  # the first action arrived at physics step 30, the second is in flight


class CountingMujocoRobot(MujocoRobot):
    """A MuJoCo robot that counts the physics steps it is asked to take."""

    def __init__(self, *args, **kwargs) -> None:
        self.steps_taken = 0
        super().__init__(*args, **kwargs)

    def step(self, n: int = 1) -> None:
        self.steps_taken += n
        super().step(n)


class TickRecordingBalance(CartPoleBalance):
    """Records the robot's simulated time at every controller tick."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.tick_times: list[float] = []

    def apply_command(self) -> None:
        self.tick_times.append(self.robot.time())
        super().apply_command()


@pytest.mark.parametrize("controller_rate", [50.0, 250.0, 1000.0])
def test_physics_steps_and_controller_ticks_are_the_ones_taken(controller_rate: float) -> None:
    """Counted from what happened (MuJoCo's clock, the robot's step calls, the ticks' times), not from the settings."""
    robot = CountingMujocoRobot(make().sim_robot.description)
    task = TickRecordingBalance()
    env = SimulatedRuntime(task, robot, agent_rate=50.0, controller_rate=controller_rate)
    dt = robot.model.opt.timestep
    env.reset(seed=0)
    assert robot.steps_taken == 0 and robot.data.time == 0.0
    for k in range(1, 4):
        env.step([0.0])
        assert robot.data.time == pytest.approx(k / 50.0, abs=1e-12)  # MuJoCo's own clock: k agent periods
        assert robot.steps_taken == round(k / 50.0 / dt)
        assert env.time == pytest.approx(robot.data.time, abs=1e-12)
    expected = np.arange(0.0, 3 / 50.0 - 1e-9, 1.0 / controller_rate)  # a tick at every controller period, from t = 0
    np.testing.assert_allclose(task.tick_times, expected, atol=1e-12)
    assert env.timings.physics_steps == robot.steps_taken and env.timings.agent_steps == 3


def test_controller_ticks_stay_on_their_period_when_an_action_arrives_between_them() -> None:
    """An action latency of 6 physics steps splits the chunks off the 4-step controller grid; the
    ticks must still fall every 4 steps from t = 0."""
    robot = CountingMujocoRobot(make().sim_robot.description)
    task = TickRecordingBalance()
    env = SimulatedRuntime(task, robot, agent_rate=50.0, controller_rate=250.0, sim2real={"action_latency": 6})
    env.reset(seed=0)
    for _ in range(3):
        env.step([0.0])
    np.testing.assert_allclose(task.tick_times, np.arange(15) * 0.004, atol=1e-12)
    assert robot.steps_taken == 60


def test_step_timings_add_up_per_part(monkeypatch) -> None:
    """On a fake clock that advances by one unit per reading: each controller tick and each physics
    chunk costs exactly one unit, and the totals accumulate over steps."""
    env = make(controller_rate=250.0)  # 20 physics steps per agent step, a tick every 4: 5 chunks
    env.reset(seed=0)
    env.timings.clear()
    clock = FakeClock(work=1.0)
    monkeypatch.setattr(time, "perf_counter", clock.perf_counter)
    for _ in range(3):
        env.step([0.0])
    timings = env.timings
    assert (timings.agent_steps, timings.physics_steps) == (3, 60)
    assert timings.controller == 15.0 and timings.physics == 15.0
    assert timings.total == 3 * (2 * 5 + 2 * 5 + 1)  # per step: two readings per tick and per chunk, one at the end
    assert timings.other == timings.total - 30.0
    timings.clear()
    assert (timings.total, timings.physics, timings.controller, timings.agent_steps, timings.physics_steps) == (0, 0, 0, 0, 0)


def test_step_before_reset_and_step_results_are_plain_bools() -> None:
    env = make()
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before step\(\)$"):
        env.step([0.0])
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step([0.0])
    assert terminated is False and truncated is False and type(reward) is float
    assert info["time"] == pytest.approx(0.02) and "physics_diverged" not in info


def test_a_diverged_simulation_terminates_the_episode() -> None:
    env = make()
    env.reset(seed=0)
    env.step([0.0])
    env.sim_robot.data.qvel[:] = np.nan  # MuJoCo flags the bad state and resets it
    _, _, terminated, _, info = env.step([0.0])
    assert terminated is True and info["physics_diverged"] is True
    _, _, terminated, _, info = env.step([0.0])  # it stays flagged until the next reset
    assert terminated is True and info["physics_diverged"] is True
    env.reset(seed=0)
    _, _, terminated, _, info = env.step([0.0])
    assert terminated is False and "physics_diverged" not in info


def test_human_render_mode_draws_at_every_reset_and_step(monkeypatch) -> None:
    env = make()
    frames: list[None] = []
    monkeypatch.setattr(env, "render", lambda: frames.append(None))
    env.reset(seed=0)
    env.step([0.0])
    assert frames == []  # headless: never drawn
    env.render_mode = "human"
    env.reset(seed=0)
    env.step([0.0])
    env.step([0.0])
    assert len(frames) == 3


def test_a_truncating_task_truncates_the_episode() -> None:
    class Truncating(CartPoleBalance):
        def is_truncated(self) -> bool:
            return self.robot.time() >= 0.04

    env = SimulatedRuntime(Truncating(), make().sim_robot.description, agent_rate=50.0)
    env.reset(seed=0)
    assert [env.step([0.0])[3] for _ in range(3)] == [False, True, True]


def test_runtime_options_are_kept_and_checked(monkeypatch) -> None:
    import giwbc.runtimes.simulated

    # as on a machine with a display (without one "human" is refused: tests/test_render_human.py)
    monkeypatch.setattr(giwbc.runtimes.simulated, "require_display", lambda: None)
    env = make(real_time_factor=0.5)  # slower than real time is allowed
    assert env.real_time_factor == 0.5 and env.render_mode is None
    assert env.render_size == (480, 640)
    assert make(agent_rate=25.0).metadata["render_fps"] == 25.0  # frames at the agent rate
    env.reset(seed=0)
    assert env.randomization is None  # no randomizer: nothing drawn
    human = make(render_mode="human")  # the viewer opens at the first render, not here
    assert human.render_mode == "human" and human.real_time_factor == 1.0  # paced to real time by default
    assert make(render_mode="human", real_time_factor=3.0).real_time_factor == 3.0
    assert make(render_mode="rgb_array").real_time_factor is None
    with pytest.raises(ValueError, match=r"^render_mode must be one of \('human', 'rgb_array'\) or None, got 'movie'$"):
        make(render_mode="movie")
    with pytest.raises(ValueError, match=r"^rendering needs the MuJoCo engine; this runtime runs on \['pybullet'\]$"):
        make(render_mode="rgb_array", engine="pybullet")
    assert make(engine="pybullet").metadata["render_modes"] == [] and env.metadata["render_modes"] == ["human", "rgb_array"]
    with pytest.raises(TypeError, match=r"^_NotSimulated cannot be simulated: it needs step\(\), reset\(\) and "):
        SimulatedRuntime(CartPoleBalance(), _NotSimulated(), agent_rate=50.0)


class _NotSimulated(AnalyticCartPoleRobot):
    """A robot without set_external_wrench: it cannot be pushed, so the runtime refuses it."""

    set_external_wrench = None  # type: ignore[assignment]


def test_the_task_sees_what_each_reset_drew() -> None:
    class Recording(CartPoleBalance):
        def __init__(self) -> None:
            super().__init__()
            self.drawn: list[object] = []

        def randomized(self, drawn) -> None:
            self.drawn.append(drawn)

    task = Recording()
    pushes = {"pushes": {"interval": [0.05, 0.2], "duration": 0.03, "force": [1.0, 5.0], "link": "cart"}}
    env = SimulatedRuntime(task, make().sim_robot.description, agent_rate=50.0, sim2real=pushes)
    env.reset(seed=0)
    env.reset(seed=1)
    assert len(task.drawn) == 2 and task.drawn[-1] is env.randomization and env.randomization is not None


def test_rates_edges() -> None:
    assert Rates(agent=0.5, controller=0.5, physics=1000.0).physics_per_agent == 2000  # below 1 Hz is a rate too
    assert Rates(agent=1.0, controller=1.0, physics=1000.0000001).physics_per_agent == 1000  # within 1e-9 relative
    with pytest.raises(RateError, match=r"= 1\.5 is not an integer; nearest valid agent rates: 500 Hz \(2 physics steps\) or 1000 Hz"):
        Rates(agent=1000.0 / 1.5, controller=1000.0 / 1.5, physics=1000.0)
    for bad in (0.0, -0.001, float("nan"), float("inf")):
        with pytest.raises(RateError, match=rf"^physics timestep must be positive, got {bad!r}$"):
            Rates.from_timestep(bad, agent=50.0)


def test_describe_reports_the_rates_robot_and_engine() -> None:
    description = make(controller_rate=250.0).describe()
    assert description["rates"] == {"agent_hz": 50.0, "controller_hz": 250.0, "physics_hz": 1000.0}
    assert description["robot"] == "cartpole" and description["engine"] == "mujoco"


def test_pushes_follow_their_schedule() -> None:
    pushes = PushConfig(interval=(0.1, 0.1), duration=0.05, force=(3.0, 3.0), link="cart")
    env = make(sim2real=SimToReal(pushes=pushes))
    env.reset(seed=0)
    seen = []
    for _ in range(14):  # 20 physics steps each: pushes during ticks [100, 150) and [250, 300)
        _, _, _, _, info = env.step([0.0])
        seen.append((info["pushes"], float(np.linalg.norm(info["push_force"]))))
    assert [count for count, _ in seen] == [0] * 5 + [1] * 7 + [2] * 2
    assert [round(force, 9) for _, force in seen] == [0.0] * 5 + [3.0, 3.0] + [0.0] * 5 + [3.0, 3.0]
    assert np.linalg.norm(env.sim_robot.data.xfrc_applied[:, :3], axis=1).max() == pytest.approx(3.0)


def test_observation_noise_has_the_requested_std() -> None:
    env = make(sim2real={"observation_noise": [0.0, 0.02, 0.0, 0.0, 0.05]}, max_angle=10.0, x_limit=2.3)
    env.reset(seed=0)
    errors = []
    for _ in range(300):
        observation, *_ = env.step([0.0])
        errors.append(observation - env.task.get_observation())
    std = np.std(errors, axis=0)
    assert std[[0, 2, 3]].max() == 0.0
    assert std[1] == pytest.approx(0.02, rel=0.15) and std[4] == pytest.approx(0.05, rel=0.15)
    errors = np.array(errors)
    assert abs(errors[:, 1].mean()) < 0.004 and abs(errors[:, 4].mean()) < 0.01  # zero mean (3 sigma over 300 draws)
    assert abs(np.corrcoef(errors[:, 1], errors[:, 4])[0, 1]) < 0.3  # an independent draw per component


def test_observation_noise_by_name_perturbs_only_the_named_entries() -> None:
    """``{pattern: std}`` over the task's observation names (the cart-pole's: cart_position,
    cart_velocity, pole_cos, pole_sin, pole_velocity)."""
    env = make(sim2real={"observation_noise": {"*_velocity": 0.03, "pole_velocity": 0.0}}, max_angle=10.0, x_limit=2.3)
    assert env._noise_std.tolist() == [0.0, 0.03, 0.0, 0.0, 0.0]  # the last matching pattern wins
    env.reset(seed=0)
    errors = np.array([env.step([0.0])[0] - env.task.get_observation() for _ in range(300)])
    std = np.std(errors, axis=0)
    assert std[[0, 2, 3, 4]].max() == 0.0 and std[1] == pytest.approx(0.03, rel=0.15)
    with pytest.raises(ValueError, match="matches no observation entry"):
        make(sim2real={"observation_noise": {"base_velocity/*": 0.05}})
    with pytest.raises(ValueError, match="finite stds"):
        make(sim2real={"observation_noise": {"obs/1": -0.1}})


def test_sim2real_validation() -> None:
    with pytest.raises(ValueError, match="physics steps"):
        SimToReal(action_latency=-1)
    with pytest.raises(ValueError, match="physics steps"):
        SimToReal(actuator_delay=0.5)
    with pytest.raises(ValueError, match="push interval"):
        PushConfig(interval=(0.0, 1.0))
    with pytest.raises(ValueError, match="observation_noise has 2 entries"):
        make(sim2real={"observation_noise": [0.1, 0.1]})


# --- one task, several robots ---------------------------------------------------------------
def test_task_runs_unchanged_on_different_robots() -> None:
    """The same task class on MuJoCo, on MuJoCo with a 5x heavier pole, and on a non-MuJoCo robot."""
    description = make().sim_robot.description
    heavy = description.build_mujoco()
    heavy.body_mass[mujoco.mj_name2id(heavy, mujoco.mjtObj.mjOBJ_BODY, "pole")] *= 5.0
    runtimes = {
        "mujoco": SimulatedRuntime(CartPoleSwingUp(), MujocoRobot(description), agent_rate=50.0),
        "heavy": SimulatedRuntime(CartPoleSwingUp(), MujocoRobot(description, heavy), agent_rate=50.0),
        "analytic": SimulatedRuntime(CartPoleSwingUp(), AnalyticCartPoleRobot(), agent_rate=50.0),
    }
    actions = np.random.default_rng(3).uniform(-1, 1, (25, 1))
    observations = {}
    for name, env in runtimes.items():
        env.reset(seed=11)
        observations[name] = np.array([env.step(action)[0] for action in actions])
    # The hand-derived dynamics and MuJoCo agree; the heavy pole does not.
    assert np.abs(observations["mujoco"] - observations["analytic"]).max() < 1e-5
    assert np.abs(observations["mujoco"] - observations["heavy"]).max() > 1e-2
    # And through gymnasium.make: a modified MjModel, copied so the env owns its model.
    env = make(model=heavy)
    assert env.sim_robot.model is not heavy
    assert env.sim_robot.model.body_mass.tobytes() == heavy.body_mass.tobytes()


def test_task_names_missing_joints() -> None:
    class Renamed(AnalyticCartPoleRobot):
        joint_names = ("slider", "hinge")

    with pytest.raises(ValueError, match="has no joint 'linear'"):
        SimulatedRuntime(CartPoleBalance(), Renamed(), agent_rate=50.0)
    SimulatedRuntime(CartPoleBalance(cart_joint="slider", pole_joint="hinge"), Renamed(), agent_rate=50.0)


# --- tasks ------------------------------------------------------------------------------------
def test_balance_and_swing_up_differ_on_the_same_robot() -> None:
    balance, swing_up = make(), make("giwbc/CartPoleSwingUp-v0")
    upright, _ = balance.reset(seed=0)
    hanging, _ = swing_up.reset(seed=0)
    assert upright[2] > 0.99 and hanging[2] < -0.99  # cos θ: upright vs hanging down
    assert balance.step([0.0])[1] == 1.0
    assert 0.0 <= swing_up.step([0.0])[1] < 0.05
    # Balance ends when the pole falls; swing-up keeps going.
    terminated = False
    for _ in range(100):
        terminated = balance.step([1.0])[2]
        if terminated:
            break
    assert terminated and abs(balance.task.state()[2]) > 0.2
    assert balance.describe()["action_scale"] == [20.0]
    assert balance.describe()["observation_names"][2] == "pole_cos"


class FakeClock:
    """A wall clock that only moves when slept on (or by ``work`` per reading): pacing tested in counts."""

    def __init__(self, work: float = 0.0) -> None:
        self.now, self.work, self.sleeps = 100.0, work, []

    def perf_counter(self) -> float:
        self.now += self.work
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


@pytest.mark.parametrize("work", [0.0, 1e-4])
def test_real_time_factor_paces_the_simulation(monkeypatch, work: float) -> None:
    """At twice real time, 0.16 s simulated take 0.08 s of wall time: the runtime sleeps what the work
    did not use, after every step, so wall time never runs behind (and never ahead of) the pace."""
    env = make(real_time_factor=2.0)
    clock = FakeClock(work)
    monkeypatch.setattr(time, "perf_counter", clock.perf_counter)
    monkeypatch.setattr(time, "sleep", clock.sleep)
    env.reset(seed=0)
    started = clock.now
    for k in range(1, 9):  # 0.02 s simulated each
        env.step([0.0])
        assert clock.now - started == pytest.approx(0.01 * k, abs=work * 50 + 1e-12)
    assert len(clock.sleeps) == 8 and all(s > 0 for s in clock.sleeps)
    assert sum(clock.sleeps) < 0.08 if work else sum(clock.sleeps) == pytest.approx(0.08)
    with pytest.raises(ValueError, match="real_time_factor"):
        make(real_time_factor=0.0)
