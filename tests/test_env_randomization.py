"""Domain randomization through the environments: config forms and errors, same seed same parameters
and rollouts, the model visibly changed while the WBC keeps its nominal model, one place per effect."""

from __future__ import annotations

import gymnasium
import mujoco
import numpy as np
import pinocchio as pin
import pytest

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.envs import CARTPOLE_BALANCE, G1_BALANCE
from giwbc.randomization import DomainRandomizer, PerturbedRobot, RandomizationConfig, RandomizationError, default_config_path
from giwbc.robot import RobotDescription

POLE_MASS = {"parameter": "link_mass", "distribution": "uniform", "low": 0.5, "high": 1.5, "operation": "scale", "links": ["pole"]}


@pytest.fixture(scope="module")
def g1_model(g1: RobotDescription) -> mujoco.MjModel:
    return g1.build_mujoco()


def make_g1(g1_model: mujoco.MjModel, **kwargs) -> gymnasium.Env:
    """G1Balance with the prebuilt model and OSQP in the WBC (bitwise reproducible; see test_env_g1)."""
    return gymnasium.make(G1_BALANCE, model=g1_model, wbc_options={"solver": "osqp"}, **kwargs).unwrapped


# --- configs ---------------------------------------------------------------------------------------
def test_shipped_g1_config_is_valid_and_realistic(g1: RobotDescription) -> None:
    config = RandomizationConfig.from_toml(default_config_path(g1), g1)
    assert {"link_mass", "link_com", "ground_friction", "actuator_strength", "actuator_latency", "imu_latency"} <= config.parameters
    assert not config.parameters & {"push_force", "push_interval"}  # pushes come from the environment's setting
    rng = np.random.default_rng(0)
    nominal = config.nominal.values
    for _ in range(20):
        randomizer = DomainRandomizer(config, g1)
        drawn = randomizer.sample(rng)
        massive = nominal["link_mass"] > 0
        ratio = drawn.physics["link_mass"][massive] / nominal["link_mass"][massive]
        assert 0.88 <= ratio.min() and ratio.max() <= 1.12
        assert np.abs(drawn.physics["link_com"] - nominal["link_com"]).max() <= 0.03 + 1e-12
        assert 0.5 <= drawn.physics.scalar("ground_friction") <= 1.2
        assert drawn.physics.scalar("actuator_latency") in (0.0, 1.0, 2.0)


@pytest.mark.parametrize(
    ("randomization", "error", "message"),
    [
        ({"parameters": [{**POLE_MASS, "parameter": "pole_mass"}]}, RandomizationError, r"entry #0 \(pole_mass\): unknown parameter"),
        ({"parameters": [{**POLE_MASS, "links": ["pole", "mast"]}]}, RandomizationError, r"unknown link 'mast'"),
        ("no/such/file.toml", RandomizationError, r"randomization config file 'no/such/file.toml' does not exist"),
        ("default", RandomizationError, r"robot 'cartpole' ships no default randomization config"),
        (42, RandomizationError, r"randomization must be a config dict, a TOML path"),
        ({"parameters": [{"parameter": "gyro_bias", "distribution": "uniform", "low": 0.0, "high": 0.1, "operation": "add"}],
          "physics_every": 0}, RandomizationError, r"'physics_every' must be an integer >= 1"),
    ],
)
def test_invalid_randomization_is_a_clear_error_at_make(randomization, error, message) -> None:
    with pytest.raises(error, match=message):
        gymnasium.make(CARTPOLE_BALANCE, randomization=randomization)


