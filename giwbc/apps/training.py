"""Training with PPO (stable-baselines3, CPU torch): vectorized envs, seeds, progress bar, checkpoints,
and export of the deterministic policy to ONNX with the metadata a deployment needs.

Needs the ``train`` extra (torch, stable-baselines3, onnx, onnxruntime, tqdm, rich); everything here
imports them lazily, so ``giwbc --help`` and the deploy path (:mod:`giwbc.policy`) never load torch.

Layout of a run folder::

    out/config.json                                     the TrainConfig
    out/progress.csv                                    the learning curve: one row per rollout (LearningCurve)
    out/checkpoints/step_<N>.{zip,vecnormalize.pkl,onnx}  every checkpoint_every steps
    out/policy.{zip,vecnormalize.pkl,onnx}              the final policy (SB3 model, normalizer, ONNX)

PPO trains whole rollouts of ``n_envs × n_steps`` steps, so ``total_timesteps`` is rounded up to
one: :func:`train` says so on stderr before it starts, and every ONNX file records the steps
actually trained (metadata ``training.timesteps``; the request is ``config.json``'s
``total_timesteps``). A folder that already holds a run is refused (nothing of it lost) unless the
run resumes one of its checkpoints or ``overwrite`` replaces it. Every check is made before any
work (:mod:`giwbc.apps.training_checks`).

Exact resume. A run is defined by its seed and its configuration, ``checkpoint_every`` included:
each checkpoint is a *restart boundary*. Right after a checkpoint is saved (at the start of a
rollout, after the previous PPO update), every environment is reset with seeds derived from
``(seed, N)`` (``N``: the environment steps so far, :func:`boundary_seeds`), and the learner's
generators (numpy's and torch's global ones: action sampling, minibatch shuffling) are reseeded
from the same pair. The episodes running at that moment are cut; the rollout that ended there
already bootstrapped their value from the next observation, as for a time limit. ``--resume
step_N.zip`` loads the model (parameters, Adam state, step count) and the normalizer's
statistics, and performs the same restart before learning, so it continues exactly as the
uninterrupted run did: same seed and configuration => the resumed run's files equal the
uninterrupted run's, bit for bit (tested). Nothing else needs saving: the environments' state
(simulator, controller warm starts, latency buffers, push schedules) is not serialisable in
general, and after a boundary no state from before it is used. A checkpoint at ``N`` is the final
policy of the same command with ``--timesteps N`` (the same ``--checkpoint-every``: the
boundaries are part of the run). Resuming from a file that is not a boundary of the run (the
final ``policy.zip`` between checkpoints, another ``--checkpoint-every``, changed options) works
but starts a new branch: not the uninterrupted run's continuation (``giwbc train --resume`` says
which, from the run folder's ``config.json``: :func:`resume_branch`).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.apps.play import PlayResult, play
from giwbc.apps.progress import Progress, wants_progress
from giwbc.apps.training_checks import (check_checkpoint, check_env, check_out, check_ppo, clear_run, describe_env, json_object,
                                        module_id as _module_id, planned_steps, steps_note)
from giwbc.distributed import add_ray_argument, connect
from giwbc.errors import ConfigError
from giwbc.policy import MlpWeights, ObservationNormalization, export_onnx

if TYPE_CHECKING:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize


LOG_STD_RANGE = (-10.0, 2.0)  # initial log std of the actor: exp(-10) ~ 5e-5 (no exploration) to exp(2) ~ 7 (action units)


@dataclass
class TrainConfig:
    """One PPO run. ``ppo`` overrides stable-baselines3's PPO arguments (n_steps, batch_size, ...)."""

    env_id: str = "giwbc/CartPoleBalance-v0"
    total_timesteps: int = 100_000
    n_envs: int = 4
    seed: int = 0
    out_dir: str = "runs/cartpole"
    vectorization: str = "subproc"  # worker processes; "dummy": all envs in this process; "ray": Ray actors
    ray_address: str | None = None  # vectorization "ray": a cluster's address (None: a local instance)
    envs_per_worker: int | None = None  # vectorization "ray": environments per Ray actor (None: as few as the CPUs allow)
    checkpoint_every: int = 50_000  # environment steps, all envs together; 0: none
    normalize_observations: bool = True
    normalize_rewards: bool = True
    net_arch: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    log_std_init: float = 0.0  # initial log std of the Gaussian actor: < 0 explores less (residual policies)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    ppo: dict[str, Any] = field(default_factory=dict)
    progress_bar: bool = True  # a bar on stderr (the command line draws one only on a terminal, or with --progress)
    eval_episodes: int = 3
    resume: str | None = None  # a checkpoint's .zip (its .vecnormalize.pkl beside it): continue that run to total_timesteps
    warm_start: str | None = None  # another run's checkpoint .zip, or a policy .onnx: a new run starting from it, matched by names (giwbc.apps.warm_start)
    new_action_means: dict[str, float] = field(default_factory=dict)  # warm start: a new action's initial mean (normalized) other than 0
    critic_warmup: int = 0  # environment steps whose updates train the critic alone (the actor frozen): a policy file's warm start has no critic
    overwrite: bool = False  # replace the run out_dir already holds (else train refuses it, unless resuming from it)

    def __post_init__(self) -> None:
        if self.vectorization not in ("subproc", "dummy", "ray"):
            raise ConfigError(f"vectorization must be 'subproc', 'dummy' or 'ray', got {self.vectorization!r}")
        if self.n_envs < 1 or self.total_timesteps < 1 or (self.envs_per_worker is not None and self.envs_per_worker < 1):
            raise ConfigError("n_envs, total_timesteps and envs_per_worker must be >= 1")
        if self.resume is not None and self.warm_start is not None:
            raise ConfigError("resume continues a run, warm_start begins one: give one of them")
        if self.new_action_means and self.warm_start is None:
            raise ConfigError("new_action_means sets new actions of a warm start: give warm_start")
        if self.critic_warmup < 0:
            raise ConfigError(f"critic_warmup must be >= 0 environment steps, got {self.critic_warmup}")
        if self.seed < 0 or self.checkpoint_every < 0:
            raise ConfigError(f"seed and checkpoint_every must be >= 0, got {self.seed} and {self.checkpoint_every}")
        if self.activation not in ("tanh", "relu", "elu"):
            raise ConfigError(f"activation must be tanh, relu or elu, got {self.activation!r}")
        if not self.net_arch or any(int(size) < 1 for size in self.net_arch):
            raise ConfigError(f"net_arch must be one or more hidden layer sizes >= 1, got {list(self.net_arch)}")
        if not (math.isfinite(self.log_std_init) and LOG_STD_RANGE[0] <= self.log_std_init <= LOG_STD_RANGE[1]):
            raise ConfigError(f"log_std_init must be a finite number in {list(LOG_STD_RANGE)}, got {self.log_std_init}")
        try:
            json.dumps(self.env_kwargs)
        except TypeError as error:
            raise ConfigError(f"env_kwargs must be JSON-serializable (they go into the policy metadata): {error}") from error


