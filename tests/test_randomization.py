"""Domain randomization: configs validated with clear errors, samples reproducible from the seed,
every parameter visibly applied to MuJoCo (in place, equal to recompiling) and PyBullet, and
re-applying from nominal never accumulates."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from giwbc.randomization import (
    PARAMETERS,
    DomainRandomizer,
    EngineChoice,
    PerturbedRobot,
    RandomizationConfig,
    RandomizationError,
    randomized_pinocchio_model,
    sample_group,
)
from giwbc.randomization.mujoco import dampratio_for_restitution
from giwbc.robot import MujocoRobot, RobotDescription
from giwbc.robot.mujoco_model import build_mujoco_spec
from giwbc.robot.standing import pd_hold_command


def entry(parameter: str, low: float | list[float], high: float | list[float] | None = None, operation: str = "absolute", **extra: object) -> dict:
    """A uniform entry (``high`` defaults to ``low``: a fixed value)."""
    return {"parameter": parameter, "distribution": "uniform", "low": low, "high": low if high is None else high, "operation": operation, **extra}


PHYSICS = [
    entry("link_mass", 0.8, 1.2, "scale"),
    {"parameter": "link_com", "distribution": "gaussian", "mean": 0.0, "std": [0.01, 0.01, 0.0], "operation": "add", "links": ["pelvis", "torso_link"]},
    entry("joint_damping", 0.0, 0.5),
    entry("joint_friction", 0.0, 0.2),
    {"parameter": "joint_armature", "distribution": "loguniform", "low": 0.8, "high": 1.25, "operation": "scale"},
    entry("actuator_strength", 0.8, 1.0, "scale", regex=".*_(hip|knee)_.*"),
    entry("kp_scale", 0.9, 1.1, "scale"),
    entry("kd_scale", 0.5, 2.0, "scale", shared=True),
    entry("ground_friction", 0.5, 1.2),
    entry("ground_restitution", 0.0, 0.3),
    {"parameter": "gravity", "distribution": "gaussian", "mean": 0.0, "std": [0.1, 0.1, 0.05], "operation": "add"},
]
EPISODE = [
    entry("joint_position_noise", 0.001, 0.003),
    entry("gyro_bias", -0.01, 0.01, "add"),
    entry("push_interval", 0.5, 1.0),
    entry("push_force", 20.0, 40.0),
]


@pytest.fixture(scope="module")
def g1_config(g1: RobotDescription) -> RandomizationConfig:
    return RandomizationConfig.from_dict({"parameters": PHYSICS + EPISODE, "push_horizon": 5.0}, g1)


# --- configs ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (entry("link_mas", 1.0), r"entry #1 \(link_mas\): unknown parameter 'link_mas' \(did you mean 'link_mass'\?\)"),
        (entry("link_mass", 1.2, 0.8, "scale"), r"entry #1 \(link_mass\): low must be <= high"),
        ({"parameter": "gravity", "distribution": "gaussian", "mean": 0.0, "std": -0.1, "operation": "add"}, r"entry #1 \(gravity\): .*std >= 0"),
        ({"parameter": "link_mass", "distribution": "loguniform", "low": 0.0, "high": 2.0, "operation": "scale"}, r"loguniform .* low > 0"),
        ({"parameter": "link_mass", "distribution": "beta", "operation": "scale"}, r"entry #1 \(link_mass\): 'distribution' must be one of"),
        ({"parameter": "link_mass", "distribution": "uniform", "low": 1.0, "operation": "scale"}, r"missing 'high'"),
        (entry("link_mass", 1.0, operation="scale", links=["pelvis", "tail"]), r"entry #1 \(link_mass\): unknown link 'tail'"),
        (entry("joint_damping", 0.1, joints=["left_knee"]), r"unknown joint 'left_knee' \(did you mean 'left_knee_joint'\?\)"),
        (entry("joint_damping", 0.1, regex="elbow"), r"regex 'elbow' matches no joint name"),
        (entry("joint_damping", 0.1, operation="scale"), r"'scale' would change nothing"),
        (entry("gravity", 0.0, operation="multiply"), r"operation must be one of"),
        (entry("ground_friction", 0.5, links=["pelvis"]), r"'links' does not apply: this parameter takes no targets"),
        (entry("joint_damping", 0.1, links=["pelvis"]), r"'links' does not apply: this parameter takes joints"),
        (entry("gravity", [0.0, 0.0], [1.0, 1.0], operation="add"), r"gravity has 3 component\(s\)"),
        (entry("link_mass", [1.0, 1.0, 1.0], operation="scale"), r"link_mass has 1 component\(s\); give scalar bounds"),
        ({**entry("ground_friction", 0.5), "sigma": 1.0}, r"entry #1 \(ground_friction\): unknown keys \['sigma'\]"),
        (entry("push_force", 10.0), r"pushes need both a 'push_force' and a 'push_interval' entry"),
        (entry("push_force", 10.0, link="nose"), r"unknown link 'nose'"),
    ],
)
def test_invalid_entries_are_rejected_naming_the_entry(g1: RobotDescription, bad: dict, message: str) -> None:
    with pytest.raises(RandomizationError, match=message):
        RandomizationConfig.from_dict({"parameters": [entry("ground_friction", 0.5), bad]}, g1)


def test_invalid_top_level_keys_are_rejected(g1: RobotDescription) -> None:
    with pytest.raises(RandomizationError, match=r"unknown keys \['parameter'\]"):
        RandomizationConfig.from_dict({"parameter": []}, g1)
    with pytest.raises(RandomizationError, match="physics_every"):
        RandomizationConfig.from_dict({"physics_every": 0}, g1)
    with pytest.raises(RandomizationError, match="invalid TOML"):
        RandomizationConfig.from_toml("parameters = [\n", g1)


def test_toml_and_dict_configs_sample_the_same(g1: RobotDescription, tmp_path) -> None:
    toml = """
