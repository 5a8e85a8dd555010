"""Push-recovery evaluation: a couple of short G1 episodes (the full 50-episode evaluation is not a test)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from giwbc.apps.evaluation import (  # noqa: E402
    DEFAULT_ENV_KWARGS,
    PushProtocol,
    add_evaluate_command,
    compare,
    mcnemar_exact,
    run_episodes,
    wilson_interval,
)
from giwbc.policy import MlpWeights, export_onnx  # noqa: E402

# A short protocol: one 0.1 s push starting in [0.6, 0.7] s, and the 3 s settle window after it (an earlier push
# meets the reset's transient: the WBC's QP then takes several times longer per tick).
SHORT = PushProtocol(force=30.0, duration=0.1, interval=(0.6, 0.7), episode_seconds=3.8)


def test_protocol_rejects_a_second_push_or_too_short_a_settle_window() -> None:
    with pytest.raises(ValueError, match="second push"):
        PushProtocol(interval=(0.5, 1.2), episode_seconds=5.0)
    with pytest.raises(ValueError, match="judged 3 s after the push ends"):
        PushProtocol(interval=(1.2, 1.6), episode_seconds=4.7)
    overrides = PushProtocol().env_overrides({"sim2real": {"observation_noise": 0.01}, "controller": "wbc"}, 50.0)
    assert overrides["max_episode_steps"] == 240  # 4.8 s: the latest push ends at 1.8 s, + 3 s
    assert overrides["sim2real"] == {"observation_noise": 0.01, "pushes": {"interval": [1.2, 1.6], "duration": 0.2, "force": [80.0, 80.0],
                                                                         "horizon": 2.6}}  # fmt: skip
    assert overrides["controller"] == "wbc"


def test_one_push_per_episode_however_long_the_episode() -> None:
    """The push schedule stops before a second push could start: a 10 s episode gets one push."""
    import gymnasium

    protocol = PushProtocol(force=30.0, duration=0.1, interval=(0.2, 0.3), episode_seconds=10.0)
    env = gymnasium.make("giwbc/G1Balance-v0", **protocol.env_overrides(DEFAULT_ENV_KWARGS, 50.0))
    try:
        env.reset(seed=3)
        pushes = env.unwrapped.sim_robot.pushes
        assert len(pushes) == 1 and 0.2 <= pushes[0].start <= 0.3
    finally:
        env.close()


def test_wilson_interval() -> None:
    low, high = wilson_interval(25, 50)
    assert low < 0.5 < high and high - low < 0.3
    assert wilson_interval(0, 0) == (0.0, 1.0)


def _zero_policy(tmp_path, env_kwargs):
    """A policy file whose network outputs exactly zero: it must reproduce the WBC arm."""
    from giwbc.apps.training import describe_env

    described = describe_env("giwbc/G1Balance-v0", env_kwargs)
    n_obs, n_act = len(described["observation_names"]), len(described["action_names"])
    weights = MlpWeights(((np.zeros((8, n_obs)), np.zeros(8)), (np.zeros((n_act, 8)), np.zeros(n_act))))
    metadata = {**described, "env_id": "giwbc/G1Balance-v0", "env_kwargs": env_kwargs}
    return export_onnx(tmp_path / "zero.onnx", weights, metadata)


def test_zero_policy_matches_the_wbc_arm_episode_for_episode(tmp_path) -> None:
    env_kwargs = {**DEFAULT_ENV_KWARGS, "max_episode_steps": 1000}  # the evaluation replaces the time limit
    policy = _zero_policy(tmp_path, env_kwargs)
    comparison = compare(policy, protocol=SHORT, episodes=2, seed=7, workers=2)
    assert comparison.same_pushes
    assert (comparison.wbc.name, comparison.residual.name) == ("wbc", "zero.onnx")  # arms named in the table
    assert [e.seed for e in comparison.wbc.episodes] == [7, 8]
    for wbc, residual in zip(comparison.wbc.episodes, comparison.residual.episodes):
        assert wbc.survived and wbc.success  # 30 N is nothing for the WBC
        assert wbc.survival_time == pytest.approx(SHORT.episode_seconds)
        assert 0.6 <= wbc.push_time <= 0.74
        assert np.linalg.norm(wbc.push_force) == pytest.approx(30.0)
        assert wbc == residual  # same pushes, same states, bit for bit
    summary = comparison.summary()
    assert summary["wbc"]["success_rate"] == 1.0 and summary["residual"]["episodes"] == 2
    assert summary["paired"] == {"saved": 0, "lost": 0, "mcnemar_exact_p": 1.0}
    json.dumps(summary)


def test_mcnemar_exact_matches_the_binomial_tails() -> None:
    assert mcnemar_exact(0, 0) == 1.0 and mcnemar_exact(3, 3) == 1.0
    assert mcnemar_exact(5, 0) == pytest.approx(2 / 32)  # all five discordant pairs one way
    assert mcnemar_exact(0, 5) == mcnemar_exact(5, 0)
    assert mcnemar_exact(8, 2) == pytest.approx(2 * (1 + 10 + 45) / 1024)


def test_results_do_not_depend_on_the_number_of_workers() -> None:
    one = run_episodes(None, protocol=SHORT, episodes=2, seed=3, workers=1)
    two = run_episodes(None, protocol=SHORT, episodes=2, seed=3, workers=2)
    assert one.episodes == two.episodes


def test_evaluate_command(capsys) -> None:
    parser = argparse.ArgumentParser()
    add_evaluate_command(parser.add_subparsers())
    args = parser.parse_args(["evaluate", "--episodes", "1", "--workers", "1", "--force", "30", "--duration", "0.1",
                              "--interval", "0.6", "0.7", "--json"])
    assert args.run(args) == 0
    summary = json.loads(capsys.readouterr().out)
    (arm,) = summary["arms"]
    assert arm["force"] == 30.0 and arm["episodes"] == 1 and arm["success_rate"] == 1.0
    assert arm["mean_survival_time_s"] == pytest.approx(0.7 + 0.1 + 3.0)  # the default episode: the latest push's end + 3 s
    assert arm["settle_after_push_s"] == 3.0 and arm["falls"] == 0


def test_training_is_reproducible_and_a_checkpoint_is_the_final_policy_of_a_shorter_run(tmp_path) -> None:
    """Same seed => same policy file, bit for bit; ``step_N`` of a longer run == the policy of ``--timesteps N``."""
    pytest.importorskip("stable_baselines3")
    from giwbc.apps.training import TrainConfig, train

    def run(name: str, steps: int, every: int):
        return train(TrainConfig(total_timesteps=steps, n_envs=2, seed=3, out_dir=str(tmp_path / name), vectorization="dummy",
                                 checkpoint_every=every, progress_bar=False, eval_episodes=0, net_arch=(8, 8), log_std_init=-1.0,
                                 ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1}))

    long = run("long", 192, 64)
    assert [p.name for p in long.checkpoints] == ["step_64.onnx", "step_128.onnx", "step_192.onnx"]
    short = run("short", 128, 64)  # the same command but --timesteps (checkpoints are restart boundaries of the run)
    again = run("again", 128, 64)
    assert short.policy.read_bytes() == again.policy.read_bytes()
    assert (tmp_path / "long" / "checkpoints" / "step_128.onnx").read_bytes() == short.policy.read_bytes()


def test_training_resumes_from_a_checkpoint(tmp_path) -> None:
    """``resume``: the checkpoint's model and normalizer go on to the total, checkpoints numbered on from it."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from giwbc.apps.training import TrainConfig, train

    common = {"n_envs": 2, "seed": 3, "vectorization": "dummy", "progress_bar": False, "eval_episodes": 0, "net_arch": (8, 8),
              "ppo": {"n_steps": 32, "batch_size": 32, "n_epochs": 1}}
    first = train(TrainConfig(total_timesteps=128, checkpoint_every=64, out_dir=str(tmp_path / "a"), **common))
    checkpoint = tmp_path / "a" / "checkpoints" / "step_64.zip"
    resumed = train(TrainConfig(total_timesteps=192, checkpoint_every=64, out_dir=str(tmp_path / "b"), resume=str(checkpoint), **common))
    assert [p.name for p in resumed.checkpoints] == ["step_128.onnx", "step_192.onnx"]
    assert PPO.load(resumed.model, device="cpu").num_timesteps == 192
    assert first.policy.read_bytes() != resumed.policy.read_bytes()
    with pytest.raises(ValueError, match="seed"):
        TrainConfig(seed=-1)
    with pytest.raises(FileNotFoundError):
        train(TrainConfig(total_timesteps=192, out_dir=str(tmp_path / "c"), resume=str(tmp_path / "missing.zip"), **common))


