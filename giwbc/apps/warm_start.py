"""Warm start: a new PPO run begins from another run's checkpoint whose layout differs, matched by
the observation and action *names* of the two environments.

The use: a policy with more residual blocks (``G1Walk-v0`` with ``step`` and ``orientation``)
starting from a trained one with fewer (``step`` alone), instead of from scratch. Each weight
reading an observation the source also had, and each output of an action the source also had,
is the source's; a new observation's input weights and a new action's output weights are zero, so
the warm-started actor's mean action *is* the source's on the shared actions and zero on the new
ones (for a residual policy: exactly the source policy at the first step), and the critic's value
is the source's (``new_action_means`` can start a new action's mean elsewhere: a value known to
help, for the run to improve on). A new action's exploration starts at ``log_std_init``; the observation
normalizer keeps the source's statistics for the shared entries and starts the new ones at
mean 0, variance 1. The optimizer starts afresh (the source's Adam state is for other shapes).

The source is a run's checkpoint (``step_N.zip`` with its ``.onnx`` and ``.vecnormalize.pkl``
beside it) or a policy file alone (``policy.onnx``, e.g. a shipped one: fine-tuning it). A policy
file holds the actor and the observation normalizer, not the critic nor the actor's exploration:
the critic then starts as PPO initializes it (``TrainConfig.critic_warmup`` lets it learn the
source's values, the actor frozen, before the actor moves), every action's log std is
``log_std_init``, and the normalizer's statistics count as the source's training steps.

The hidden layers must have the source's sizes and activation. Needs the ``train`` extra.
"""

from __future__ import annotations

import math
import pickle
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.errors import ConfigError, MissingFileError
from giwbc.policy import ACTIVATIONS, OnnxPolicy

if TYPE_CHECKING:
    from stable_baselines3 import PPO

# SB3 MlpPolicy parameters that read the observation, and those that produce the action.
_INPUT_LAYERS = ("mlp_extractor.policy_net.0.weight", "mlp_extractor.value_net.0.weight")
_OUTPUT_LAYERS = ("action_net.weight", "action_net.bias")


@dataclass(frozen=True)
class WarmStart:
    """What a warm start took from its source: the names shared and the names new to the run."""

    source: Path
    shared_observations: int
    new_observations: tuple[str, ...]
    shared_actions: int
    new_actions: tuple[str, ...]
    dropped_observations: tuple[str, ...]
    dropped_actions: tuple[str, ...]
    critic: bool = True  # the source's critic was taken (False: a policy file, PPO's fresh critic)

    def summary(self) -> str:
        return (f"warm start from {self.source}: {self.shared_observations} observations and {self.shared_actions} actions shared"
                + ("" if self.critic else " (a policy file: the critic starts afresh)") + "; "
                f"new: observations {list(self.new_observations)}, actions {list(self.new_actions)}"
                + (f"; the source's {list(self.dropped_observations + self.dropped_actions)} are not used" if self.dropped_observations
                   or self.dropped_actions else ""))


def name_map(source: list[str] | tuple[str, ...], target: list[str] | tuple[str, ...]) -> np.ndarray:
    """For each ``target`` name, its index among ``source`` (-1: new). Names must be unique."""
    for names, which in ((source, "source"), (target, "target")):
        if len(set(names)) != len(names):
            raise ConfigError(f"the {which} names are not unique")
    index = {name: i for i, name in enumerate(source)}
    return np.array([index.get(name, -1) for name in target], dtype=np.int64)


def onnx_actor(path: str | Path, activation: str) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, float, dict[str, Any]]:
    """A giwbc policy file's actor as SB3 ``MlpPolicy`` parameters (``mlp_extractor.policy_net.*``,
    ``action_net.*``), its normalizer's mean and variance (None without one), the source's training
    steps (0 if not recorded) and its metadata. ``ConfigError`` unless it is an MLP with ``activation``."""
    import onnx
    from onnx import numpy_helper

    policy = OnnxPolicy(path)
    graph = onnx.load(str(path)).graph
    values = {tensor.name: numpy_helper.to_array(tensor).astype(np.float64) for tensor in graph.initializer}
    kinds = {node.op_type for node in graph.node} & set(ACTIVATIONS.values())
    if kinds != {ACTIVATIONS.get(activation)}:
        raise ConfigError(f"{path}: its activation is {sorted(kinds)}, this run's {activation!r}")
    layers = sum(1 for name in values if name.startswith("W"))
    if layers < 2 or any(f"W{i}" not in values or f"b{i}" not in values for i in range(layers)):
        raise ConfigError(f"{path}: not a giwbc MLP policy graph (layers W0..W{layers - 1})")
    actor = {}
    for i in range(layers - 1):  # SB3's policy_net: Linear, activation, Linear, ... (index 2 i)
        actor[f"mlp_extractor.policy_net.{2 * i}.weight"], actor[f"mlp_extractor.policy_net.{2 * i}.bias"] = values[f"W{i}"], values[f"b{i}"]
    actor["action_net.weight"], actor["action_net.bias"] = values[f"W{layers - 1}"], values[f"b{layers - 1}"]
    mean = values.get("obs_mean")
    var = None if mean is None else 1.0 / values["obs_inv_std"] ** 2 - 1e-8  # (the exported epsilon)
    steps = int((policy.metadata.get("training") or {}).get("timesteps", 0))
    return actor, mean, var, steps, policy.metadata


