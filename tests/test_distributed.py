"""Ray (the ``ray`` extra): envs on Ray actors as an SB3 ``VecEnv``, episodes as Ray tasks, lost workers.

One local Ray instance with 2 CPUs serves the whole module; every rollout is short.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from giwbc.apps.cli import main as giwbc_main
from giwbc.distributed import RayRunner, connect, require_ray
from giwbc.errors import GiwbcError, UnavailableError, WorkerLostError

pytest.importorskip("stable_baselines3")
pytest.importorskip("onnx")

CARTPOLE = "giwbc.envs:giwbc/CartPoleBalance-v0"
SHORT_EPISODES = {"max_episode_steps": 15}  # several auto-resets in a short rollout


def test_a_missing_ray_is_one_line_error(monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails as if it were not installed
    with pytest.raises(UnavailableError, match=r"pip install 'giwbc\[ray\]'"):
        require_ray()
    assert giwbc_main(["evaluate", "--ray", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Ray is not installed" in err


def test_ray_flag_on_train_evaluate_and_sim_to_sim() -> None:
    from giwbc.apps.cli import build_parser

    parser = build_parser()
    for command in ("train", "evaluate", "sim-to-sim"):
        assert parser.parse_args([command]).ray is None  # one machine unless asked
        assert parser.parse_args([command, "--ray"]).ray == "local"  # a local instance with this machine's CPUs
        assert parser.parse_args([command, "--ray", "10.0.0.1:6379"]).ray == "10.0.0.1:6379"  # join that cluster
    assert parser.parse_args(["train", "--ray", "--envs-per-worker", "4"]).envs_per_worker == 4
    assert parser.parse_args(["train", "--ray"]).envs_per_worker is None


def test_env_workers_are_planned_within_the_cluster_cpus() -> None:
    from giwbc.distributed.vec_env import plan_workers

    assert plan_workers(3, None, cpus=4.0) == [[0], [1], [2]]  # one env per actor when the CPUs are there
    assert plan_workers(5, None, cpus=2.0) == [[0, 1, 2], [3, 4]]  # else as few per actor as fit
    assert plan_workers(4, 3, cpus=2.0) == [[0, 1, 2], [3]]
    with pytest.raises(UnavailableError, match=r"4 Ray env workers .* need 4 CPUs, the cluster has 2: .*>= 2"):
        plan_workers(4, 1, cpus=2.0)  # the extra actors would wait for a CPU forever
    with pytest.raises(ValueError):
        plan_workers(2, 0, cpus=2.0)


@pytest.fixture(scope="module")
def ray_cluster():
    pytest.importorskip("ray")
    connection = connect(num_cpus=2, object_store_mb=128)
    assert connection.started and connection.cpus == 2
    yield connection
    connection.close()


def _make(vec_cls, n_envs: int, **vec_kwargs):
    from stable_baselines3.common.env_util import make_vec_env

    return make_vec_env(CARTPOLE, n_envs=n_envs, seed=11, env_kwargs=SHORT_EPISODES, vec_env_cls=vec_cls, vec_env_kwargs=vec_kwargs)


def _rollout(venv, steps: int) -> list:
    """Observations, rewards, dones and infos of ``steps`` seeded random steps (actions from a Generator)."""
    rng = np.random.default_rng(5)
    record = [venv.reset()]
    for _ in range(steps):
        actions = rng.uniform(-1.0, 1.0, (venv.num_envs, *venv.action_space.shape)).astype(np.float32)
        record.append(venv.step(actions))
    return record


def _assert_identical(a, b) -> None:
    """Bit for bit: arrays by bytes and dtype, dicts key by key, everything else with ==."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    elif isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b)
        for key in a:
            if key != "t":  # Monitor's episode info: wall-clock seconds since the start
                _assert_identical(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b)
        for x, y in zip(a, b):
            _assert_identical(x, y)
    else:
        assert type(a) is type(b) and a == b