[randomization]
physics_every = 2

[[randomization.parameters]]
parameter = "link_mass"
distribution = "uniform"
low = 0.9
high = 1.1
operation = "scale"
regex = ".*_knee_link"

[[randomization.parameters]]
parameter = "gravity"
distribution = "gaussian"
mean = 0.0
std = [0.1, 0.1, 0.0]
operation = "add"
"""
    path = tmp_path / "randomization.toml"
    path.write_text(toml)
    from_toml = RandomizationConfig.from_toml(path, g1)
    from_dict = RandomizationConfig.from_dict(
        {
            "physics_every": 2,
            "parameters": [
                entry("link_mass", 0.9, 1.1, "scale", regex=".*_knee_link"),
                {"parameter": "gravity", "distribution": "gaussian", "mean": 0.0, "std": [0.1, 0.1, 0.0], "operation": "add"},
            ],
        },
        g1,
    )
    assert from_toml.physics_every == 2
    a, b = (sample_group(c, "physics", np.random.default_rng(5)) for c in (from_toml, from_dict))
    for name in a.values:
        np.testing.assert_array_equal(a[name], b[name])
    changed = np.flatnonzero(a["link_mass"] != from_toml.nominal.values["link_mass"])
    assert [from_toml.nominal.links[i] for i in changed] == ["left_knee_link", "right_knee_link"]
    assert a["gravity"][2] == -9.81 and a["gravity"][0] != 0.0  # std 0 on z


# --- sampling --------------------------------------------------------------------------------
def test_same_seed_same_samples_other_seed_other_samples(g1_config: RandomizationConfig) -> None:
    def draw(seed: int):
        rng = np.random.default_rng(seed)
        return sample_group(g1_config, "physics", rng), sample_group(g1_config, "episode", rng)

    (p1, e1), (p2, e2), (p3, _) = draw(7), draw(7), draw(8)
    for name in p1.values:
        np.testing.assert_array_equal(p1[name], p2[name])
    for name in e1.values:
        np.testing.assert_array_equal(e1[name], e2[name])
    assert e1.noise_seed == e2.noise_seed and len(e1.pushes) == len(e2.pushes) > 0
    for a, b in zip(e1.pushes, e2.pushes):
        assert a.start == b.start and np.array_equal(a.force, b.force)
    assert not np.array_equal(p1["link_mass"], p3["link_mass"])


def test_samples_follow_their_distributions(g1: RobotDescription, g1_config: RandomizationConfig) -> None:
    rng = np.random.default_rng(0)
    nominal = g1_config.nominal.values
    sample = sample_group(g1_config, "physics", rng)
    massive = nominal["link_mass"] > 0
    ratio = sample["link_mass"][massive] / nominal["link_mass"][massive]
    assert np.all((0.8 <= ratio) & (ratio <= 1.2)) and len(np.unique(ratio)) == massive.sum()  # one draw per link
    np.testing.assert_array_equal(sample["link_mass"][~massive], 0.0)  # massless frames stay massless
    strength = sample["actuator_strength"] / g1.effort_limits
    hips_knees = np.array(["hip" in n or "knee" in n for n in g1.joint_names])
    assert np.all((0.8 <= strength[hips_knees]) & (strength[hips_knees] <= 1.0))
    np.testing.assert_array_equal(strength[~hips_knees], 1.0)
    moved = np.flatnonzero(np.any(sample["link_com"] != nominal["link_com"], axis=1))
    assert sorted(g1_config.nominal.links[i] for i in moved) == ["pelvis", "torso_link"]
    np.testing.assert_array_equal(sample["link_com"][moved, 2], nominal["link_com"][moved, 2])  # std 0 on z
    episode = sample_group(g1_config, "episode", rng)
    for push in episode.pushes:
        assert 20.0 <= np.linalg.norm(push.force) <= 40.0 and push.force[2] == 0.0 and push.link == "pelvis"
    starts = np.array([p.start for p in episode.pushes])
    previous_ends = np.concatenate([[0.0], starts[:-1] + 0.1])  # nominal push duration 0.1 s
    waits = starts - previous_ends
    assert np.all((0.5 - 1e-9 <= waits) & (waits <= 1.0 + 1e-9)) and starts[-1] < 5.0  # push_horizon


def test_gaussian_draws_are_clipped_to_physical_ranges(g1: RobotDescription) -> None:
    config = RandomizationConfig.from_dict(
        {"parameters": [{"parameter": "ground_friction", "distribution": "gaussian", "mean": 0.0, "std": 1.0, "operation": "absolute"},
                        {"parameter": "ground_restitution", "distribution": "gaussian", "mean": 0.5, "std": 5.0, "operation": "absolute"},
                        {"parameter": "actuator_latency", "distribution": "uniform", "low": 0.0, "high": 3.0, "operation": "absolute"}]},
        g1,
    )
    rng = np.random.default_rng(1)
    samples = [sample_group(config, "physics", rng) for _ in range(200)]
    friction = np.array([s.scalar("ground_friction") for s in samples])
    restitution = np.array([s.scalar("ground_restitution") for s in samples])
    latency = np.array([s.scalar("actuator_latency") for s in samples])
    assert friction.min() == 0.0 and friction.max() > 0.5
    assert restitution.min() == 0.0 and restitution.max() == 1.0
    assert set(latency) == {0.0, 1.0, 2.0, 3.0}


# --- MuJoCo -------------------------------------------------------------------------------------
def test_mujoco_changes_in_place_equal_recompiling(g1: RobotDescription) -> None:
    """In-place randomization + mj_setConst gives the model (and rollout) compiling it would."""
    config = {"parameters": [p for p in PHYSICS if p["parameter"] in ("link_mass", "joint_damping", "joint_armature", "ground_friction", "gravity")]}
    randomizer = DomainRandomizer(config, g1)
    robot = MujocoRobot(g1)
    sample = randomizer.randomize(robot, np.random.default_rng(1)).physics
    spec = build_mujoco_spec(g1)
    for link, mass in zip(randomizer.config.nominal.links, sample["link_mass"]):
        body = spec.body(link)
        if body.mass > 0:
            ratio, body.mass = mass / body.mass, mass
            body.fullinertia = np.array(body.fullinertia) * ratio
            body.inertia = np.array(body.inertia) * ratio
    for name, damping, armature in zip(g1.joint_names, sample["joint_damping"], sample["joint_armature"]):
        spec.joint(name).damping = [damping, 0.0, 0.0]  # MuJoCo 4: linear term, then polynomial ones
        spec.joint(name).armature = armature
    for geom in spec.geoms:
        if geom.contype:
            geom.friction = [sample.scalar("ground_friction"), 0.005, 0.0001]
    spec.option.gravity = sample["gravity"]
    compiled = spec.compile()
    for field in ("body_mass", "body_inertia", "body_subtreemass", "body_invweight0", "dof_invweight0", "dof_M0", "dof_damping", "dof_armature", "actuator_acc0", "geom_friction"):
        np.testing.assert_allclose(getattr(robot.model, field), getattr(compiled, field), rtol=1e-9, atol=1e-12, err_msg=field)
    np.testing.assert_array_equal(robot.model.opt.gravity, compiled.opt.gravity)
    twin = MujocoRobot(g1, model=compiled)
    for r in (robot, twin):
        r.reset()
        r.set_joint_impedance(pd_hold_command(g1))
        r.step(300)
    np.testing.assert_allclose(robot.data.qpos, twin.data.qpos, atol=1e-12)


def test_mujoco_model_shows_every_sampled_value(g1: RobotDescription, g1_config: RandomizationConfig) -> None:
    randomizer = DomainRandomizer(g1_config, g1)
    robot = PerturbedRobot(MujocoRobot(g1))
    drawn = randomizer.randomize(robot, np.random.default_rng(3))
    physics, m = drawn.physics, robot.model
    nominal = g1_config.nominal.values
    bodies = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link) for link in g1_config.nominal.links]
    # Total mass changes by exactly the sampled amount.
    assert m.body_subtreemass[0] == pytest.approx(physics["link_mass"].sum(), rel=1e-12)
    assert m.body_subtreemass[0] - g1.total_mass == pytest.approx(physics["link_mass"].sum() - nominal["link_mass"].sum(), abs=1e-9)
    np.testing.assert_array_equal(m.body_mass[bodies], physics["link_mass"])
    massive = nominal["link_mass"] > 0
    np.testing.assert_array_equal(m.body_ipos[np.array(bodies)[massive]], physics["link_com"][massive])
    dofs = m.jnt_dofadr[1:]
    np.testing.assert_array_equal(m.dof_damping[dofs], physics["joint_damping"])
    np.testing.assert_array_equal(m.dof_frictionloss[dofs], physics["joint_friction"])
    np.testing.assert_array_equal(m.dof_armature[dofs], physics["joint_armature"])
    np.testing.assert_array_equal(m.actuator_forcerange[:, 1], physics["actuator_strength"])
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert m.geom_friction[floor, 0] == physics.scalar("ground_friction")
    assert m.geom_solref[floor, 1] == pytest.approx(dampratio_for_restitution(physics.scalar("ground_restitution")))
    np.testing.assert_array_equal(m.opt.gravity, physics["gravity"])
    # Gain scales reach the actuators through the wrapper: bias = -kp * scale.
    robot.reset()
    robot.set_joint_impedance(pd_hold_command(g1))
    np.testing.assert_allclose(-m.actuator_biasprm[:, 1], g1.kp * physics["kp_scale"])
    np.testing.assert_allclose(-m.actuator_biasprm[:, 2], g1.kd * physics["kd_scale"])
    assert len(set(physics["kd_scale"])) == 1 and len(set(physics["kp_scale"])) == g1.dofs  # shared vs per joint
    # The controller's Pinocchio model stays nominal; the opt-in copy has the sample.
    model = g1.build_pinocchio()
    assert pin.computeTotalMass(model) == pytest.approx(g1.total_mass)
    oracle = randomized_pinocchio_model(model, physics, g1_config.nominal)
    assert pin.computeTotalMass(oracle) == pytest.approx(physics["link_mass"].sum(), rel=1e-12)
    assert pin.computeTotalMass(model) == pytest.approx(g1.total_mass)  # the original is untouched
    # ... and its centre of mass is MuJoCo's.
    q, _ = robot.robot.generalized_state()  # the engine's, without the wrapper's encoder noise
    mujoco.mj_forward(m, robot.data)
    np.testing.assert_allclose(pin.centerOfMass(oracle, oracle.createData(), q), robot.data.subtree_com[1], atol=1e-9)
    assert np.linalg.norm(pin.centerOfMass(model, model.createData(), q) - robot.data.subtree_com[1]) > 1e-4


def test_mujoco_reapplying_from_nominal_does_not_accumulate(g1: RobotDescription) -> None:
    config = {"parameters": [entry("link_mass", 1.1, operation="scale"), entry("joint_armature", 2.0, operation="scale"),
                             entry("gravity", [0.0, 0.0, 1.0], operation="add"), entry("ground_friction", 1.5, operation="scale")]}
    randomizer = DomainRandomizer(config, g1)
    robot = MujocoRobot(g1)
    nominal = {f: getattr(robot.model, f).copy() for f in ("body_mass", "body_inertia", "dof_armature", "geom_friction", "body_subtreemass", "dof_invweight0")}
    for _ in range(4):
        randomizer.randomize(robot, np.random.default_rng(0))
    assert robot.model.body_subtreemass[0] == pytest.approx(1.1 * g1.total_mass)  # 1.1 x, not 1.1^4 x
    np.testing.assert_allclose(robot.model.dof_armature[6:], 2.0 * nominal["dof_armature"][6:])
    np.testing.assert_allclose(robot.model.opt.gravity, [0.0, 0.0, -8.81])
    assert robot.model.geom_friction[0, 0] == pytest.approx(1.5 * g1.floor_friction)
    randomizer.restore(robot)
    for field, value in nominal.items():
        np.testing.assert_array_equal(getattr(robot.model, field), value, err_msg=field)
    np.testing.assert_array_equal(robot.model.opt.gravity, [0.0, 0.0, -9.81])


def test_same_seed_gives_identical_mujoco_rollouts(g1: RobotDescription, g1_config: RandomizationConfig) -> None:
    def rollout(seed: int) -> list[np.ndarray]:
        randomizer = DomainRandomizer(g1_config, g1)
        robot = PerturbedRobot(MujocoRobot(g1))
        rng = np.random.default_rng(seed)
        states = []
        for _ in range(2):  # two episodes
            randomizer.randomize(robot, rng)
            robot.reset()
            for _ in range(4):
                robot.set_joint_impedance(pd_hold_command(g1))
                robot.step(150)
                states.append(np.concatenate([robot.data.qpos, robot.joint_positions(), robot.imu().angular_velocity]))
        return states

    a, b, c = rollout(11), rollout(11), rollout(12)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a[-1], c[-1])


def test_physics_is_resampled_every_n_episodes(g1: RobotDescription) -> None:
    randomizer = DomainRandomizer({"physics_every": 3, "parameters": [entry("ground_friction", 0.2, 1.0), entry("gyro_bias", -1.0, 1.0, "add")]}, g1)
    robot = PerturbedRobot(MujocoRobot(g1))
    rng = np.random.default_rng(0)
    draws = [randomizer.randomize(robot, rng) for _ in range(7)]
    assert [d.resampled for d in draws] == [True, False, False, True, False, False, True]
    frictions = [d.physics.scalar("ground_friction") for d in draws]
    assert frictions[0] == frictions[1] == frictions[2] != frictions[3] == frictions[4] == frictions[5] != frictions[6]
    biases = [tuple(d.episode["gyro_bias"]) for d in draws]
    assert len(set(biases)) == 7  # episode parameters change at every reset


def test_joint_damping_and_friction_act_on_both_engines(cartpole: RobotDescription) -> None:
    """Cart-pole without gravity: a 2 N push on a cart with damping c tends to v = 2 / c; friction
    above the push holds the cart still."""
    from giwbc.robot.pybullet_robot import PybulletRobot

    pytest.importorskip("pybullet")
    damped = {"parameters": [entry("gravity", [0.0, 0.0, 0.0]), entry("joint_damping", 10.0, joints=["linear"])]}
    stuck = {"parameters": [entry("gravity", [0.0, 0.0, 0.0]), entry("joint_friction", 3.0, joints=["linear"])]}
    for robot in (MujocoRobot(cartpole), PybulletRobot(cartpole)):
        for config, expected in ((damped, 0.2), (stuck, 0.0)):
            DomainRandomizer(config, cartpole).randomize(robot, np.random.default_rng(0))
            robot.reset()
            robot.set_joint_torques(np.array([2.0, 0.0]))
            robot.step(1000)
            assert robot.joint_velocities()[0] == pytest.approx(expected, abs=3e-3), type(robot).__name__


# --- PyBullet ------------------------------------------------------------------------------------
def test_pybullet_shows_every_sampled_value(g1: RobotDescription, g1_config: RandomizationConfig) -> None:
    pytest.importorskip("pybullet")
    from giwbc.robot.pybullet_robot import PybulletRobot

    randomizer = DomainRandomizer(g1_config, g1)
    with PybulletRobot(g1) as engine:
        robot = PerturbedRobot(engine)
        physics = randomizer.randomize(robot, np.random.default_rng(3)).physics
        robot.reset()
        c = engine.client
        assert engine.total_mass() == pytest.approx(physics["link_mass"].sum(), rel=1e-12)
        for link, mass in zip(g1_config.nominal.links, physics["link_mass"]):
            assert engine.link_mass(link) == pytest.approx(mass, rel=1e-12)
        for name in ("pelvis", "torso_link"):  # reloaded with the moved inertial frames
            com = c.getDynamicsInfo(engine.body, engine.link_index(name))[3]
            np.testing.assert_allclose(com, physics["link_com"][g1_config.nominal.links.index(name)], atol=1e-12)
        # (getJointInfo keeps reporting the URDF damping; the cart-pole test shows the new one acts.)
        np.testing.assert_array_equal(engine.joint_damping, physics["joint_damping"])
        np.testing.assert_array_equal(engine.joint_friction, physics["joint_friction"])
        np.testing.assert_array_equal(engine.armature, physics["joint_armature"])
        np.testing.assert_array_equal(engine.effort_limits, physics["actuator_strength"])
        floor = c.getDynamicsInfo(engine.floor, -1)
        assert floor[1] == pytest.approx(physics.scalar("ground_friction"))
        assert floor[5] == pytest.approx(physics.scalar("ground_restitution"))
        np.testing.assert_array_equal(engine.gravity, physics["gravity"])
        # The whole-body CoM is the randomized Pinocchio model's.
        oracle = randomized_pinocchio_model(g1.build_pinocchio(), physics, g1_config.nominal)
        q, _ = engine.generalized_state()
        links = [-1, *range(c.getNumJoints(engine.body))]
        positions = np.array([c.getBasePositionAndOrientation(engine.body)[0]] + [c.getLinkState(engine.body, i)[0] for i in links[1:]])
        masses = np.array([c.getDynamicsInfo(engine.body, i)[0] for i in links])
        np.testing.assert_allclose(masses @ positions / masses.sum(), pin.centerOfMass(oracle, oracle.createData(), q), atol=1e-6)
        # Restoring gives the nominal robot back.
        randomizer.restore(robot)
        robot.reset()
        assert engine.total_mass() == pytest.approx(g1.total_mass, rel=1e-12)
        np.testing.assert_allclose(engine.gravity, [0.0, 0.0, -9.81])
        assert c.getDynamicsInfo(engine.floor, -1)[1] == pytest.approx(g1.floor_friction)


def test_pybullet_reapplying_does_not_accumulate(g1: RobotDescription) -> None:
    pytest.importorskip("pybullet")
    from giwbc.robot.pybullet_robot import PybulletRobot

    config = {"parameters": [entry("link_mass", 1.1, operation="scale"), entry("joint_armature", 2.0, operation="scale"), entry("actuator_strength", 0.5, operation="scale")]}
    randomizer = DomainRandomizer(config, g1)
    with PybulletRobot(g1) as robot:
        inertia = np.array(robot.client.getDynamicsInfo(robot.body, robot._joints[3])[2])
        for _ in range(3):
            randomizer.randomize(robot, np.random.default_rng(0))
        assert robot.total_mass() == pytest.approx(1.1 * g1.total_mass)
        np.testing.assert_allclose(robot.effort_limits, 0.5 * g1.effort_limits)
        randomizer.restore(robot)
        np.testing.assert_allclose(robot.client.getDynamicsInfo(robot.body, robot._joints[3])[2], inertia, rtol=1e-12)


# --- robot-level perturbations -------------------------------------------------------------------
def test_actuator_latency_delays_commands_by_whole_physics_steps(g1: RobotDescription) -> None:
    robot = PerturbedRobot(MujocoRobot(g1))
    DomainRandomizer({"parameters": [entry("actuator_latency", 3.0)]}, g1).randomize(robot, np.random.default_rng(0))
    robot.reset()
    torques = np.full(g1.dofs, 1.0)
    robot.set_joint_torques(torques)
    robot.step(3)
    np.testing.assert_array_equal(robot.joint_efforts(), 0.0)  # steps 0, 1, 2 ran without it
    np.testing.assert_array_equal(robot.robot.data.ctrl, torques)  # it reached the actuators on step 3
    robot.step(1)
    np.testing.assert_array_equal(robot.joint_efforts(), torques)
    assert robot.tick == 4


def test_sensor_noise_bias_and_imu_latency(g1: RobotDescription) -> None:
    config = {"parameters": [entry("joint_position_bias", 0.01, operation="add"), entry("joint_velocity_noise", 0.05),
                             entry("gyro_bias", [0.1, -0.1, 0.0], operation="add"), entry("imu_latency", 2.0),
                             entry("accelerometer_bias", [0.0, 0.0, 0.5], operation="add"), entry("imu_orientation_noise", 0.02)]}
    robot = PerturbedRobot(MujocoRobot(g1))
    DomainRandomizer(config, g1).randomize(robot, np.random.default_rng(0))
    robot.reset()
    robot.set_external_wrench("pelvis", [40.0, 0.0, 0.0], [0.0, 0.0, 20.0])  # the IMU has something to see
    history, noise = [], []
    for _ in range(40):
        robot.step(1)
        history.append(robot.robot.imu())
        np.testing.assert_array_equal(robot.joint_positions(), robot.robot.joint_positions() + 0.01)
        first = robot.joint_velocities()
        np.testing.assert_array_equal(first, robot.joint_velocities())  # one draw per physics step
        noise.append(first - robot.robot.joint_velocities())
    assert np.std(noise) == pytest.approx(0.05, rel=0.1)
    delayed = history[-3]  # 2 physics steps old
    np.testing.assert_allclose(robot.imu().angular_velocity, delayed.angular_velocity + [0.1, -0.1, 0.0], atol=1e-12)
    assert robot.imu().time == delayed.time
    np.testing.assert_allclose(robot.imu().linear_acceleration, delayed.linear_acceleration + [0.0, 0.0, 0.5], atol=1e-12)
    tilt = np.degrees(2 * np.arccos(min(1.0, abs(float(np.dot(robot.imu().quaternion, delayed.quaternion))))))
    assert 0.05 < tilt < 10.0  # orientation noise of 0.02 rad per axis: a small, nonzero rotation
    assert np.linalg.norm(robot.imu().quaternion) == pytest.approx(1.0)
    q, v = robot.generalized_state()
    np.testing.assert_array_equal(q[7:], robot.joint_positions())
    np.testing.assert_array_equal(v[6:], robot.joint_velocities())


def test_push_schedule_is_applied_on_its_physics_steps(g1: RobotDescription) -> None:
    config = {"push_horizon": 3.0, "parameters": [entry("push_interval", 0.4, 0.6), entry("push_force", 30.0), entry("push_duration", 0.1)]}
    robot = PerturbedRobot(MujocoRobot(g1))
    drawn = DomainRandomizer(config, g1).randomize(robot, np.random.default_rng(2))
    robot.reset()
    pelvis = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, "pelvis")
    applied = []
    for _ in range(1600):  # 3.2 s: every push of the 3 s horizon has ended
        robot.step(1)
        applied.append(robot.robot.data.xfrc_applied[pelvis, :3].copy())
    applied = np.array(applied)
    pushing = np.linalg.norm(applied, axis=1) > 0
    starts = np.flatnonzero(np.diff(pushing.astype(int)) == 1) + 1
    assert len(starts) == len(drawn.episode.pushes) >= 4
    for start, push in zip(starts, drawn.episode.pushes):
        assert (start + 1) * 0.002 == pytest.approx(push.start, abs=0.001)  # applied[i]: after step i + 1
        np.testing.assert_array_equal(applied[start], push.force)
        assert pushing[start: start + 49].all() and not pushing[start + 50]  # 0.1 s = 50 steps


def test_robot_level_parameters_need_the_wrapper(g1: RobotDescription) -> None:
    randomizer = DomainRandomizer({"parameters": [entry("kp_scale", 0.9, operation="scale")]}, g1)
    with pytest.raises(RandomizationError, match=r"\['kp_scale'\] needs the robot wrapped in giwbc.randomization.PerturbedRobot"):
        randomizer.randomize(MujocoRobot(g1), np.random.default_rng(0))


# --- the engine as a randomized choice ---------------------------------------------------------
def test_engine_choice(g1: RobotDescription) -> None:
    choice = EngineChoice({"mujoco": 0.7, "pybullet": 0.3})
    draws = [choice.sample(np.random.default_rng(seed)) for seed in range(2000)]
    assert draws.count("pybullet") / len(draws) == pytest.approx(0.3, abs=0.03)
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    assert [choice.sample(rng_a) for _ in range(20)] == [choice.sample(rng_b) for _ in range(20)]
    assert EngineChoice({"mujoco": 1.0}).sample(np.random.default_rng(0)) == "mujoco"
    with pytest.raises(RandomizationError, match="unknown engines \\['gazebo'\\]"):
        EngineChoice({"gazebo": 1.0})
    with pytest.raises(RandomizationError, match="sum to 1"):
        EngineChoice({"mujoco": 0.7, "pybullet": 0.7})
    with pytest.raises(RandomizationError, match=">= 0"):
        EngineChoice({"mujoco": 1.5, "pybullet": -0.5})


def test_every_parameter_is_documented() -> None:
    for name, spec in PARAMETERS.items():
        assert spec.doc and spec.scope in ("link", "joint", "global") and spec.group in ("physics", "episode"), name


def test_cartpole_without_imu_randomizes_reproducibly_on_both_engines(cartpole: RobotDescription) -> None:
    """A robot with no IMU and a fixed base: masses, latency and encoder noise, same seed same run."""
    pytest.importorskip("pybullet")
    from giwbc.robot.pybullet_robot import PybulletRobot

    config = {"parameters": [entry("link_mass", 0.5, 1.5, "scale", links=["pole"]), entry("actuator_latency", 0.0, 5.0),
                             entry("joint_position_noise", 0.0, 0.01)]}

    def rollout(make, seed: int) -> np.ndarray:
        robot, randomizer, rng = PerturbedRobot(make()), DomainRandomizer(config, cartpole), np.random.default_rng(seed)
        readings = []
        for _ in range(2):
            randomizer.randomize(robot, rng)
            robot.reset(q=np.array([0.0, 0.1]))
            for _ in range(5):
                robot.set_joint_torques(np.array([3.0, 0.0]))
                robot.step(40)
                readings.append(robot.joint_positions())
        return np.array(readings)

    for make in (lambda: MujocoRobot(cartpole), lambda: PybulletRobot(cartpole)):
        a, b, c = rollout(make, 5), rollout(make, 5), rollout(make, 6)
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(a, c)
