"""G1Walk on a plant drawn per episode (plant="random"): reproducible draws, parameters that really
reach the simulated model, an actor observation without the plant's parameters."""

from __future__ import annotations

import hashlib

import gymnasium
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the ids)
from giwbc.errors import RandomizationError
from giwbc.plants import named_variant
from giwbc.randomization.plant_distribution import PlantDistribution, variant_nominal
from giwbc.robot import load


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _rollout(env, seed: int, steps: int = 15) -> tuple[str, str]:
    observation, info = env.reset(seed=seed)
    digest = hashlib.sha256(observation.tobytes())
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    for _ in range(steps):
        observation, reward, terminated, truncated, info = env.step(zero)
        digest.update(observation.tobytes())
        digest.update(np.float64(reward).tobytes())
        if terminated or truncated:
            break
    return info["plant"], digest.hexdigest()


def test_same_seed_same_plant_and_rollout_also_after_other_episodes():
    fresh = gymnasium.make("giwbc/G1Walk-v0", plant="random")
    used = gymnasium.make("giwbc/G1Walk-v0", plant="random")
    try:
        for seed in (11, 12):  # the used env walks other plants first
            _rollout(used, seed, steps=5)
        first = _rollout(fresh, 7)
        again = _rollout(used, 7)
        assert first == again
        plants = {_rollout(fresh, seed, steps=0)[0] for seed in range(6)}
        assert len(plants) >= 2  # the seed does choose the plant
    finally:
        fresh.close()
        used.close()


def test_drawn_parameters_are_in_the_model_around_the_variant(g1):
    env = gymnasium.make("giwbc/G1Walk-v0", plant="random")
    try:
        seen = {}
        for seed in range(40):
            _, info = env.reset(seed=seed)
            if info["plant"] in ("frictional_joints", "nominal") and info["plant"] not in seen:
                runtime = env.unwrapped
                model = runtime.engine_robot.model
                knee = model.joint("left_knee_joint").dofadr[0]
                wrist = model.joint("left_wrist_yaw_joint").dofadr[0]
                seen[info["plant"]] = (model.dof_frictionloss[knee], model.dof_frictionloss[wrist], model.dof_armature[knee],
                                       runtime.engine_robot.actuator_dynamics, info["privileged"], runtime.privileged_names())
            if len(seen) == 2:
                break
        assert set(seen) == {"frictional_joints", "nominal"}
        armature = g1.joints[g1.joint_names.index("left_knee_joint")].armature
        # frictional_joints: 1.2 N m on the knee plus U(0, 1.0); 0.05 on a 4010 wrist plus U(0, 0.04); armature 0.5x * [0.6, 1.6]
        knee_f, wrist_f, knee_a, dynamics, privileged, names = seen["frictional_joints"]
        assert 1.2 < knee_f < 2.2 and 0.05 < wrist_f < 0.09
        assert 0.5 * 0.6 * armature <= knee_a <= 0.5 * 1.6 * armature and knee_a != pytest.approx(0.5 * armature)
        assert privileged[names.index("frictionloss/left_knee_joint")] == knee_f
        assert privileged[names.index("plant/frictional_joints")] == 1.0
        # nominal: no friction of its own, only the draw; lag 0-4 ms (the nominal plant has none of its own)
        knee_f, wrist_f, knee_a, dynamics, privileged, names = seen["nominal"]
        assert 0.0 < knee_f < 1.0 and 0.0 < wrist_f < 0.04
        assert dynamics is not None and np.all((dynamics.lag >= 0) & (dynamics.lag <= 0.004)) and np.ptp(dynamics.lag) > 0
        assert privileged[names.index("plant/nominal")] == 1.0
    finally:
        env.close()


def test_foot_shape_comes_from_the_variant_model_compiled_once(g1):
    env = gymnasium.make("giwbc/G1Walk-v0", plant={"variants": {"point_feet": 1.0, "nominal": 1.0}})
    try:
        models = {}
        for seed in range(12):
            _, info = env.reset(seed=seed)
            model = env.unwrapped.engine_robot.model
            assert models.setdefault(info["plant"], model) is model  # the same compiled model, reused
        assert set(models) == {"point_feet", "nominal"}
        spheres = [int(np.sum(m.geom_type == 2)) for m in (models["point_feet"], models["nominal"])]
        assert spheres[0] >= spheres[1] + 6  # three sole points a foot
        # the actor sees the same observation layout on every plant: no plant parameters in it
        plain = gymnasium.make("giwbc/G1Walk-v0")
        assert plain.observation_space == env.observation_space
        plain.close()
    finally:
        env.close()


