"""Warm start: a new PPO run begins from another run's checkpoint whose layout differs, matched by
the observation and action *names* of the two environments.

The use: a policy with more residual blocks (``G1Walk-v0`` with ``step`` and ``orientation``)
starting from a trained one with fewer (``step`` alone), instead of from scratch. Each weight
reading an observation the source also had, and each output of an action the source also had,
is the source's; a new observation's input weights and a new action's output weights are zero, so
the warm-started actor's mean action *is* the source's on the shared actions and zero on the new
ones (for a residual policy: exactly the source policy at the first step), and the critic's value
is the source's. A new action's exploration starts at ``log_std_init``; the observation
normalizer keeps the source's statistics for the shared entries and starts the new ones at
mean 0, variance 1. The optimizer starts afresh (the source's Adam state is for other shapes).

The hidden layers must have the source's sizes and activation. Needs the ``train`` extra.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.errors import ConfigError
from giwbc.policy import OnnxPolicy

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

    def summary(self) -> str:
        return (f"warm start from {self.source}: {self.shared_observations} observations and {self.shared_actions} actions shared; "
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


def source_files(checkpoint: str | Path) -> tuple[Path, Path, Path]:
    """The checkpoint ``.zip`` and the ``.onnx`` (its names) and ``.vecnormalize.pkl`` beside it."""
    checkpoint = Path(checkpoint)
    onnx, normalizer = checkpoint.with_suffix(".onnx"), checkpoint.with_suffix(".vecnormalize.pkl")
    for path in (checkpoint, onnx):
        if not path.is_file():
            raise FileNotFoundError(f"warm start needs {path} (a run's checkpoint: .zip with its .onnx beside it)")
    return checkpoint, onnx, normalizer


def warm_start(model: "PPO", venv: Any, checkpoint: str | Path, observation_names: list[str], action_names: list[str],
               log_std_init: float) -> WarmStart:
    """Overwrite ``model``'s actor-critic (and ``venv``'s normalizer, a ``VecNormalize``) from the
    checkpoint, matching names (module docstring). ``ConfigError`` when nothing is shared or
    the hidden layers differ."""
    import torch
    from stable_baselines3 import PPO

    checkpoint, onnx, normalizer = source_files(checkpoint)
    metadata = OnnxPolicy(onnx).metadata
    source_obs, source_act = list(metadata["observation_names"]), list(metadata["action_names"])
    obs_map, act_map = name_map(source_obs, observation_names), name_map(source_act, action_names)
    if not (obs_map >= 0).any() or not (act_map >= 0).any():
        raise ConfigError(f"{checkpoint}: its policy shares no observation or no action with this run's environment")
    source = PPO.load(checkpoint, device="cpu").policy.state_dict()
    target = model.policy.state_dict()
    if set(source) != set(target):
        raise ConfigError(f"{checkpoint}: another policy architecture ({sorted(set(source) ^ set(target))})")
    obs_shared, act_shared = np.flatnonzero(obs_map >= 0), np.flatnonzero(act_map >= 0)
    new: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        for key, value in target.items():
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
            elif key == "log_std":
                layer = torch.full_like(value, float(log_std_init))
                layer[act_shared] = old[act_map[act_shared]]
                new[key] = layer
            elif old.shape != value.shape:
                raise ConfigError(f"{checkpoint}: {key} has shape {tuple(old.shape)}, this run {tuple(value.shape)}")
            else:
                new[key] = old.clone()
    model.policy.load_state_dict(new)
    _warm_normalizer(venv, normalizer, obs_map)
    return WarmStart(
        checkpoint, len(obs_shared), tuple(n for n, i in zip(observation_names, obs_map) if i < 0), len(act_shared),
        tuple(n for n, i in zip(action_names, act_map) if i < 0),
        tuple(sorted(set(source_obs) - set(observation_names))), tuple(sorted(set(source_act) - set(action_names))),
    )


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
    shared = obs_map >= 0
    if venv.norm_obs and source.norm_obs:
        rms = venv.obs_rms
        rms.mean = np.where(shared, np.asarray(source.obs_rms.mean)[np.maximum(obs_map, 0)], 0.0)
        rms.var = np.where(shared, np.asarray(source.obs_rms.var)[np.maximum(obs_map, 0)], 1.0)
        rms.count = source.obs_rms.count
    if venv.norm_reward and source.norm_reward:
        venv.ret_rms = source.ret_rms