@dataclass(frozen=True)
class TrainResult:
    """Where a run left its files, and how the exported policy did in evaluation."""

    out_dir: Path
    model: Path
    policy: Path
    vecnormalize: Path | None
    checkpoints: tuple[Path, ...]
    evaluation: PlayResult | None


def boundary_seeds(seed: int, steps: int) -> tuple[int, int]:
    """The learner's seed and the environments' base seed (environment ``i`` gets ``base + i``) at
    the restart boundary after ``steps`` environment steps of the run with ``seed`` (module docstring)."""
    learner, envs = np.random.SeedSequence([seed, steps]).generate_state(2)
    return int(learner), int(envs) >> 1  # numpy's legacy seeding takes < 2**32; env seeds base + i stay below


def _restart(model: "PPO", venv: Any, seed: int, steps: int) -> None:
    """The restart boundary after ``steps`` steps: reseed the learner, reset every environment from
    derived seeds (the normalizer's discounted returns restart with them)."""
    from stable_baselines3.common.utils import set_random_seed

    learner, envs = boundary_seeds(seed, steps)
    set_random_seed(learner)
    venv.seed(envs)
    model._last_obs = venv.reset()
    model._last_episode_starts = np.ones((venv.num_envs,), dtype=bool)


class LearningCurve:
    """``progress.csv``: per rollout, the episodes that ended in it (count, mean return, mean
    length, how many ended by termination rather than the time limit) and the wall time.

    Reads what the vectorized environments report (SB3's ``Monitor`` info); draws nothing, so the
    run's results do not depend on it. A resume from ``N`` steps keeps the rows up to ``N`` and
    appends after them. Episodes cut at a restart boundary are not counted (they did not end)."""

    COLUMNS = ("timesteps", "episodes", "return_mean", "length_mean", "terminated", "wall_s")

    def __init__(self, path: Path, start: int) -> None:
        self.path = path
        rows = [line for line in path.read_text().splitlines()[1:] if int(line.split(",")[0]) <= start] if start and path.is_file() else []
        path.write_text("\n".join([",".join(self.COLUMNS), *rows]) + "\n")
        self._clock = time.monotonic()
        self._returns: list[float] = []
        self._lengths: list[int] = []
        self._terminated = 0

    def record(self, infos: Any) -> None:
        """One vectorized step's infos: keep the episodes that ended."""
        for info in infos:
            episode = info.get("episode")
            if episode is not None:
                self._returns.append(float(episode["r"]))
                self._lengths.append(int(episode["l"]))
                self._terminated += not info.get("TimeLimit.truncated", False)

    def write(self, timesteps: int) -> None:
        """Append the rollout's row and start the next one."""
        n = len(self._returns)
        mean_return = f"{np.mean(self._returns):.4f}" if n else ""
        mean_length = f"{np.mean(self._lengths):.4f}" if n else ""
        with self.path.open("a") as file:
            file.write(f"{timesteps},{n},{mean_return},{mean_length},{self._terminated},{time.monotonic() - self._clock:.1f}\n")
        self._returns, self._lengths, self._terminated = [], [], 0