def test_variant_nominal_and_bad_distributions(g1):
    variant = named_variant(g1, "lagged_actuators")
    nominal = variant_nominal(g1, variant)
    assert nominal.values["actuator_lag"][g1.joint_names.index("left_knee_joint")] == pytest.approx(0.004)
    with pytest.raises(RandomizationError, match="unknown variant 'pointy_feet'"):
        PlantDistribution.from_dict({"variants": {"pointy_feet": 1.0}}, g1)
    with pytest.raises(RandomizationError, match="not plant parameters"):
        PlantDistribution.from_dict({"variants": {"nominal": 1.0}, "parameters": [
            {"parameter": "gyro_noise", "distribution": "uniform", "low": 0.0, "high": 0.01, "operation": "absolute"}]}, g1)
    with pytest.raises(RandomizationError, match="sum to 0"):
        PlantDistribution.from_dict({"variants": {"nominal": 0.0}}, g1)
    distribution = PlantDistribution.load("random", g1)
    rng = np.random.default_rng(0)
    counts = {v: 0 for v in distribution.variants}
    for _ in range(4000):
        counts[distribution.draw(rng)] += 1
    expected = 4000 / len(distribution.variants)
    assert all(abs(c - expected) < 5 * np.sqrt(expected) for c in counts.values())


@pytest.mark.slow
def test_evaluate_walk_on_random_plants_pairs_the_plant_draws(tmp_path, capsys):
    """giwbc evaluate --protocol walk --plant random: both arms on the plant each seed draws, figures per plant."""
    import argparse
    import json

    pytest.importorskip("onnxruntime")
    from giwbc.apps.training import describe_env
    from giwbc.apps.walk_evaluation import add_evaluate_command
    from giwbc.policy import MlpWeights, export_onnx

    env_kwargs = {"residuals": ["step"], "sim2real": {"pushes": None}}
    described = describe_env("giwbc/G1Walk-v0", env_kwargs)
    n_obs, n_act = len(described["observation_names"]), len(described["action_names"])
    bias = np.array([0.5, 0.0, -0.5])  # longer, quicker steps than the walker's: an arm that differs
    weights = MlpWeights(((np.zeros((8, n_obs)), np.zeros(8)), (np.zeros((n_act, 8)), bias)))
    policy = export_onnx(tmp_path / "biased.onnx", weights, {**described, "env_id": "giwbc/G1Walk-v0", "env_kwargs": env_kwargs})
    parser = argparse.ArgumentParser()
    add_evaluate_command(parser.add_subparsers())
    args = parser.parse_args(["evaluate", "--protocol", "walk", "--policy", str(policy), "--plant", "random", "--episodes", "2",
                              "--workers", "1", "--force", "40", "--duration", "0.1", "--interval", "1.2", "1.3", "--seed", "3", "--json"])
    assert args.run(args) == 0
    (summary,) = json.loads(capsys.readouterr().out)["comparisons"]
    drawn = []
    env = gymnasium.make("giwbc/G1Walk-v0", plant="random", **env_kwargs)
    for seed in (3, 4):
        drawn.append(env.reset(seed=seed)[1]["plant"])
    env.close()
    assert summary["same_plants"] and summary["same_pushes"]
    per_plant = summary["per_plant"]
    assert sorted(per_plant) == sorted(set(drawn)) and sum(row["episodes"] for row in per_plant.values()) == 2
    assert sum(row["wbc_successes"] for row in per_plant.values()) == round(summary["wbc"]["success_rate"] * 2)
    assert summary["wbc"]["mean_return"] != summary["residual"]["mean_return"]  # the policy acted


def test_the_training_config_builds_its_environment_across_plants():
    """configs/g1_walk_plants.env.json: a G1Walk on random plants with the estimator in the loop and the torque block."""
    import json
    from pathlib import Path

    kwargs = json.loads((Path(__file__).resolve().parents[1] / "configs" / "g1_walk_plants.env.json").read_text())
    kwargs.pop("max_episode_steps")
    env = gymnasium.make("giwbc/G1Walk-v0", **kwargs)
    try:
        runtime = env.unwrapped
        assert runtime.estimated is not None  # the walker reads the estimator's base
        names = runtime.task.action_names()
        assert sum(n.startswith("torque/") for n in names) == 12 and "hip/roll_gain" in names
        observation, info = env.reset(seed=2)
        assert info["plant"] in runtime.distribution.variants
        assert len(info["privileged"]) == len(runtime.privileged_names())
        assert observation.shape == env.observation_space.shape  # the plant's parameters are not in it
        commands = runtime.task.commands
        assert commands.vx == (-0.5, 0.65) and commands.yaw_rate == (-1.0, 1.0)
    finally:
        env.close()