def _state(run_dir):
    """Everything a run leaves that learning depends on: policy and value parameters, Adam's state,
    the step count, the normalizer's statistics."""
    import pickle

    import torch
    from stable_baselines3 import PPO

    model = PPO.load(run_dir / "policy.zip", device="cpu")
    tensors = {**{f"policy.{k}": v for k, v in model.policy.state_dict().items()},
               **{f"adam.{k}": v for k, v in _flat(model.policy.optimizer.state_dict()).items() if isinstance(v, torch.Tensor)}}
    normalizer = pickle.loads((run_dir / "policy.vecnormalize.pkl").read_bytes())
    return model.num_timesteps, tensors, normalizer


def _flat(tree, prefix=""):
    if isinstance(tree, dict):
        return {k: v for key, value in tree.items() for k, v in _flat(value, f"{prefix}{key}.").items()}
    if isinstance(tree, list):
        return {k: v for i, value in enumerate(tree) for k, v in _flat(value, f"{prefix}{i}.").items()}
    return {prefix: tree}


def test_a_resumed_run_equals_the_uninterrupted_run_bit_for_bit(tmp_path) -> None:
    """N/2 steps then ``--resume`` to N == N steps in one go: parameters, Adam, normalizer, ONNX file.

    Episodes of the cart-pole run across the boundary (episodes of up to 500 steps, 2 x 64 steps per
    rollout), and the learner samples and shuffles after it: a resume that restarted the
    environments or the generators differently would differ."""
    pytest.importorskip("stable_baselines3")
    from giwbc.apps.training import TrainConfig, resume_branch, train

    common = {"n_envs": 2, "seed": 5, "vectorization": "dummy", "progress_bar": False, "eval_episodes": 0, "net_arch": (8, 8),
              "checkpoint_every": 256, "ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 2}}
    whole = train(TrainConfig(total_timesteps=512, out_dir=str(tmp_path / "whole"), **common))
    train(TrainConfig(total_timesteps=256, out_dir=str(tmp_path / "half"), **common))
    resumed = train(TrainConfig(total_timesteps=512, out_dir=str(tmp_path / "resumed"),
                                resume=str(tmp_path / "half" / "checkpoints" / "step_256.zip"), **common))
    steps, tensors, normalizer = _state(tmp_path / "whole")
    steps_r, tensors_r, normalizer_r = _state(tmp_path / "resumed")
    assert steps == steps_r == 512 and tensors.keys() == tensors_r.keys() and len(tensors) > 10
    for name, value in tensors.items():
        assert value.dtype == tensors_r[name].dtype and bool((value == tensors_r[name]).all()), name
    for stats in ("obs_rms", "ret_rms"):
        a, b = getattr(normalizer, stats), getattr(normalizer_r, stats)
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.var, b.var) and a.count == b.count
    assert whole.policy.read_bytes() == resumed.policy.read_bytes()
    # The learning curve: one row per rollout (128 steps), the resumed run's rows are the whole run's after 256.
    from giwbc.apps.training import read_learning_curve

    curve, curve_r = read_learning_curve(tmp_path / "whole" / "progress.csv"), read_learning_curve(tmp_path / "resumed" / "progress.csv")
    assert list(curve["timesteps"]) == [128, 256, 384, 512] and list(curve_r["timesteps"]) == [384, 512]
    for name in ("episodes", "return_mean", "length_mean", "terminated"):
        assert np.array_equal(curve[name][2:], curve_r[name], equal_nan=True), name
    assert curve["episodes"].sum() > 0 and np.all(curve["terminated"] <= curve["episodes"])
    ended = ~np.isnan(curve["return_mean"])
    assert np.allclose(curve["return_mean"][ended], curve["length_mean"][ended])  # cart-pole: +1 per step survived
    resume = str(tmp_path / "half" / "checkpoints" / "step_256.zip")
    assert resume_branch(TrainConfig(total_timesteps=512, resume=resume, **common)) == []
    assert [r.split(":")[0] for r in resume_branch(TrainConfig(resume=resume, **{**common, "seed": 6, "checkpoint_every": 128}))] == [
        "seed", "checkpoint_every"]
    assert "not a checkpoint" in resume_branch(TrainConfig(resume=str(tmp_path / "half" / "policy.zip"), **common))[0]
    # The restart is seeded from the run: the same checkpoint resumed with another seed goes another way.
    other = train(TrainConfig(total_timesteps=512, out_dir=str(tmp_path / "other"),
                              resume=str(tmp_path / "whole" / "checkpoints" / "step_256.zip"), **{**common, "seed": 6}))
    assert other.policy.read_bytes() != whole.policy.read_bytes()