def test_config_forms_sample_alike(cartpole: RobotDescription, tmp_path) -> None:
    """A dict, a TOML file, a RandomizationConfig and a DomainRandomizer give the same episodes;
    an env never shares a randomizer's state with another (each gets a fresh one)."""
    path = tmp_path / "r.toml"
    path.write_text('[[parameters]]\nparameter = "link_mass"\ndistribution = "uniform"\nlow = 0.5\nhigh = 1.5\n'
                    'operation = "scale"\nlinks = ["pole"]\n')
    shared = DomainRandomizer({"parameters": [POLE_MASS]}, cartpole)
    forms = [{"parameters": [POLE_MASS]}, str(path), RandomizationConfig.from_dict({"parameters": [POLE_MASS]}, cartpole), shared, shared]
    masses = []
    for form in forms:
        env = gymnasium.make(CARTPOLE_BALANCE, randomization=form).unwrapped
        pole = mujoco.mj_name2id(env.engine_robot.model, mujoco.mjtObj.mjOBJ_BODY, "pole")
        row = []
        for seed in (0, 1, 2):
            env.reset(seed=seed)
            row.append(env.engine_robot.model.body_mass[pole])
        masses.append(row)
    assert all(row == masses[0] for row in masses) and len(set(masses[0])) == 3
    assert shared.episodes == 0


# --- reproducibility -----------------------------------------------------------------------------
def test_g1_same_seed_same_parameters_and_identical_rollouts(g1_model: mujoco.MjModel) -> None:
    """The shipped config plus pushes, sensor noise and latency on MuJoCo: two envs seeded 42 agree
    bit for bit over two episodes (parameters, observations, rewards, states); seed 43 differs."""

    def rollout(seed: int) -> tuple[list[dict[str, np.ndarray]], list[bytes]]:
        env = make_g1(g1_model, randomization="default",
                      sim2real={"observation_noise": 0.01, "action_latency": 1,
                                "pushes": {"interval": [0.05, 0.1], "duration": 0.04, "force": [30.0, 60.0]}})
        actions, samples, record = np.random.default_rng(1), [], []
        env.reset(seed=seed)
        for _ in range(2):
            samples.append({**env.randomization.physics.values, **env.randomization.episode.values})
            for _ in range(8):
                observation, reward, *_ = env.step(actions.uniform(-1, 1, 35).astype(np.float32))
                record.append(observation.tobytes() + np.float64(reward).tobytes() + env.engine_robot.data.qpos.tobytes())
            env.reset()
        return samples, record

    (samples_a, record_a), (samples_b, record_b), (samples_c, _) = rollout(42), rollout(42), rollout(43)
    for a, b in zip(samples_a, samples_b):
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    assert record_a == record_b
    assert not np.array_equal(samples_a[0]["link_mass"], samples_c[0]["link_mass"])
    assert not np.array_equal(samples_a[0]["link_mass"], samples_a[1]["link_mass"])  # resampled every episode


def test_cartpole_randomized_on_pybullet_is_reproducible() -> None:
    pytest.importorskip("pybullet")

    def rollout(seed: int) -> list[bytes]:
        env = gymnasium.make(CARTPOLE_BALANCE, engine="pybullet", sim2real={"actuator_delay": 3},
                             randomization={"parameters": [POLE_MASS, {"parameter": "joint_position_noise", "distribution": "uniform",
                                                                       "low": 0.0, "high": 0.01, "operation": "absolute"}]}).unwrapped
        record = []
        for episode in range(3):
            observation, _ = env.reset(seed=seed + episode)
            record.append(observation.tobytes() + np.float64(env.engine_robot.link_mass("pole")).tobytes())
            for _ in range(5):
                record.append(env.step([0.5])[0].tobytes())
        env.close()
        return record

    assert rollout(0) == rollout(0) != rollout(10)