def read_learning_curve(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """``progress.csv`` as columns (empty cells, rollouts where no episode ended: NaN)."""
    lines = Path(path).read_text().splitlines()
    header = lines[0].split(",")
    values = [[float(cell) if cell else math.nan for cell in line.split(",")] for line in lines[1:] if line]
    table = np.array(values, dtype=float).reshape(len(values), len(header))
    return {name: table[:, i] for i, name in enumerate(header)}


# The TrainConfig fields that define a run (with the seed): a resume that changes one starts a new branch.
RUN_FIELDS = ("env_id", "env_kwargs", "n_envs", "seed", "checkpoint_every", "normalize_observations", "normalize_rewards",
              "net_arch", "activation", "log_std_init", "ppo", "critic_warmup", "new_action_means")  # (a warm start's source is in config.json: its resume gives none)


def resume_branch(config: TrainConfig) -> list[str]:
    """Why resuming ``config.resume`` starts a new branch instead of continuing its run exactly
    (compared with the ``config.json`` of the checkpoint's run folder); empty: it continues exactly."""
    if config.resume is None:
        return ["not a resume"]
    resume = Path(config.resume)
    reasons = []
    if resume.parent.name != "checkpoints" or not resume.name.startswith("step_"):
        reasons.append(f"{resume.name} is not a checkpoint (a restart boundary) of its run")
    run_config = resume.parent.parent / "config.json"
    if not run_config.is_file():
        return [*reasons, f"its run's configuration is not at {run_config}"]
    saved, mine = json.loads(run_config.read_text()), json.loads(json.dumps(asdict(config)))  # tuples as JSON lists
    if saved.get("warm_start"):  # measured: its resume parts from the uninterrupted run at the first rollout (configs/README.md)
        reasons.append(f"the run was warm-started from {saved['warm_start']}, whose resume is not yet exact")
    defaults = json.loads(json.dumps(asdict(TrainConfig())))  # a field newer than the run's config.json: its default
    saved = {key: saved.get(key, defaults[key]) for key in RUN_FIELDS}
    return reasons + [f"{key}: {saved[key]!r} in the run, {mine[key]!r} now" for key in RUN_FIELDS if saved[key] != mine[key]]


def _activation(name: str) -> Any:
    import torch.nn as nn

    try:
        return {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}[name]
    except KeyError:
        raise ValueError(f"activation must be tanh, relu or elu, got {name!r}") from None


def freeze_actor(model: "PPO", frozen: bool) -> None:
    """Whether PPO's updates leave the actor (policy MLP, mean, log std) as it is and train the
    critic alone: a critic warm-up (``TrainConfig.critic_warmup``). Adam skips a parameter without
    a gradient, so a frozen actor keeps its weights and optimizer state exactly."""
    for name, parameter in model.policy.named_parameters():
        if name.startswith(("mlp_extractor.policy_net.", "action_net.", "log_std")):
            parameter.requires_grad_(not frozen)


def sb3_policy_weights(model: "PPO", activation: str) -> MlpWeights:
    """The deterministic actor of an SB3 ``MlpPolicy``: policy MLP then ``action_net`` (the Gaussian mean)."""
    import torch.nn as nn
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy = model.policy
    if not isinstance(policy.action_dist, DiagGaussianDistribution) or policy.squash_output:
        raise ValueError("only unsquashed diagonal-Gaussian MlpPolicy actors can be exported")
    if not isinstance(policy.pi_features_extractor, FlattenExtractor):
        raise ValueError("only flat observations (FlattenExtractor) can be exported")
    expected = type(_activation(activation)())
    layers = []
    for module in policy.mlp_extractor.policy_net:
        if isinstance(module, nn.Linear):
            layers.append(module)
        elif not isinstance(module, expected):
            raise ValueError(f"unexpected module {module} in the policy network (activation {activation})")
    layers.append(policy.action_net)
    return MlpWeights(
        tuple((layer.weight.detach().cpu().numpy().astype(np.float64), layer.bias.detach().cpu().numpy().astype(np.float64)) for layer in layers),
        activation,
    )


def export_sb3_policy(
    model: "PPO",
    path: str | os.PathLike[str],
    *,
    env_id: str,
    env_kwargs: dict[str, Any],
    vecnormalize: "VecNormalize | None" = None,
    activation: str = "tanh",
    described: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Export a PPO actor (with its observation normalization and action clip) to a giwbc ONNX policy."""
    described = described if described is not None else describe_env(env_id, env_kwargs)
    normalization = None
    if vecnormalize is not None and vecnormalize.norm_obs:
        normalization = ObservationNormalization(
            np.asarray(vecnormalize.obs_rms.mean, float), np.asarray(vecnormalize.obs_rms.var, float),
            float(vecnormalize.epsilon), float(vecnormalize.clip_obs),
        )
    space = model.action_space
    metadata = {
        **described,
        "env_id": env_id.split(":", 1)[-1],
        "env_kwargs": env_kwargs,
        "observation_normalization": "in_graph" if normalization is not None else "none",
        **(extra or {}),
    }
    return export_onnx(path, sb3_policy_weights(model, activation), metadata, normalization=normalization,
                       action_low=space.low, action_high=space.high)


def train(config: TrainConfig) -> TrainResult:
    """Train PPO on ``config.env_id``, checkpointing as it goes; export and evaluate the final policy.

    Everything is checked before any work (:mod:`giwbc.apps.training_checks`): the environment, the
    PPO options, the resume or warm-start source, and the run folder (one holding a run is refused
    unless resuming it or ``config.overwrite``). PPO trains whole rollouts of ``n_envs × n_steps``:
    the run says on stderr how many steps it will take, and its policies record the count."""
    out = Path(config.out_dir)
    earlier = check_out(out, config.resume, config.overwrite)
    described = check_env(config.env_id, config.env_kwargs)
    rollout = check_ppo(config.ppo, config.n_envs)
    normalize = config.normalize_observations or config.normalize_rewards
    start = 0 if config.resume is None else check_checkpoint(config.resume, described, config.env_id, normalize).num_timesteps
    if config.warm_start is not None:
        from giwbc.apps.warm_start import check_source

        check_source(config.warm_start, described["observation_names"], described["action_names"], config.net_arch,
                     config.activation, normalize)
    import torch

    torch.set_num_threads(1)  # small MLPs: one thread is fastest, and leaves the cores to the workers
    branch = resume_branch(config) if config.resume is not None else []  # (read before config.json is rewritten)
    try:
        clear_run(earlier)  # (--overwrite: none of the earlier run's checkpoints mixes with this one's)
        (out / "checkpoints").mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(asdict(config), indent=2))
    except OSError as error:
        raise ConfigError(f"--out: cannot write the run folder {out}: {error.strerror or error}") from None
    if config.resume is not None:
        print(f"resuming {config.resume}: " + ("a new branch (" + "; ".join(branch) + ")" if branch else
                                                 "continues its run exactly (same seed and options)"), file=sys.stderr)
    print(steps_note(config.total_timesteps, start, rollout, config.n_envs, config.resume), file=sys.stderr)
    env_id = _module_id(config.env_id)
    planned = planned_steps(config.total_timesteps, start, rollout)
    with connect(config.ray_address) if config.vectorization == "ray" else nullcontext():
        return _train(config, described, env_id, out, planned)


def _train(config: TrainConfig, described: dict[str, Any], env_id: str, out: Path, planned: int) -> TrainResult:
    """:func:`train` once the run folder exists (and Ray is connected for ``vectorization="ray"``)."""
    import stable_baselines3
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize

    vec_cls: type[VecEnv]
    if config.vectorization == "subproc":
        vec_cls, vec_kwargs = SubprocVecEnv, {"start_method": "fork" if os.name == "posix" else "spawn"}
    elif config.vectorization == "ray":
        from giwbc.distributed.vec_env import RayVecEnv  # needs stable-baselines3, like everything here

        vec_cls, vec_kwargs = RayVecEnv, {"envs_per_worker": config.envs_per_worker}
    else:
        vec_cls, vec_kwargs = DummyVecEnv, {}
    venv = make_vec_env(env_id, n_envs=config.n_envs, seed=config.seed, env_kwargs=config.env_kwargs,
                        vec_env_cls=vec_cls, vec_env_kwargs=vec_kwargs)
    ppo_kwargs = {"gamma": 0.99, **config.ppo}
    normalize = config.normalize_observations or config.normalize_rewards
    resume = Path(config.resume) if config.resume else None
    if normalize:
        if resume is not None:  # the running statistics of the checkpoint, not fresh ones
            venv = VecNormalize.load(str(resume.with_suffix(".vecnormalize.pkl")), venv)
        else:
            venv = VecNormalize(venv, norm_obs=config.normalize_observations, norm_reward=config.normalize_rewards,
                                clip_obs=10.0, gamma=ppo_kwargs["gamma"])
    if resume is not None:
        model = PPO.load(resume, env=venv, device="cpu")
        _restart(model, venv, config.seed, model.num_timesteps)  # the boundary the checkpoint was saved at
    else:
        model = PPO(
            "MlpPolicy", venv, seed=config.seed, device="cpu", verbose=0,
            policy_kwargs={"net_arch": {"pi": list(config.net_arch), "vf": list(config.net_arch)},
                           "activation_fn": _activation(config.activation), "log_std_init": config.log_std_init},
            **ppo_kwargs,
        )
        if config.warm_start is not None:
            from giwbc.apps.warm_start import warm_start

            started = warm_start(model, venv, config.warm_start, described["observation_names"], described["action_names"],
                                 config.log_std_init, config.activation, config.new_action_means)
            print(started.summary(), file=sys.stderr)
    start = model.num_timesteps
    training_info = {"algorithm": "PPO", "stable_baselines3": stable_baselines3.__version__, "seed": config.seed,
                     "n_envs": config.n_envs, "n_steps": model.n_steps}  # (+ "timesteps": the steps actually trained)
    checkpoints: list[Path] = []
    curve = LearningCurve(out / "progress.csv", start)

    def save(folder: Path, name: str, steps: int) -> Path:
        """``name.zip`` (SB3), ``name.vecnormalize.pkl`` and ``name.onnx`` in ``folder``."""
        model.save(folder / f"{name}.zip")
        vecnormalize = venv if isinstance(venv, VecNormalize) else None
        if vecnormalize is not None:
            vecnormalize.save(str(folder / f"{name}.vecnormalize.pkl"))
        return export_sb3_policy(model, folder / f"{name}.onnx", env_id=config.env_id, env_kwargs=config.env_kwargs,
                                 vecnormalize=vecnormalize, activation=config.activation, described=described,
                                 extra={"training": {**training_info, "timesteps": steps}})

    class Checkpoints(BaseCallback):
        """Model, normalizer and ONNX policy every ``checkpoint_every`` environment steps (and
        the learning curve's row after every rollout).

        Saved at the start of a rollout, after the previous update: a checkpoint at ``N`` steps is
        then exactly the final policy of the same run with ``total_timesteps=N`` (constant schedules).
        Each one is a restart boundary (module docstring): after saving, the environments and the
        learner's generators restart from seeds derived from ``(seed, N)``, as a resume from it does.
        """

        def __init__(self, every: int) -> None:
            super().__init__()
            self.every, self.next = every, (start // every + 1) * every if every else 0

        def _checkpoint(self) -> bool:
            """Save one if due; whether it was."""
            if not (self.every and self.num_timesteps >= self.next):
                return False
            while self.next <= self.num_timesteps:
                self.next += self.every
            checkpoints.append(save(out / "checkpoints", f"step_{self.num_timesteps}", self.num_timesteps))
            return True

        def _on_rollout_end(self) -> None:
            curve.write(self.num_timesteps)
            freeze_actor(model, self.num_timesteps <= config.critic_warmup)  # for the update that follows

        def _on_rollout_start(self) -> None:
            if self._checkpoint():
                _restart(model, venv, config.seed, self.num_timesteps)

        def _on_training_end(self) -> None:
            self._checkpoint()

        def _on_step(self) -> bool:
            curve.record(self.locals["infos"])
            bar(venv.num_envs)
            return True

    bar = Progress(planned - start, "train", unit="step", enabled=config.progress_bar)  # on stderr, as every giwbc bar
    try:
        model.learn(total_timesteps=max(config.total_timesteps - start, 0), callback=Checkpoints(config.checkpoint_every),
                    progress_bar=False, reset_num_timesteps=resume is None)
        policy_path = save(out, "policy", model.num_timesteps)
    finally:
        bar.close()
        venv.close()
    if model.num_timesteps != planned:  # the note printed before training said `planned`
        raise RuntimeError(f"PPO trained {model.num_timesteps} steps, {planned} were announced")
    evaluation = play(policy_path, episodes=config.eval_episodes, seed=10_000 + config.seed) if config.eval_episodes else None
    return TrainResult(out, out / "policy.zip", policy_path, out / "policy.vecnormalize.pkl" if normalize else None,
                       tuple(checkpoints), evaluation)


# --- command line ------------------------------------------------------------------------------
MAX_TIMESTEPS = 1_000_000_000  # environment steps of one run (a billion: days of G1 training on a large machine)
MAX_ENVS = 1024  # parallel environments of one run
MAX_HIDDEN = 4096  # units of one hidden layer
TRAIN_DESCRIPTION = """train a PPO policy and export it to ONNX (needs the train extra)

Writes OUT/config.json, OUT/progress.csv, OUT/checkpoints/step_N.{zip,vecnormalize.pkl,onnx} and
OUT/policy.{zip,vecnormalize.pkl,onnx}. PPO trains whole rollouts of n_envs x n_steps environment
steps, so --timesteps is rounded up to a multiple of it (said before training starts). An OUT that
already holds a run is refused unless --resume continues it or --overwrite replaces it."""


def _parse_name_value(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` with a finite VALUE in [-1, 1] (a normalized action mean); ``ValueError`` otherwise."""
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        sep = ""
    if not (sep and name) or not (math.isfinite(number) and -1.0 <= number <= 1.0):
        raise ValueError(f"expected NAME=VALUE with VALUE a finite number in [-1, 1], got {text!r}")
    return name, number


def _name_values(items: list[str]) -> dict[str, float]:
    """``["a/b=0.5", ...]`` as ``{"a/b": 0.5}``; ``ValueError`` on another form."""
    return dict(_parse_name_value(item) for item in items)


def _name_value(text: str) -> tuple[str, float]:
    """An argparse type: :func:`_parse_name_value`."""
    import argparse

    try:
        return _parse_name_value(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


_name_value.__name__ = "NAME=VALUE"


def add_train_command(commands: Any) -> None:
    """Add ``giwbc train`` to an argparse subparsers object."""
    from giwbc.apps.arguments import add_command, existing_file, integer, number, seed

    parser = add_command(commands, "train", TRAIN_DESCRIPTION.splitlines()[0], TRAIN_DESCRIPTION)
    parser.add_argument("--env", default=TrainConfig.env_id, help="registered environment id (giwbc/CartPoleBalance-v0, "
                        "giwbc/CartPoleSwingUp-v0, giwbc/G1Balance-v0, giwbc/G1Walk-v0)")
    parser.add_argument("--timesteps", type=integer(1, MAX_TIMESTEPS), default=TrainConfig.total_timesteps,
                        help=f"environment steps to train, all environments together, in [1, {MAX_TIMESTEPS:.0e}]; "
                        "rounded up to whole rollouts (n_envs x n_steps)")
    parser.add_argument("--n-envs", type=integer(1, MAX_ENVS), default=TrainConfig.n_envs,
                        help=f"environments stepped in parallel, in [1, {MAX_ENVS}]; a rollout is n_envs x n_steps steps")
    parser.add_argument("--seed", type=seed(), default=TrainConfig.seed,
                        help="run seed in [0, 2**32-1]: same seed and options, same policy file bit for bit (default: %(default)s)")
    parser.add_argument("--out", default=None, help="run folder (default: runs/<env name>); refused if it holds a run, "
                        "unless --resume continues it or --overwrite replaces it")
    parser.add_argument("--overwrite", action="store_true", help="replace the run --out already holds (its files are deleted)")
    parser.add_argument("--checkpoint-every", type=integer(0, MAX_TIMESTEPS), default=TrainConfig.checkpoint_every,
                        help="environment steps between checkpoints (saved at the first rollout boundary after each "
                        "multiple); 0: no checkpoints")
    parser.add_argument("--vectorization", choices=("subproc", "dummy"), default="subproc",
                        help="subproc: one worker process per environment; dummy: all environments in this process "
                        "(--ray: Ray actors)")
    parser.add_argument("--env-kwargs", default="{}", help='JSON object of options for gymnasium.make, e.g. \'{"controller": "pd"}\'')
    parser.add_argument("--ppo", default="{}", help='JSON object of stable-baselines3 PPO options, e.g. \'{"n_steps": 1024, '
                        '"batch_size": 256}\' (n_steps default 2048)')
    parser.add_argument("--net-arch", type=integer(1, MAX_HIDDEN), nargs="+", default=list(TrainConfig.net_arch),
                        help=f"hidden layer sizes (units, each in [1, {MAX_HIDDEN}]) of the actor and the critic")
    parser.add_argument("--log-std-init", type=number(*LOG_STD_RANGE), default=TrainConfig.log_std_init,
                        help=f"initial log std of the actor's Gaussian, in {list(LOG_STD_RANGE)} (natural log of normalized "
                        "action units; e.g. -1 for residual policies over a working controller)")
    bar = parser.add_mutually_exclusive_group()
    bar.add_argument("--progress", action="store_true", help="draw the progress bar on stderr even when it is not a terminal")
    bar.add_argument("--no-progress", action="store_true", help="no progress bar (there is none anyway when stderr is not a terminal)")
    parser.add_argument("--resume", type=existing_file(".zip"), default=None,
                        help="continue from a checkpoint .zip of the same run (to --timesteps in all; with the run's "
                        "seed and options it continues exactly as the uninterrupted run: see giwbc.apps.training)")
    parser.add_argument("--warm-start", type=existing_file(".zip", ".onnx"), default=None,
                        help="begin from another run's checkpoint .zip, or a policy .onnx, whose environment may differ (e.g. "
                        "fewer residual blocks): weights matched by observation and action names, new ones zero (see giwbc.apps.warm_start)")
    parser.add_argument("--new-action-mean", type=_name_value, action="append", default=[], metavar="NAME=VALUE",
                        help="with --warm-start: start a new action's mean at VALUE in [-1, 1] (normalized) instead of 0 (repeatable)")
    parser.add_argument("--critic-warmup", type=integer(0, MAX_TIMESTEPS), default=0,
                        help="environment steps whose updates train the critic alone, the actor frozen (for --warm-start "
                        "from a policy .onnx, which has no critic) (default: %(default)s)")
    add_ray_argument(parser)
    parser.add_argument("--envs-per-worker", type=integer(1, MAX_ENVS), default=TrainConfig.envs_per_worker,
                        help="with --ray: environments per Ray actor (default: one per actor, or as few as the cluster's CPUs allow)")
    parser.set_defaults(run=run_train_command)


def run_train_command(args: Any) -> int:
    """``giwbc train``: every error is one line (a :class:`ConfigError`) before anything is written."""
    out = args.out or f"runs/{args.env.split('/')[-1]}"
    if args.envs_per_worker is not None and not args.ray:
        raise ConfigError("--envs-per-worker sets how many environments each Ray actor steps: give --ray too")
    config = TrainConfig(env_id=args.env, total_timesteps=args.timesteps, n_envs=args.n_envs, seed=args.seed, out_dir=out,
                         checkpoint_every=args.checkpoint_every, vectorization="ray" if args.ray else args.vectorization,
                         ray_address=args.ray, envs_per_worker=args.envs_per_worker,
                         env_kwargs=json_object(args.env_kwargs, "--env-kwargs"), ppo=json_object(args.ppo, "--ppo"),
                         progress_bar=args.progress or wants_progress(args), net_arch=tuple(args.net_arch),
                         log_std_init=args.log_std_init, resume=args.resume, warm_start=args.warm_start,
                         critic_warmup=args.critic_warmup, new_action_means=dict(args.new_action_mean), overwrite=args.overwrite)
    result = train(config)
    print(f"policy: {result.policy}")
    if result.evaluation is not None:
        returns = result.evaluation.returns
        print(f"evaluation over {len(returns)} episodes: mean return {np.mean(returns):.2f} (min {min(returns):.2f})")
    return 0