@pytest.mark.slow
def test_a_resumed_g1_walk_run_equals_the_uninterrupted_run(tmp_path) -> None:
    """The same on a tiny G1Walk run in worker processes (walker, WBC, pushes and commands restarted
    at the boundary), under 200–260 N pushes every 0.3–0.6 s, so that episodes end in falls
    (degenerate QPs) before the boundary: 256 steps in one go == 128 steps, then ``--resume`` to
    256 (~20 s). (The used-env test in test_env_walk.py covers the solver build's part.)"""
    pytest.importorskip("stable_baselines3")
    from giwbc.apps.training import TrainConfig, train

    common = {"env_id": "giwbc/G1Walk-v0", "n_envs": 2, "seed": 0, "vectorization": "subproc", "progress_bar": False, "eval_episodes": 0,
              "net_arch": (16, 16), "checkpoint_every": 128, "log_std_init": -1.0,
              "env_kwargs": {"residuals": ["step"], "max_episode_steps": 400,
                             "sim2real": {"pushes": {"interval": [0.3, 0.6], "duration": 0.2, "force": [200.0, 260.0]}}},
              "ppo": {"n_steps": 16, "batch_size": 16, "n_epochs": 2}}
    whole = train(TrainConfig(total_timesteps=256, out_dir=str(tmp_path / "whole"), **common))
    train(TrainConfig(total_timesteps=128, out_dir=str(tmp_path / "half"), **common))
    resumed = train(TrainConfig(total_timesteps=256, out_dir=str(tmp_path / "resumed"),
                                resume=str(tmp_path / "half" / "checkpoints" / "step_128.zip"), **common))
    steps, tensors, normalizer = _state(tmp_path / "whole")
    steps_r, tensors_r, normalizer_r = _state(tmp_path / "resumed")
    assert steps == steps_r == 256
    assert all(bool((value == tensors_r[name]).all()) for name, value in tensors.items())
    assert np.array_equal(normalizer.obs_rms.mean, normalizer_r.obs_rms.mean) and normalizer.ret_rms.var == normalizer_r.ret_rms.var
    assert whole.policy.read_bytes() == resumed.policy.read_bytes()