# --- the model changes, the controller's model does not ----------------------------------------------
def test_randomization_changes_the_engine_model_and_the_wbc_keeps_the_nominal_one(g1: RobotDescription, g1_model: mujoco.MjModel) -> None:
    env = make_g1(g1_model, randomization="default", sim2real={"pushes": None})
    m = env.engine_robot.model
    nominal = {name: getattr(m, name).copy() for name in ("body_mass", "body_ipos", "dof_damping", "dof_frictionloss", "dof_armature",
                                                           "actuator_forcerange", "geom_friction", "geom_solref")}
    env.reset(seed=0)
    drawn = env.randomization
    for name, value in nominal.items():
        assert not np.array_equal(getattr(m, name), value), name
    assert not np.array_equal(m.opt.gravity, [0.0, 0.0, -9.81])
    assert m.body_subtreemass[0] == pytest.approx(drawn.physics["link_mass"].sum(), rel=1e-12)
    robot = env.sim_robot
    assert isinstance(robot, PerturbedRobot) and robot.sensors is not None
    assert robot.latency == drawn.physics.scalar("actuator_latency")
    np.testing.assert_array_equal(robot.kp_scale, drawn.physics["kp_scale"])
    assert robot.sensors.errors.imu_latency == drawn.episode.scalar("imu_latency")
    # The WBC's Pinocchio model is the description's, whatever the engine simulates ...
    assert pin.computeTotalMass(env.task.controller.pin_model) == pytest.approx(g1.total_mass)
    zero = np.zeros(35, np.float32)
    for _ in range(25):
        assert not env.step(zero)[2]  # ... and it stands on the randomized robot
    # ... unless asked for the sampled one (an oracle, for studies).
    oracle = make_g1(g1_model, randomization="default", sim2real={"pushes": None}, controller_model="randomized")
    oracle.reset(seed=0)
    assert pin.computeTotalMass(oracle.task.controller.pin_model) == pytest.approx(oracle.randomization.physics["link_mass"].sum())
    with pytest.raises(ValueError, match="needs controller='wbc'"):
        make_g1(g1_model, controller="pd", controller_model="randomized")


# --- one place per effect ---------------------------------------------------------------------------
def test_sim2real_robot_knobs_and_the_config_cannot_both_set_an_effect() -> None:
    pushes = {"parameters": [{"parameter": "push_interval", "distribution": "uniform", "low": 1.0, "high": 2.0, "operation": "absolute"},
                             {"parameter": "push_force", "distribution": "uniform", "low": 1.0, "high": 2.0, "operation": "absolute", "link": "cart"}]}
    latency = {"parameters": [{"parameter": "actuator_latency", "distribution": "uniform", "low": 0.0, "high": 3.0, "operation": "absolute"}]}
    with pytest.raises(RandomizationError, match=r"pushes vs push_force, push_interval"):
        gymnasium.make(CARTPOLE_BALANCE, randomization=pushes, sim2real={"pushes": {"link": "cart"}})
    with pytest.raises(RandomizationError, match=r"actuator_delay vs actuator_latency"):
        gymnasium.make(CARTPOLE_BALANCE, randomization=latency, sim2real={"actuator_delay": 2})
    # Apart, each works; the pushes then come from the config alone.
    env = gymnasium.make(CARTPOLE_BALANCE, randomization=pushes).unwrapped
    env.reset(seed=0)
    assert [p.link for p in env.randomization.episode.pushes][:1] == ["cart"] and "pushes" in env.step([0.0])[4]


def test_g1_default_pushes_give_way_to_the_configs_own(g1_model: mujoco.MjModel) -> None:
    own = {"push_horizon": 5.0, "parameters": [
        {"parameter": "push_interval", "distribution": "uniform", "low": 0.5, "high": 0.5, "operation": "absolute"},
        {"parameter": "push_force", "distribution": "uniform", "low": 10.0, "high": 10.0, "operation": "absolute"}]}
    env = make_g1(g1_model, randomization=own)
    env.reset(seed=0)
    assert {round(float(np.linalg.norm(p.force)), 9) for p in env.randomization.episode.pushes} == {10.0}
    default = make_g1(g1_model)
    default.reset(seed=0)
    forces = [np.linalg.norm(p.force) for p in default.randomization.episode.pushes]
    assert forces and all(40.0 <= f <= 120.0 for f in forces)  # PushConfig()'s range


def test_no_randomization_means_no_wrapper() -> None:
    env = gymnasium.make(CARTPOLE_BALANCE).unwrapped
    env.reset(seed=0)
    assert env.randomizer is None and env.sim_robot is env.engine_robot and env.randomization is None