@pytest.mark.parametrize("transport", ["channel", "calls"])
def test_ray_rollouts_are_bit_identical_to_subprocesses(ray_cluster, transport) -> None:
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import SubprocVecEnv

    from giwbc.distributed.vec_env import RayVecEnv

    steps = 40  # 15-step episodes: every environment auto-resets twice
    ray_env = _make(RayVecEnv, 3, envs_per_worker=2, transport=transport)  # 2 actors: envs {0, 1} and {2}
    try:
        assert ray_env.groups == [[0, 1], [2]]
        on_ray = _rollout(ray_env, steps)
        assert ray_env.env_is_wrapped(Monitor) == [True, True, True]
        assert ray_env.get_attr("spec", indices=[2, 0])[0].id == "giwbc/CartPoleBalance-v0"
        ray_env.set_attr("marker", 7, indices=[1])
        assert ray_env.get_attr("marker", indices=[1]) == [7] and not ray_env.has_attr("marker")
        episode_lengths = ray_env.env_method("get_episode_lengths")
    finally:
        ray_env.close()
    subproc = _make(SubprocVecEnv, 3, start_method="fork")
    try:
        in_processes = _rollout(subproc, steps)
    finally:
        subproc.close()
    _assert_identical(on_ray, in_processes)
    dones = np.array([step[2] for step in on_ray[1:]])  # (steps, envs)
    for env, lengths in enumerate(episode_lengths):  # env_method reached each env's own Monitor
        ends = np.flatnonzero(dones[:, env]) + 1
        assert lengths == list(np.diff(ends, prepend=0)) and len(lengths) >= 2 and max(lengths) <= 15
        assert all("terminal_observation" in on_ray[end][3][env] for end in ends)


def test_ppo_on_ray_trains_the_same_policy_as_on_subprocesses(ray_cluster, tmp_path) -> None:
    """SB3's own checks on the way (VecCheckNan, VecNormalize, PPO's space checks), then the same file bit for bit."""
    from stable_baselines3.common.vec_env import VecCheckNan

    from giwbc.distributed.vec_env import RayVecEnv
    from giwbc.apps.training import TrainConfig, train

    checked = VecCheckNan(_make(RayVecEnv, 2), raise_exception=True)
    try:
        _rollout(checked, 20)
    finally:
        checked.close()

    def run(vectorization: str):
        return train(TrainConfig(env_id="giwbc/CartPoleBalance-v0", total_timesteps=64, n_envs=2, seed=4,
                                 out_dir=str(tmp_path / vectorization), vectorization=vectorization, checkpoint_every=0,
                                 progress_bar=False, eval_episodes=0, net_arch=(8, 8), env_kwargs=SHORT_EPISODES,
                                 ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1}))

    on_ray, in_processes = run("ray"), run("subproc")
    assert on_ray.policy.read_bytes() == in_processes.policy.read_bytes()
    assert on_ray.vecnormalize.read_bytes() == in_processes.vecnormalize.read_bytes()


def test_a_worker_dying_mid_step_is_reported_not_skipped(ray_cluster) -> None:
    from giwbc.distributed.vec_env import RayVecEnv

    def crash(action):  # replaces env 1's step: its worker process dies inside the step
        os._exit(1)

    venv = _make(RayVecEnv, 2)
    try:
        venv.reset()
        actions = np.zeros((2, *venv.action_space.shape), np.float32)
        venv.step(actions)
        venv.set_attr("step", crash, indices=[1])
        with pytest.raises(WorkerLostError, match=r"worker 1 \(envs 1\.\.1\) died.*cannot continue"):
            venv.step(actions)
        with pytest.raises(WorkerLostError, match="worker 1"):  # and stays lost: no step with one env missing
            venv.step(actions)
    finally:
        venv.close()


def test_an_env_error_in_a_step_reaches_the_caller_and_the_worker_lives_on(ray_cluster) -> None:
    from giwbc.distributed.vec_env import RayVecEnv

    def fail(action):  # shadows env 0's (Monitor's) step: an error of the env's own, not a lost process
        raise FloatingPointError("simulation diverged")

    with pytest.raises(ValueError, match="transport must be one of channel, calls"):
        _make(RayVecEnv, 1, transport="pigeon")
    venv = _make(RayVecEnv, 2)
    try:
        venv.reset()
        actions = np.zeros((2, *venv.action_space.shape), np.float32)
        venv.set_attr("step", fail, indices=[0])
        with pytest.raises(FloatingPointError, match="simulation diverged"):
            venv.step(actions)
        venv.env_method("__delattr__", "step", indices=[0])  # Monitor's own step again
        observations, rewards, dones, _ = venv.step(actions)
        # env 1 stepped twice, env 0 once: each channel's replies stayed in step with its requests
        assert venv.env_method("get_total_steps") == [1, 2]
        assert observations.shape == (2, *venv.observation_space.shape) and np.isfinite(observations).all()
    finally:
        venv.close()


