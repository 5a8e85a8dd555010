"""``giwbc train`` from the command line: every bad input refused in one line (exit 2) before
anything is written, a run folder never silently replaced, the rounding to whole rollouts said up
front and recorded, the progress bar only on stderr. CartPole, tiny rollouts: a few seconds each."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from giwbc.apps.cli import main  # noqa: E402
from giwbc.policy import OnnxPolicy  # noqa: E402

CARTPOLE = "giwbc/CartPoleBalance-v0"
# One environment, 16-step rollouts, a tiny network, short episodes: each run trains in about a second.
TINY = ["--env", CARTPOLE, "--n-envs", "1", "--vectorization", "dummy", "--net-arch", "8", "--seed", "5",
        "--ppo", '{"n_steps": 16, "batch_size": 16, "n_epochs": 1}', "--env-kwargs", '{"max_episode_steps": 15}']


def train(capsys, *argv: str) -> tuple[int, str, str]:
    """``giwbc train TINY argv``: exit code, stdout, stderr."""
    try:
        code = main(["train", *TINY, *argv])
    except SystemExit as stop:  # argparse's refusals
        code = stop.code if isinstance(stop.code, int) else 2
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def refused(capsys, *argv: str) -> str:
    """The one stderr line of a refused ``giwbc train``, asserting exit 2, no traceback, nothing on stdout."""
    code, out, err = train(capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and out == "", (code, out, err)
    assert lines[0].startswith("giwbc train: error: ") and "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def first_run(tmp_path_factory) -> Path:
    """A finished tiny run (checkpoints every 16 steps; --timesteps 20 rounds up to 32)."""
    out = tmp_path_factory.mktemp("train") / "run"
    code = main(["train", *TINY, "--timesteps", "20", "--checkpoint-every", "16", "--out", str(out)])
    assert code == 0
    return out


# --- refusals: one line, exit 2, nothing written ------------------------------------------------
def _zip(path: Path, members: dict[str, str]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, text in members.items():
            archive.writestr(name, text)
    return path


BAD = [
    (["--env", "giwbc/Nope-v0"], "unknown environment 'giwbc/Nope-v0'"),
    (["--env", "CartPole-v1"], "cannot describe itself"),
    (["--timesteps", "0"], "--timesteps: expected an integer in [1,"),
    (["--timesteps", "1e12"], "--timesteps"),
    (["--n-envs", "0"], "--n-envs: expected an integer in [1,"),
    (["--n-envs", "-1"], "--n-envs"),
    (["--checkpoint-every", "-1"], "--checkpoint-every"),
    (["--seed", "-1"], "--seed"),
    (["--log-std-init", "nan"], "--log-std-init: expected a finite number"),
    (["--net-arch", "0"], "--net-arch"),
    (["--ppo", "{n_steps: 16}"], "--ppo: not JSON"),
    (["--ppo", "[16]"], "--ppo: expected a JSON object"),
    (["--ppo", '{"n_stepz": 16}'], "'n_stepz' is not a stable-baselines3 PPO option"),
    (["--ppo", '{"seed": 1}'], "'seed' cannot be set here (set by --seed)"),
    (["--ppo", '{"use_sde": true}'], "'use_sde' cannot be set here"),
    (["--ppo", '{"learning_rate": NaN}'], "--ppo: NaN is not a finite number"),
    (["--ppo", '{"gamma": 1.5}'], "--ppo: gamma must be a finite number in (0, 1]"),
    (["--ppo", '{"n_steps": 16.5}'], "--ppo: n_steps must be an integer"),
    (["--ppo", '{"n_steps": 1, "batch_size": 2}'], "must hold at least 2 steps"),
    (["--env-kwargs", '{"max_episode_steps": Infinity}'], "--env-kwargs: Infinity is not a finite number"),
    (["--env-kwargs", '{"no_such_option": 1}'], "--env-kwargs: giwbc/CartPoleBalance-v0 refuses"),
    (["--new-action-mean", "a=nan"], "--new-action-mean: expected NAME=VALUE"),
    (["--new-action-mean", "a=0.5"], "give warm_start"),
    (["--envs-per-worker", "2"], "--envs-per-worker sets how many environments each Ray actor steps: give --ray too"),
]


@pytest.mark.parametrize("argv, message", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_options_are_refused_in_one_line_before_anything_is_written(argv, message, tmp_path, capsys):
    out = tmp_path / "run"
    line = refused(capsys, "--timesteps", "16", "--out", str(out), *argv)
    assert message in line, line
    assert not out.exists()


@pytest.mark.parametrize("case", ["missing", "empty", "corrupted", "not a checkpoint"])
def test_a_bad_resume_file_is_refused(case, tmp_path, capsys):
    path = tmp_path / "step_16.zip"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "corrupted":
        path.write_bytes(np.random.default_rng(1).bytes(2048))
    elif case == "not a checkpoint":
        _zip(path, {"notes.txt": "hello"})
    line = refused(capsys, "--timesteps", "16", "--out", str(tmp_path / "run"), "--resume", str(path))
    assert {"missing": "no such file", "empty": "empty file", "corrupted": "not a checkpoint written by giwbc train",
            "not a checkpoint": "not a checkpoint written by giwbc train"}[case] in line, line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("case", ["missing", "empty", "corrupted"])
def test_a_bad_warm_start_file_is_refused(case, tmp_path, capsys):
    path = tmp_path / "policy.onnx"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "corrupted":
        path.write_bytes(np.random.default_rng(2).bytes(2048))
    line = refused(capsys, "--timesteps", "16", "--out", str(tmp_path / "run"), "--warm-start", str(path))
    assert {"missing": "no such file", "empty": "empty file", "corrupted": "onnxruntime cannot load it"}[case] in line, line
    assert not (tmp_path / "run").exists()


def test_an_out_that_cannot_be_a_run_folder_is_refused(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert f"--out: {blocker} is a file, not a run folder" in refused(capsys, "--timesteps", "16", "--out", str(blocker))
    line = refused(capsys, "--timesteps", "16", "--out", str(blocker / "run"))  # a folder inside a file: mkdir fails
    assert f"--out: cannot write the run folder {blocker / 'run'}" in line, line
    assert blocker.read_text() == "not a folder"


def test_a_checkpoint_of_another_environment_is_refused(first_run, tmp_path, capsys):
    checkpoint = first_run / "checkpoints" / "step_16.zip"
    # G1Balance observes more than CartPole's 5 entries: the checkpoint's shapes say it is not of this environment
    line = refused(capsys, "--env", "giwbc/G1Balance-v0", "--timesteps", "16", "--out", str(tmp_path / "g1"), "--resume", str(checkpoint))
    assert "is of another environment (5 observations and 1 actions" in line and "--warm-start" in line, line
    # the same shapes, but its run folder's config.json names another environment
    other = tmp_path / "swing"
    shutil.copytree(first_run, other)
    config = json.loads((other / "config.json").read_text())
    (other / "config.json").write_text(json.dumps({**config, "env_id": "giwbc/CartPoleSwingUp-v0"}))
    line = refused(capsys, "--timesteps", "48", "--out", str(other), "--resume", str(other / "checkpoints" / "step_16.zip"))
    assert "is a checkpoint of a giwbc/CartPoleSwingUp-v0 run, not giwbc/CartPoleBalance-v0" in line, line
    (other / "checkpoints" / "step_16.vecnormalize.pkl").unlink()
    (other / "config.json").write_text(json.dumps(config))
    line = refused(capsys, "--timesteps", "48", "--out", str(other), "--resume", str(other / "checkpoints" / "step_16.zip"))
    assert "its normalizer" in line and "is missing" in line, line
    assert not (tmp_path / "g1").exists()


def _damage(path: Path) -> None:
    """Flip one byte in the middle of a file (inside a zip's compressed member: its checksum fails)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("option", ["--resume", "--warm-start"])
def test_a_damaged_checkpoint_or_normalizer_is_refused(option, first_run, tmp_path, capsys):
    source = tmp_path / "source"
    shutil.copytree(first_run, source)
    checkpoint = source / "checkpoints" / "step_16.zip"
    _damage(checkpoint)
    line = refused(capsys, "--timesteps", "48", "--out", str(tmp_path / "run"), option, str(checkpoint))
    assert "corrupted" in line or "not an intact checkpoint" in line, line
    shutil.copy(first_run / "checkpoints" / "step_16.zip", checkpoint)
    (source / "checkpoints" / "step_16.vecnormalize.pkl").write_bytes(b"\x80\x04not a pickle")
    line = refused(capsys, "--timesteps", "48", "--out", str(tmp_path / "run"), option, str(checkpoint))
    assert "normalizer" in line and "is corrupted" in line, line
    assert not (tmp_path / "run").exists()


def test_a_warm_start_of_other_hidden_layers_is_refused(first_run, tmp_path, capsys):
    line = refused(capsys, "--timesteps", "16", "--out", str(tmp_path / "run"), "--warm-start", str(first_run / "policy.onnx"),
                   "--net-arch", "16", "16")
    assert "has hidden layers [8], this run [16, 16] (give --net-arch 8)" in line, line
    assert not (tmp_path / "run").exists()


# --- the run folder -------------------------------------------------------------------------------
def test_a_run_folder_is_never_silently_replaced(first_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    before = {path: path.read_bytes() for path in out.rglob("*") if path.is_file()}
    line = refused(capsys, "--timesteps", "16", "--out", str(out))
    assert f"--out: {out} already holds a run" in line and f"--resume {out / 'checkpoints' / 'step_32.zip'}" in line, line
    assert "--overwrite" in line
    assert {path: path.read_bytes() for path in out.rglob("*") if path.is_file()} == before  # nothing of it lost

    code, stdout, err = train(capsys, "--timesteps", "16", "--checkpoint-every", "0", "--out", str(out), "--overwrite")
    assert code == 0, err
    assert not list((out / "checkpoints").iterdir())  # the earlier run's checkpoints went with it
    assert OnnxPolicy(out / "policy.onnx").metadata["training"]["timesteps"] == 16
    line = refused(capsys, "--timesteps", "16", "--out", str(out))  # a run without checkpoints: no --resume to suggest
    assert "already holds a run" in line and "(it has no checkpoint to --resume) another --out, or --overwrite" in line, line


def test_a_resume_into_its_own_folder_continues_the_run_exactly(first_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    uninterrupted = (out / "policy.onnx").read_bytes()
    code, stdout, err = train(capsys, "--timesteps", "20", "--checkpoint-every", "16", "--out", str(out),
                              "--resume", str(out / "checkpoints" / "step_16.zip"))
    assert code == 0, err
    assert f"resuming {out / 'checkpoints' / 'step_16.zip'}: continues its run exactly" in err
    assert ("training 16 steps: whole rollouts of n_envs × n_steps = 1 × 16 = 16, from step 16 of "
            f"{out / 'checkpoints' / 'step_16.zip'} to step 32 (--timesteps 20 rounded up to 32)") in err
    assert (out / "policy.onnx").read_bytes() == uninterrupted  # exact resume: the same policy, bit for bit
    code, stdout, err = train(capsys, "--timesteps", "20", "--checkpoint-every", "16", "--out", str(out),
                              "--resume", str(out / "checkpoints" / "step_16.zip"), "--seed", "6")
    assert code == 0 and "a new branch (seed: 5 in the run, 6 now)" in err, err
    assert (out / "policy.onnx").read_bytes() != uninterrupted


# --- rounding, metadata, progress -------------------------------------------------------------------
def test_the_rounding_to_whole_rollouts_is_said_up_front_and_recorded(tmp_path, capsys):
    out = tmp_path / "run"
    code, stdout, err = train(capsys, "--timesteps", "20", "--checkpoint-every", "0", "--out", str(out), "--n-envs", "2")
    assert code == 0, err
    lines = err.splitlines()
    assert lines[0] == "training 32 steps: whole rollouts of n_envs × n_steps = 2 × 16 = 32 (--timesteps 20 rounded up to 32)"
    assert len(lines) == 1  # not a terminal: no progress bar
    assert stdout.splitlines()[0] == f"policy: {out / 'policy.onnx'}"
    training = OnnxPolicy(out / "policy.onnx").metadata["training"]
    assert training["timesteps"] == 32 and training["n_envs"] == 2 and training["n_steps"] == 16
    assert json.loads((out / "config.json").read_text())["total_timesteps"] == 20  # what was asked
    rows = (out / "progress.csv").read_text().splitlines()
    assert [int(row.split(",")[0]) for row in rows[1:]] == [32]  # one rollout of 2 × 16 steps


def test_the_progress_bar_goes_to_stderr_only(tmp_path, capsys):
    code, stdout, err = train(capsys, "--timesteps", "32", "--checkpoint-every", "0", "--out", str(tmp_path / "run"), "--progress")
    assert code == 0, err
    assert "32/32" in err and "step" in err  # forced: drawn on stderr although it is no terminal
    assert "%|" not in stdout and "32/32" not in stdout
    with pytest.raises(SystemExit):  # --progress and --no-progress contradict each other
        main(["train", "--progress", "--no-progress"])
    assert "not allowed with argument" in capsys.readouterr().err


def test_help_says_what_every_option_is_with_defaults(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # (argparse wraps lines)
    assert stop.value.code == 0
    for expected in ("(default: 100000)", "(default: 4)", "(default: 50000)", "(default: subproc)", "(default: 0)",
                     "rounded up to whole rollouts", "0: no checkpoints", "--overwrite"):
        assert expected in text, expected


def test_a_warm_started_run_is_not_said_to_resume_exactly(tmp_path) -> None:
    """Resuming a run that began from a warm start is said to start a new branch (its resume is
    measured not to be bit-exact yet); the same run without one continues exactly."""
    import json
    from dataclasses import asdict

    from giwbc.apps.training import TrainConfig, resume_branch

    checkpoints = tmp_path / "run" / "checkpoints"
    checkpoints.mkdir(parents=True)
    (checkpoints / "step_512.zip").write_bytes(b"")
    plain = TrainConfig(resume=str(checkpoints / "step_512.zip"))
    saved = {**json.loads(json.dumps(asdict(plain))), "resume": None}
    (tmp_path / "run" / "config.json").write_text(json.dumps(saved))
    assert resume_branch(plain) == []
    (tmp_path / "run" / "config.json").write_text(json.dumps({**saved, "warm_start": "policies/g1_walk_residual.onnx"}))
    (reason,) = resume_branch(plain)
    assert "warm-started from policies/g1_walk_residual.onnx" in reason
