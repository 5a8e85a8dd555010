"""Policies as ONNX files that carry everything a deployment needs; running them needs only onnxruntime.

An exported policy is one graph, ``observation (N, obs) float32 -> action (N, act) float32``,
holding the observation normalization, the MLP and the clip to the action space, plus metadata
(``metadata_props``, one JSON value per key): the environment id and options it was trained on,
joint names and order, action names and scales, observation layout, agent/controller/physics
rates, gains and default pose. :meth:`OnnxPolicy.make_env` rebuilds the environment from that
metadata (``giwbc play``, :mod:`giwbc.apps.play`, runs it). Nothing here imports torch.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids: a policy names the env it was trained on)
from giwbc.errors import PolicyFormatError

FORMAT = "giwbc-policy/1"
INPUT_NAME = "observation"
OUTPUT_NAME = "action"
REQUIRED_METADATA = (
    "format", "env_id", "env_kwargs", "observation_names", "action_names", "action_scale", "joint_names", "rates",
)
ACTIVATIONS = {"tanh": "Tanh", "relu": "Relu", "elu": "Elu"}


@dataclass(frozen=True)
class MlpWeights:
    """A multilayer perceptron: ``(weight (out, in), bias (out,))`` per layer, the activation between layers."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    activation: str = "tanh"

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Reference forward pass in numpy (what the ONNX graph computes)."""
        functions = {"tanh": np.tanh, "relu": lambda y: np.maximum(y, 0.0), "elu": lambda y: np.where(y > 0, y, np.expm1(y))}
        for index, (weight, bias) in enumerate(self.layers):
            x = x @ weight.T + bias
            if index < len(self.layers) - 1:
                x = functions[self.activation](x)
        return x


@dataclass(frozen=True)
class ObservationNormalization:
    """``clip((obs - mean) / sqrt(var + epsilon), -clip, clip)``, as running-mean normalizers apply it."""

    mean: np.ndarray
    var: np.ndarray
    epsilon: float = 1e-8
    clip: float = 10.0

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        return np.clip((observation - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip, self.clip)


def export_onnx(
    path: str | os.PathLike[str],
    mlp: MlpWeights,
    metadata: dict[str, Any],
    *,
    normalization: ObservationNormalization | None = None,
    action_low: np.ndarray | None = None,
    action_high: np.ndarray | None = None,
) -> Path:
    """Write the policy graph and its metadata (needs the ``onnx`` package, not torch)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    metadata = {"format": FORMAT, **metadata}
    missing = [key for key in REQUIRED_METADATA if key not in metadata]
    if missing:
        raise PolicyFormatError(f"policy metadata lacks {missing}")
    if mlp.activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {mlp.activation!r}")
    n_obs = mlp.layers[0][0].shape[1]
    n_act = mlp.layers[-1][0].shape[0]
    if len(metadata["observation_names"]) != n_obs or len(metadata["action_names"]) != n_act:
        raise PolicyFormatError(
            f"the network maps {n_obs} -> {n_act} but the metadata names {len(metadata['observation_names'])} "
            f"observations and {len(metadata['action_names'])} actions"
        )

    nodes, initializers = [], []

    def constant(name: str, value: np.ndarray) -> str:
        initializers.append(numpy_helper.from_array(np.asarray(value, dtype=np.float32), name))
        return name

    x = INPUT_NAME
    if normalization is not None:
        nodes.append(helper.make_node("Sub", [x, constant("obs_mean", normalization.mean)], ["obs_centered"]))
        scale = 1.0 / np.sqrt(np.asarray(normalization.var, dtype=np.float64) + normalization.epsilon)
        nodes.append(helper.make_node("Mul", ["obs_centered", constant("obs_inv_std", scale)], ["obs_scaled"]))
        nodes.append(helper.make_node(
            "Clip", ["obs_scaled", constant("obs_clip_low", -normalization.clip), constant("obs_clip_high", normalization.clip)], ["obs_normalized"]
        ))
        x = "obs_normalized"
    for index, (weight, bias) in enumerate(mlp.layers):
        out = f"layer{index}"
        nodes.append(helper.make_node("Gemm", [x, constant(f"W{index}", weight), constant(f"b{index}", bias)], [out], transB=1))
        x = out
        if index < len(mlp.layers) - 1:
            nodes.append(helper.make_node(ACTIVATIONS[mlp.activation], [x], [f"{out}_act"]))
            x = f"{out}_act"
    if action_low is not None and action_high is not None:
        nodes.append(helper.make_node("Max", [x, constant("action_low", action_low)], ["action_above_low"]))
        nodes.append(helper.make_node("Min", ["action_above_low", constant("action_high", action_high)], [OUTPUT_NAME]))
    else:
        nodes.append(helper.make_node("Identity", [x], [OUTPUT_NAME]))
    graph = helper.make_graph(
        nodes,
        "giwbc_policy",
        [helper.make_tensor_value_info(INPUT_NAME, TensorProto.FLOAT, ["batch", n_obs])],
        [helper.make_tensor_value_info(OUTPUT_NAME, TensorProto.FLOAT, ["batch", n_act])],
        initializers,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="giwbc")
    model.ir_version = 8  # readable by onnxruntime >= 1.10 on the robot
    helper.set_model_props(model, {key: json.dumps(value) for key, value in metadata.items()})
    onnx.checker.check_model(model)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path