def test_a_task_whose_worker_dies_is_retried_or_reported(ray_cluster, tmp_path) -> None:
    def die_once(job: tuple[str, int]) -> int:
        marker, value = job
        with open(marker, "a") as file:
            file.write("x")
        if os.path.getsize(marker) == 1:
            os._exit(1)  # the worker process dies: Ray must run the job again
        return value * value

    markers = [str(tmp_path / f"attempts_{i}") for i in range(3)]
    assert RayRunner(ray_cluster, max_retries=1).map(die_once, [(m, i) for i, m in enumerate(markers)]) == [0, 1, 4]
    assert [Path(m).read_text() for m in markers] == ["xx"] * 3  # every job ran twice: died, then succeeded

    def always_die(seed: int) -> int:
        os._exit(1)

    with pytest.raises(WorkerLostError, match=r"always_die\(7\) after 0 retries") as lost:
        RayRunner(ray_cluster, max_retries=0).map(always_die, [7])
    assert isinstance(lost.value, GiwbcError)

    def bad_input(seed: int) -> int:
        raise ValueError(f"bad seed {seed}")

    with pytest.raises(ValueError, match="bad seed 3"):  # our own errors come back as they are, not retried
        RayRunner(ray_cluster).map(bad_input, [3])


@pytest.fixture(scope="module")
def residual_policy(tmp_path_factory) -> Path:
    """A small random residual policy for G1Balance-v0: the two arms differ."""
    from giwbc.policy import MlpWeights, export_onnx
    from giwbc.apps.training import describe_env

    described = describe_env("giwbc/G1Balance-v0", {})
    rng = np.random.default_rng(3)
    sizes = (len(described["observation_names"]), 8, len(described["action_names"]))
    mlp = MlpWeights(tuple((rng.normal(0, 0.05, (o, i)), np.zeros(o)) for i, o in zip(sizes[:-1], sizes[1:])))
    metadata = {**described, "env_id": "giwbc/G1Balance-v0", "env_kwargs": {}}
    return export_onnx(tmp_path_factory.mktemp("policy") / "residual.onnx", mlp, metadata)


def test_evaluate_on_ray_prints_the_same_table(ray_cluster, residual_policy, capsys) -> None:
    argv = ["evaluate", "--policy", str(residual_policy), "--episodes", "1", "--seed", "21", "--force", "40", "70", "--duration", "0.1",
            "--interval", "0.6", "0.7"]  # episodes of 0.7 + 0.1 + 3 s (the settle window after the push)
    assert giwbc_main(argv) == 0
    local = capsys.readouterr().out
    assert giwbc_main([*argv, "--ray"]) == 0
    on_ray = capsys.readouterr().out
    assert "paired at 40 N" in local and "paired at 70 N" in local and "residual.onnx" in local
    assert on_ray == local
    assert ray_cluster.ray.is_initialized()  # joined the running instance, left it running


def test_sim_to_sim_on_ray_gives_the_same_results(ray_cluster, capsys) -> None:
    import json

    argv = ["sim-to-sim", "--no-policy", "--episodes", "6", "--seconds", "0.8", "--conditions", "mujoco_nominal",
            "--push-force", "60", "--push-interval", "0.6", "0.7", "--json"]
    assert giwbc_main([*argv, "--workers", "0"]) == 0
    local = capsys.readouterr().out
    assert giwbc_main([*argv, "--ray"]) == 0
    on_ray = capsys.readouterr().out
    results = [json.loads(out)["results"]["wbc_only"]["mujoco_nominal"] for out in (local, on_ray)]
    for result in results:
        del result["wall_s_per_episode"]
    assert results[0] == results[1] and results[0]["episodes"] == 6  # two chunks of seeds, none dropped
