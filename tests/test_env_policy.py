"""ONNX policies: export with metadata, inference with onnxruntime only, PPO training end to end, play."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
onnxruntime = pytest.importorskip("onnxruntime")

from giwbc.policy import (  # noqa: E402
    FORMAT,
    MlpWeights,
    ObservationNormalization,
    OnnxPolicy,
    PolicyFormatError,
    export_onnx,
)
from giwbc.apps.play import play, write_video  # noqa: E402

BALANCE = "giwbc/CartPoleBalance-v0"


def cartpole_metadata(**overrides) -> dict:
    from giwbc.apps.training import describe_env

    return {**describe_env(BALANCE, {}), "env_id": BALANCE, "env_kwargs": {}, **overrides}


def random_mlp(rng: np.random.Generator, sizes: tuple[int, ...], activation: str = "tanh") -> MlpWeights:
    return MlpWeights(tuple((rng.normal(0, 0.5, (o, i)), rng.normal(0, 0.1, o)) for i, o in zip(sizes[:-1], sizes[1:])), activation)


@pytest.mark.parametrize("activation", ["tanh", "relu", "elu"])
def test_onnx_graph_computes_the_mlp(tmp_path, rng, activation) -> None:
    mlp = random_mlp(rng, (5, 16, 16, 1), activation)
    normalization = ObservationNormalization(rng.normal(size=5), rng.uniform(0.5, 2.0, 5), 1e-8, 3.0)
    path = export_onnx(tmp_path / "p.onnx", mlp, cartpole_metadata(), normalization=normalization,
                       action_low=np.array([-1.0]), action_high=np.array([1.0]))
    policy = OnnxPolicy(path)
    observations = rng.normal(0, 3, (64, 5)).astype(np.float32)
    expected = np.clip(mlp(normalization(observations.astype(np.float64))), -1.0, 1.0)
    assert np.allclose(policy(observations), expected, atol=1e-5)
    assert policy(observations[0]).shape == (1,)
    assert np.abs(expected).max() == 1.0  # the clip is exercised
    assert policy.metadata["format"] == FORMAT
    assert policy.metadata["joint_names"] == ["linear", "pivot"]
    assert policy.metadata["rates"] == {"agent_hz": 50.0, "controller_hz": 50.0, "physics_hz": 1000.0}
    assert policy.metadata["action_scale"] == [20.0]
    with pytest.raises(ValueError, match="expects 5 observation entries"):
        policy(np.zeros(4, np.float32))


def test_export_refuses_inconsistent_metadata(tmp_path, rng) -> None:
    with pytest.raises(PolicyFormatError, match="lacks"):
        export_onnx(tmp_path / "a.onnx", random_mlp(rng, (5, 1)), {"env_id": BALANCE})
    with pytest.raises(PolicyFormatError, match="maps 4 -> 1"):
        export_onnx(tmp_path / "b.onnx", random_mlp(rng, (4, 1)), cartpole_metadata())
    plain = onnx.helper.make_model(onnx.helper.make_graph(
        [onnx.helper.make_node("Identity", ["x"], ["y"])], "g",
        [onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1])],
        [onnx.helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1])]),
        opset_imports=[onnx.helper.make_opsetid("", 17)])
    plain.ir_version = 8
    onnx.save(plain, str(tmp_path / "plain.onnx"))
    with pytest.raises(PolicyFormatError, match="not a giwbc-policy"):
        OnnxPolicy(tmp_path / "plain.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(PolicyFormatError, match="onnxruntime cannot load"):
        OnnxPolicy(tmp_path / "junk.onnx")


def test_play_checks_the_environment_layout(tmp_path, rng) -> None:
    wrong = cartpole_metadata(joint_names=["slider", "hinge"])
    path = export_onnx(tmp_path / "w.onnx", random_mlp(rng, (5, 1)), wrong)
    with pytest.raises(PolicyFormatError, match="joint_names"):
        play(path)


def test_play_is_deterministic_and_torch_free(tmp_path, rng) -> None:
    path = export_onnx(tmp_path / "p.onnx", random_mlp(rng, (5, 8, 1)), cartpole_metadata(),
                       action_low=np.array([-1.0]), action_high=np.array([1.0]))
    first, second = play(path, episodes=2, seed=3), play(path, episodes=2, seed=3)
    assert first.returns == second.returns and len(first.lengths) == 2 and min(first.lengths) >= 1
    code = (
        "import sys, json; from giwbc.apps.play import play; "
        f"r = play({str(path)!r}, episodes=1, max_steps=5); "
        "print(json.dumps({'torch': 'torch' in sys.modules, 'sb3': 'stable_baselines3' in sys.modules, 'steps': r.lengths[0]}))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1]) == {"torch": False, "sb3": False, "steps": 5}


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_write_video(tmp_path, suffix) -> None:
    imageio = pytest.importorskip("imageio.v2")
    if suffix == ".mp4":
        pytest.importorskip("imageio_ffmpeg")
    frames = [np.full((32, 48, 3), 10 * i, dtype=np.uint8) for i in range(6)]
    path = write_video(tmp_path / f"v{suffix}", frames, fps=50.0)
    decoded = imageio.mimread(path)
    assert len(decoded) == 6
    # The frames come back in order with their content (mp4 is lossy: a few grey levels off).
    for i, frame in enumerate(decoded):
        assert frame.shape[:2] == (32, 48)
        assert abs(float(np.mean(frame[..., :3])) - 10 * i) < 3.0, (i, float(np.mean(frame)))


def test_ppo_train_export_play(tmp_path) -> None:
    """A tiny PPO run: checkpoints, and an ONNX policy equal to SB3's deterministic actor."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from giwbc.apps.training import TrainConfig, train

    config = TrainConfig(total_timesteps=256, n_envs=2, seed=1, out_dir=str(tmp_path / "run"), vectorization="dummy",
                         checkpoint_every=128, progress_bar=False, eval_episodes=1, net_arch=(16, 16),
                         ppo={"n_steps": 64, "batch_size": 64, "n_epochs": 1})
    result = train(config)
    assert [p.name for p in result.checkpoints] == ["step_128.onnx", "step_256.onnx"]
    assert all(p.is_file() and p.with_suffix(".zip").is_file() for p in result.checkpoints)
    assert result.evaluation is not None and result.evaluation.lengths[0] >= 1
    policy = OnnxPolicy(result.policy)
    assert policy.metadata["training"]["timesteps"] == 256 and policy.metadata["observation_normalization"] == "in_graph"

    model = PPO.load(result.model, device="cpu")
    with open(result.vecnormalize, "rb") as stream:
        normalizer = pickle.load(stream)  # a VecNormalize without its venv
    assert isinstance(normalizer, VecNormalize)
    observations = np.random.default_rng(0).normal(0, 1, (32, 5)).astype(np.float32)
    expected, _ = model.predict(normalizer.normalize_obs(observations), deterministic=True)
    assert np.allclose(policy(observations), expected, atol=1e-5)


