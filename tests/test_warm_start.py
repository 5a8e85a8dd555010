"""Warm start across layouts: the new run's actor acts as its source on the shared actions and not
at all on the new ones, and its critic values states as the source did."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

WALK = "giwbc/G1Walk-v0"
KWARGS = {"max_episode_steps": 20, "initial_joint_noise": 0.0}


def _source(tmp_path):
    from giwbc.apps.training import TrainConfig, train

    config = TrainConfig(env_id=WALK, total_timesteps=32, n_envs=1, seed=3, out_dir=str(tmp_path / "source"), vectorization="dummy",
                         checkpoint_every=32, progress_bar=False, eval_episodes=0, net_arch=(16, 16), log_std_init=-1.0,
                         env_kwargs={**KWARGS, "residuals": ["step"]}, ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1})
    return train(config).checkpoints[-1].with_suffix(".zip")


def _target(kwargs, log_std_init=-2.0):
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from giwbc.apps.training import _activation, _module_id, describe_env

    venv = VecNormalize(make_vec_env(_module_id(WALK), n_envs=1, seed=5, env_kwargs=kwargs, vec_env_cls=DummyVecEnv), clip_obs=10.0)
    model = PPO("MlpPolicy", venv, seed=5, device="cpu", n_steps=32, batch_size=32,
                policy_kwargs={"net_arch": {"pi": [16, 16], "vf": [16, 16]}, "activation_fn": _activation("tanh"), "log_std_init": log_std_init})
    return model, venv, describe_env(WALK, kwargs)


def _act_and_value(model, venv, raw):
    import torch

    obs = torch.as_tensor(venv.normalize_obs(raw)[None], dtype=torch.float32)
    with torch.no_grad():
        distribution = model.policy.get_distribution(obs)
        return distribution.distribution.mean.numpy()[0], model.policy.predict_values(obs).numpy()[0, 0], distribution.distribution.stddev.numpy()[0]


def test_a_warm_started_policy_with_a_new_block_acts_as_its_source(tmp_path):
    import pickle

    from stable_baselines3 import PPO

    from giwbc.apps.warm_start import warm_start
    from giwbc.policy import OnnxPolicy

    checkpoint = _source(tmp_path)
    source = PPO.load(checkpoint, device="cpu")
    with checkpoint.with_suffix(".vecnormalize.pkl").open("rb") as f:
        source_norm = pickle.load(f)
    source_names = OnnxPolicy(checkpoint.with_suffix(".onnx")).metadata["observation_names"]

    model, venv, described = _target({**KWARGS, "residuals": ["step", "orientation"]})
    names = described["observation_names"]
    started = warm_start(model, venv, checkpoint, names, described["action_names"], log_std_init=-2.0)
    assert started.new_actions == ("orientation/roll", "orientation/pitch", "orientation/yaw")
    assert set(started.new_observations) == {f"last_action/{a}" for a in started.new_actions}
    assert started.shared_actions == 3 and started.shared_observations == len(source_names)

    rng = np.random.default_rng(0)
    for _ in range(5):
        raw = rng.normal(size=len(names)) * 2.0
        shared = np.array([names.index(n) for n in source_names])
        raw_source = raw[shared]
        mean, value, std = _act_and_value(model, venv, raw)
        source_mean, source_value, source_std = _act_and_value(source, source_norm, raw_source)
        # The shared actions as the source's; the new block's mean exactly zero (the walker alone there).
        np.testing.assert_allclose(mean[:3], source_mean, rtol=1e-6, atol=1e-7)
        assert np.all(mean[3:] == 0.0)
        np.testing.assert_allclose(value, source_value, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(std[:3], source_std, rtol=1e-6)
        np.testing.assert_allclose(std[3:], np.exp(-2.0), rtol=1e-6)
    venv.close()


def test_warm_start_refuses_a_source_that_shares_no_action(tmp_path):
    from giwbc.apps.warm_start import warm_start
    from giwbc.errors import ConfigError

    checkpoint = _source(tmp_path)
    model, venv, described = _target({**KWARGS, "residuals": ["orientation"]})
    with pytest.raises(ConfigError, match="shares no observation or no action"):
        warm_start(model, venv, checkpoint, described["observation_names"], described["action_names"], log_std_init=-1.0)
    venv.close()


def test_resume_and_warm_start_are_one_or_the_other():
    from giwbc.apps.training import TrainConfig

    with pytest.raises(ValueError, match="give one of them"):
        TrainConfig(resume="a.zip", warm_start="b.zip")


def test_a_policy_file_warm_start_acts_as_the_policy_file(tmp_path):
    """From a policy .onnx alone (a shipped policy): the shared actions are the file's, the new
    ``hip`` gain is zero, every log std is log_std_init and the critic is PPO's fresh one."""
    from giwbc.apps.warm_start import warm_start
    from giwbc.policy import OnnxPolicy

    onnx = _source(tmp_path).with_suffix(".onnx")
    policy = OnnxPolicy(onnx)
    model, venv, described = _target({**KWARGS, "residuals": ["step", "hip"]}, log_std_init=-0.7)
    fresh = {k: v.clone() for k, v in model.policy.state_dict().items() if "value_net" in k}
    names = described["observation_names"]
    started = warm_start(model, venv, onnx, names, described["action_names"], log_std_init=-0.7)
    assert not started.critic and started.new_actions == ("hip/roll_gain",) and started.shared_actions == 3
    assert venv.obs_rms.count == policy.metadata["training"]["timesteps"]
    shared = np.array([names.index(n) for n in policy.metadata["observation_names"]])
    rng = np.random.default_rng(1)
    for _ in range(5):
        raw = rng.normal(size=len(names)) * 2.0
        mean, value, std = _act_and_value(model, venv, raw)
        np.testing.assert_allclose(mean[:3], policy(raw[shared].astype(np.float32)), rtol=1e-4, atol=1e-5)  # (float32 file)
        assert mean[3] == 0.0
        np.testing.assert_allclose(std, np.exp(-0.7), rtol=1e-6)
    assert all(np.array_equal(fresh[k], v) for k, v in model.policy.state_dict().items() if "value_net" in k)  # the critic as PPO made it
    venv.close()