def source_files(checkpoint: str | Path) -> tuple[Path, Path, Path]:
    """The checkpoint ``.zip`` and the ``.onnx`` (its names) and ``.vecnormalize.pkl`` beside it."""
    checkpoint = Path(checkpoint)
    onnx, normalizer = checkpoint.with_suffix(".onnx"), checkpoint.with_suffix(".vecnormalize.pkl")
    for path in (checkpoint, onnx):
        if not path.is_file():
            raise MissingFileError(f"warm start needs {path} (a run's checkpoint: .zip with its .onnx beside it)")
    return checkpoint, onnx, normalizer


def check_source(source: str | Path, observation_names: list[str], action_names: list[str], net_arch: tuple[int, ...],
                 activation: str, normalize: bool) -> None:
    """Refuse, before any work, a warm-start source that :func:`warm_start` could not use: a missing,
    empty or corrupted file, a checkpoint without its .onnx (or normalizer, for a normalized run),
    other hidden layers or activation, or no observation or no action shared with this run."""
    source = Path(source)
    if not source.is_file():
        raise MissingFileError(f"--warm-start: no such file {source}")
    if source.suffix not in (".zip", ".onnx"):
        raise ConfigError(f"--warm-start: {source} is neither a run's checkpoint .zip nor a policy .onnx")
    policy = source
    if source.suffix == ".zip":
        _, policy, normalizer = source_files(source)
        try:
            with zipfile.ZipFile(source) as archive:
                is_checkpoint = {"data", "policy.pth"} <= set(archive.namelist()) and archive.testzip() is None  # (CRCs)
        except (zipfile.BadZipFile, zlib.error, OSError):
            is_checkpoint = False
        if not is_checkpoint:
            raise ConfigError(f"--warm-start: {source} is not an intact checkpoint written by giwbc train (a step_N.zip)")
        if normalize and not normalizer.is_file():
            raise MissingFileError(f"--warm-start: a normalized run needs the source's normalizer {normalizer}")
        if normalize:
            try:
                with normalizer.open("rb") as file:
                    pickle.load(file)
            except Exception:  # a truncated or foreign pickle raises any of a dozen types
                raise ConfigError(f"--warm-start: the source's normalizer {normalizer} is corrupted") from None
    actor, _, _, _, metadata = onnx_actor(policy, activation)
    hidden = tuple(int(actor[f"mlp_extractor.policy_net.{2 * i}.weight"].shape[0]) for i in range(len(actor) // 2 - 1))
    if hidden != tuple(net_arch):
        raise ConfigError(f"--warm-start: {source} has hidden layers {list(hidden)}, this run {list(net_arch)} (give --net-arch "
                          f"{' '.join(map(str, hidden))})")
    shared_obs = set(metadata.get("observation_names", ())) & set(observation_names)
    shared_act = set(metadata.get("action_names", ())) & set(action_names)
    if not shared_obs or not shared_act:
        raise ConfigError(f"--warm-start: {source} ({metadata.get('env_id')}) shares no {'observation' if not shared_obs else 'action'} "
                          "with this run's environment")


def warm_start(model: "PPO", venv: Any, checkpoint: str | Path, observation_names: list[str], action_names: list[str],
               log_std_init: float, activation: str = "tanh", new_action_means: dict[str, float] | None = None) -> WarmStart:
    """Overwrite ``model``'s actor-critic (and ``venv``'s normalizer, a ``VecNormalize``) from the
    checkpoint, matching names (module docstring). ``ConfigError`` when nothing is shared or
    the hidden layers differ."""
    import torch
    from stable_baselines3 import PPO

    policy_file = Path(checkpoint).suffix == ".onnx"
    if policy_file:
        actor, mean, var, steps, metadata = onnx_actor(checkpoint, activation)
        source = {key: torch.as_tensor(value, dtype=torch.float32) for key, value in actor.items()}
    else:
        checkpoint, onnx, normalizer = source_files(checkpoint)
        metadata = OnnxPolicy(onnx).metadata
        source = PPO.load(checkpoint, device="cpu").policy.state_dict()
    source_obs, source_act = list(metadata["observation_names"]), list(metadata["action_names"])
    obs_map, act_map = name_map(source_obs, observation_names), name_map(source_act, action_names)
    if not (obs_map >= 0).any() or not (act_map >= 0).any():
        raise ConfigError(f"{checkpoint}: its policy shares no observation or no action with this run's environment")
    target = model.policy.state_dict()
    if set(source) - set(target) or (not policy_file and set(source) != set(target)):
        raise ConfigError(f"{checkpoint}: another policy architecture ({sorted(set(source) ^ set(target))})")
    obs_shared, act_shared = np.flatnonzero(obs_map >= 0), np.flatnonzero(act_map >= 0)
    new: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        for key, value in target.items():
            if key not in source:  # a policy file's missing critic and log std: this run's own
                new[key] = value.clone()
                continue
            old = source[key]
            if key in _INPUT_LAYERS:  # (hidden, obs): columns by observation name, new ones zero
                if old.shape[0] != value.shape[0]:
                    raise ConfigError(f"{checkpoint}: hidden layer {key} has {old.shape[0]} units, this run {value.shape[0]}")
                layer = torch.zeros_like(value)
                layer[:, obs_shared] = old[:, obs_map[obs_shared]]
                new[key] = layer
            elif key in _OUTPUT_LAYERS:  # (actions, ...) rows by action name, new ones zero
                layer = torch.zeros_like(value)
                layer[act_shared] = old[act_map[act_shared]]
                new[key] = layer
            elif key == "log_std":  # (only a checkpoint has one: a policy file's run keeps log_std_init everywhere)
                layer = torch.full_like(value, float(log_std_init))
                layer[act_shared] = old[act_map[act_shared]]
                new[key] = layer
            elif old.shape != value.shape:
                raise ConfigError(f"{checkpoint}: {key} has shape {tuple(old.shape)}, this run {tuple(value.shape)}")
            else:
                new[key] = old.clone()
    for name, value in (new_action_means or {}).items():  # a new action's mean other than zero (its output's bias)
        if name not in action_names or act_map[action_names.index(name)] >= 0 or not (math.isfinite(value) and -1.0 <= value <= 1.0):
            raise ConfigError(f"new_action_means: {name!r} must be one of the actions new to this run "
                              f"({[n for n, i in zip(action_names, act_map) if i < 0]}) with a mean in [-1, 1], got {value}")
        new["action_net.bias"][action_names.index(name)] = float(value)
    model.policy.load_state_dict(new)
    if policy_file:
        _set_normalizer(venv, mean, var, max(steps, 1), obs_map)
    else:
        _warm_normalizer(venv, normalizer, obs_map)
    return WarmStart(
        Path(checkpoint), len(obs_shared), tuple(n for n, i in zip(observation_names, obs_map) if i < 0), len(act_shared),
        tuple(n for n, i in zip(action_names, act_map) if i < 0),
        tuple(sorted(set(source_obs) - set(observation_names))), tuple(sorted(set(source_act) - set(action_names))),
        critic=not policy_file,
    )


def _set_normalizer(venv: Any, mean: np.ndarray | None, var: np.ndarray | None, count: float, obs_map: np.ndarray) -> None:
    """The source's observation statistics (a checkpoint's or a policy file's) for the shared
    entries, mean 0 and variance 1 for the new ones, counted as ``count`` samples."""
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(venv, VecNormalize) or not venv.norm_obs:
        return
    if mean is None or var is None:
        raise ConfigError("the policy file normalizes no observation, this run does: train with normalize_observations off")
    shared = obs_map >= 0
    venv.obs_rms.mean = np.where(shared, mean[np.maximum(obs_map, 0)], 0.0)
    venv.obs_rms.var = np.where(shared, var[np.maximum(obs_map, 0)], 1.0)
    venv.obs_rms.count = count


def _warm_normalizer(venv: Any, path: Path, obs_map: np.ndarray) -> None:
    """The source's observation statistics for the shared entries (mean 0, variance 1 for the new
    ones, with the source's count) and its return statistics, when both runs normalize."""
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(venv, VecNormalize):
        return
    if not path.is_file():
        raise FileNotFoundError(f"warm start into a normalized run needs the source's normalizer {path}")
    with path.open("rb") as file:
        source = pickle.load(file)  # (a VecNormalize without its environments)
    if venv.norm_obs and source.norm_obs:
        _set_normalizer(venv, np.asarray(source.obs_rms.mean), np.asarray(source.obs_rms.var), source.obs_rms.count, obs_map)
    if venv.norm_reward and source.norm_reward:
        venv.ret_rms = source.ret_rms