def test_cli_commands(tmp_path, rng, capsys) -> None:
    """``giwbc train`` and ``giwbc play`` as the lead wires them into giwbc/apps/cli.py."""
    import argparse

    from giwbc.apps.play import add_play_command

    parser = argparse.ArgumentParser(prog="giwbc")
    commands = parser.add_subparsers(dest="command", required=True)
    add_play_command(commands)
    path = export_onnx(tmp_path / "p.onnx", random_mlp(rng, (5, 1)), cartpole_metadata())
    args = parser.parse_args(["play", "--policy", str(path), "--episodes", "2", "--max-steps", "4", "--json"])
    assert args.run(args) == 0
    assert json.loads(capsys.readouterr().out)["lengths"] == [4, 4]

    pytest.importorskip("stable_baselines3")
    from giwbc.apps.training import add_train_command

    add_train_command(commands)
    out = tmp_path / "run"
    args = parser.parse_args(["train", "--timesteps", "64", "--n-envs", "1", "--vectorization", "dummy", "--no-progress",
                              "--checkpoint-every", "0", "--out", str(out),
                              "--ppo", '{"n_steps": 64, "batch_size": 64, "n_epochs": 1}'])
    assert args.run(args) == 0
    assert (out / "policy.onnx").is_file() and (out / "config.json").is_file()
    assert f"policy: {out / 'policy.onnx'}" in capsys.readouterr().out


def test_play_command_reports_a_bad_policy(tmp_path, capsys) -> None:
    import argparse

    from giwbc.apps.play import add_play_command

    parser = argparse.ArgumentParser(prog="giwbc")
    add_play_command(parser.add_subparsers(dest="command", required=True))
    with pytest.raises(SystemExit) as refused:  # refused while parsing, before any environment is built
        parser.parse_args(["play", "--policy", str(tmp_path / "missing.onnx")])
    assert refused.value.code == 2 and "no such file" in capsys.readouterr().err
    corrupted = tmp_path / "corrupted.onnx"
    corrupted.write_bytes(b"not an onnx graph")
    args = parser.parse_args(["play", "--policy", str(corrupted)])
    assert args.run(args) == 2
    assert "onnxruntime cannot load it" in capsys.readouterr().err