def test_a_policy_file_with_another_activation_is_refused(tmp_path):
    from giwbc.apps.warm_start import warm_start
    from giwbc.errors import ConfigError

    onnx = _source(tmp_path).with_suffix(".onnx")
    model, venv, described = _target({**KWARGS, "residuals": ["step"]})
    with pytest.raises(ConfigError, match="activation"):
        warm_start(model, venv, onnx, described["observation_names"], described["action_names"], log_std_init=-1.0, activation="relu")
    venv.close()


def test_the_critic_warmup_trains_the_critic_alone_then_both(tmp_path):
    """With ``critic_warmup`` 64 steps and 32-step rollouts, the first two updates leave the actor
    (MLP, mean, log std) bit for bit as the source; the critic moves; from the third, the actor moves too."""
    import torch
    from stable_baselines3 import PPO

    from giwbc.apps.training import TrainConfig, train

    onnx = _source(tmp_path).with_suffix(".onnx")
    common = dict(env_id=WALK, n_envs=1, seed=4, vectorization="dummy", checkpoint_every=32, progress_bar=False, eval_episodes=0,
                  net_arch=(16, 16), log_std_init=-1.0, env_kwargs={**KWARGS, "residuals": ["step"]}, warm_start=str(onnx),
                  ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1}, critic_warmup=64)
    run = train(TrainConfig(total_timesteps=96, out_dir=str(tmp_path / "run"), **common))
    params = {path.stem: PPO.load(path.with_suffix(".zip"), device="cpu").policy.state_dict() for path in run.checkpoints}
    actor = ("mlp_extractor.policy_net", "action_net", "log_std")

    def same(a: str, b: str, part: tuple[str, ...]) -> bool:
        return all(torch.equal(params[a][k], params[b][k]) for k in params[a] if k.startswith(part))

    critic = ("mlp_extractor.value_net", "value_net")
    assert same("step_32", "step_64", actor) and not same("step_32", "step_64", critic)  # the second update: critic alone
    assert not same("step_64", "step_96", actor)  # the third: the actor too
    first = PPO.load(run.checkpoints[0].with_suffix(".zip"), device="cpu").policy
    np.testing.assert_allclose(first.log_std.detach().numpy(), -1.0)  # the first update left the actor too


def test_a_critic_warmup_must_be_a_step_count():
    from giwbc.apps.training import TrainConfig

    with pytest.raises(ValueError, match="critic_warmup"):
        TrainConfig(critic_warmup=-1)


def test_a_new_action_can_start_at_a_chosen_mean(tmp_path):
    """``new_action_means``: the new ``hip`` gain starts at 0.5 (4 rad/m), the shared actions stay the
    source's; a shared or unknown name, or a mean outside [-1, 1], is refused."""
    from giwbc.apps.warm_start import warm_start
    from giwbc.errors import ConfigError
    from giwbc.policy import OnnxPolicy

    onnx = _source(tmp_path).with_suffix(".onnx")
    policy = OnnxPolicy(onnx)
    model, venv, described = _target({**KWARGS, "residuals": ["step", "hip"]})
    names, actions = described["observation_names"], described["action_names"]
    warm_start(model, venv, onnx, names, actions, log_std_init=-1.0, new_action_means={"hip/roll_gain": 0.5})
    raw = np.random.default_rng(2).normal(size=len(names))
    mean, _, _ = _act_and_value(model, venv, raw)
    shared = np.array([names.index(n) for n in policy.metadata["observation_names"]])
    np.testing.assert_allclose(mean[:3], policy(raw[shared].astype(np.float32)), rtol=1e-4, atol=1e-5)
    assert mean[3] == np.float32(0.5)
    for bad in ({"step/x": 0.1}, {"hip/gain": 0.1}, {"hip/roll_gain": 1.5}):
        with pytest.raises(ConfigError, match="new_action_means"):
            warm_start(model, venv, onnx, names, actions, log_std_init=-1.0, new_action_means=bad)
    venv.close()


def test_new_action_means_come_from_the_command_line():
    from giwbc.apps.training import TrainConfig, _name_values

    assert _name_values(["hip/roll_gain=0.5", "a=-1"]) == {"hip/roll_gain": 0.5, "a": -1.0}
    for bad in (["hip/roll_gain"], ["=0.5"], ["a=b"]):
        with pytest.raises(ValueError, match="NAME=VALUE"):
            _name_values(bad)
    with pytest.raises(ValueError, match="give warm_start"):
        TrainConfig(new_action_means={"hip/roll_gain": 0.5})