class OnnxPolicy:
    """A giwbc policy file run by onnxruntime: ``policy(observation) -> action``, plus its metadata."""

    def __init__(self, path: str | os.PathLike[str], threads: int = 1) -> None:
        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"no policy file at {self.path}")
        try:
            self.session = onnxruntime.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as error:  # onnxruntime raises its own Fail/InvalidGraph types
            raise PolicyFormatError(f"{self.path}: onnxruntime cannot load it: {error}") from error
        props = self.session.get_modelmeta().custom_metadata_map
        try:
            self.metadata: dict[str, Any] = {key: json.loads(value) for key, value in props.items()}
        except json.JSONDecodeError as error:
            raise PolicyFormatError(f"{self.path}: metadata is not JSON: {error}") from error
        missing = [key for key in REQUIRED_METADATA if key not in self.metadata]
        if missing or self.metadata.get("format") != FORMAT:
            raise PolicyFormatError(f"{self.path} is not a {FORMAT} policy (missing metadata {missing})")
        (self._input,) = self.session.get_inputs()
        self.observation_size = len(self.metadata["observation_names"])
        self.action_size = len(self.metadata["action_names"])

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """The action for one observation ``(obs,)`` or a batch ``(N, obs)``."""
        observation = np.asarray(observation, dtype=np.float32)
        single = observation.ndim == 1
        batch = observation[None] if single else observation
        if batch.shape[-1] != self.observation_size:
            raise ValueError(f"policy expects {self.observation_size} observation entries, got {batch.shape[-1]}")
        (action,) = self.session.run([OUTPUT_NAME], {self._input.name: batch})
        return action[0] if single else action

    @property
    def env_id(self) -> str:
        return self.metadata["env_id"]

    def make_env(self, **overrides: Any) -> Any:
        """The environment the policy was trained on, checked against the policy's layout."""
        import gymnasium


        env = gymnasium.make(self.env_id, **{**self.metadata["env_kwargs"], **overrides})
        check_compatible(self.metadata, env.unwrapped.describe())
        return env


def check_compatible(metadata: dict[str, Any], described: dict[str, Any]) -> None:
    """Raise :class:`PolicyFormatError` unless the environment has the policy's layout, joints and rates."""
    for key in ("observation_names", "action_names", "joint_names", "rates"):
        if metadata.get(key) != described.get(key):
            raise PolicyFormatError(f"the policy's {key} differ from the environment's: {metadata.get(key)} vs {described.get(key)}")
