"""The sim-to-sim evaluation: both controllers on the three conditions, table and JSON, missing policy."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.apps.sim_to_sim import CONDITIONS, PushSetting, evaluate, main, markdown_table

pytest.importorskip("pybullet")
pytest.importorskip("onnx")


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_mujoco()


@pytest.fixture
def residual_policy(tmp_path, g1_model):
    """A small random residual policy for G1Balance-v0, exported with the environment's metadata."""
    from giwbc.policy import MlpWeights, export_onnx

    env = gymnasium.make("giwbc/G1Balance-v0", model=g1_model).unwrapped
    described = env.describe()
    rng = np.random.default_rng(0)
    sizes = (env.observation_space.shape[0], 16, env.action_space.shape[0])
    mlp = MlpWeights(tuple((rng.normal(0, 0.02, (o, i)), np.zeros(o)) for i, o in zip(sizes[:-1], sizes[1:])))
    metadata = {**described, "env_id": "giwbc/G1Balance-v0", "env_kwargs": {"wbc_options": {"solver": "osqp"}}}
    return export_onnx(tmp_path / "residual.onnx", mlp, metadata, action_low=env.action_space.low, action_high=env.action_space.high)


def test_both_controllers_on_every_condition(residual_policy, g1_model) -> None:
    cells = evaluate(policy=residual_policy, episodes=1, seconds=0.8, pushes=PushSetting(force=60.0, interval=(0.6, 0.7)),
                     workers=0, env_kwargs={"model": g1_model})
    assert set(cells) == {"wbc_only", "residual_policy"}
    for row in cells.values():
        assert list(row) == list(CONDITIONS)
        for cell in row.values():  # pushed within 0.8 s, then on to 3 s after the last push's latest end
            assert cell.episodes == 1 and cell.successes == 1 and cell.simulated_s == pytest.approx(0.8 + 0.1 + 3.0)
    table = markdown_table(cells, policy_missing=False)
    assert table.splitlines()[0] == "| controller | mujoco_nominal | mujoco_randomized | pybullet |"
    assert "| residual_policy | 1/1 (100 %) | 1/1 (100 %) | 1/1 (100 %) |" in table


def test_command_without_a_policy_runs_the_wbc_alone(capsys) -> None:
    """The ``giwbc sim-to-sim`` subcommand runs the evaluation it was given (episodes, pushes,
    conditions); with --no-policy, only the WBC row; a table by default, JSON with --json."""
    import argparse

    from giwbc.apps.sim_to_sim import add_sim_to_sim_command

    parser = argparse.ArgumentParser(prog="giwbc")
    add_sim_to_sim_command(parser.add_subparsers(dest="command", required=True))
    argv = ["sim-to-sim", "--episodes", "2", "--seconds", "0.7", "--workers", "0", "--conditions", "pybullet",
            "--no-policy", "--push-force", "50", "--push-interval", "0.6", "0.65"]
    args = parser.parse_args(argv)
    assert args.run(args) == 0
    table = capsys.readouterr().out
    assert "| wbc_only | 2/2 (100 %) |" in table and "residual_policy" not in table and "{" not in table
    args = parser.parse_args([*argv, "--json"])
    assert args.run(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert not result["policy_missing"] and result["pushes"]["force"] == 50.0 and result["pushes"]["interval"] == [0.6, 0.65]
    assert result["episode_seconds"] == pytest.approx(0.7 + 0.1 + 3.0) and result["settle_after_push_s"] == 3.0
    assert list(result["results"]) == ["wbc_only"] and list(result["results"]["wbc_only"]) == ["pybullet"]
    cell = result["results"]["wbc_only"]["pybullet"]
    assert cell["episodes"] == 2 and cell["success_rate"] == 1.0
    assert main(["--episodes", "1", "--seconds", "0.1", "--workers", "0", "--conditions", "pybullet", "--no-policy", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pushes"]["force"] == PushSetting.force


def test_command_refuses_a_missing_or_walking_policy_in_one_line(capsys) -> None:
    from giwbc.apps.cli import main as giwbc_main

    with pytest.raises(SystemExit) as refused:
        giwbc_main(["sim-to-sim", "--policy", "no/such/policy.onnx"])
    assert refused.value.code == 2 and capsys.readouterr().err.count("\n") == 1
    assert giwbc_main(["sim-to-sim", "--policy", "policies/g1_walk_residual.onnx", "--episodes", "1"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and "G1Walk-v0" in captured.err