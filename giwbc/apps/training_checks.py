"""What ``giwbc train`` checks before any work starts: the environment, the PPO options, the
``--resume`` checkpoint, the run folder, and how many steps the run will really take.

Every refusal is a :class:`~giwbc.errors.ConfigError` whose message is one line naming the
option at fault, so the command line prints it once and exits 2 with nothing written. Nothing
here trains or loads torch weights: the checks read the checkpoint's JSON and shapes only.
"""

from __future__ import annotations

import inspect
import json
import math
import pickle
import shutil
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from giwbc.errors import ConfigError, GiwbcError, MissingFileError, UnavailableError

# PPO constructor arguments that `giwbc train` sets itself (or cannot export), with what to do instead.
RESERVED_PPO = {
    "policy": "giwbc train always trains an MlpPolicy",
    "env": "set by --env and --env-kwargs",
    "policy_kwargs": "set by --net-arch and --log-std-init",
    "seed": "set by --seed",
    "device": "giwbc train runs on the CPU",
    "verbose": "giwbc train reports progress itself",
    "tensorboard_log": "the learning curve is in progress.csv",
    "rollout_buffer_class": "not a JSON value",
    "rollout_buffer_kwargs": "not a JSON value",
    "use_sde": "the ONNX export needs a diagonal-Gaussian actor",
    "sde_sample_freq": "only with use_sde, which the ONNX export does not support",
    "_init_setup_model": "internal to stable-baselines3",
}


@dataclass(frozen=True)
class Bound:
    """What a PPO value may be: an integer or a finite number in a range (``None``: allowed with ``nullable``)."""

    kind: str  # "int", "float" or "bool"
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    nullable: bool = False

    def describe(self) -> str:
        if self.kind == "bool":
            return "true or false"
        what = "an integer" if self.kind == "int" else "a finite number"
        if self.low is not None and self.high is not None:
            what += f" in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"
        elif self.low is not None:
            what += f" {'>' if self.low_open else '>='} {self.low:g}"
        return what + (" or null" if self.nullable else "")

    def accepts(self, value: Any) -> bool:
        if value is None:
            return self.nullable
        if self.kind == "bool":
            return isinstance(value, bool)
        if isinstance(value, bool) or not isinstance(value, int if self.kind == "int" else (int, float)):
            return False
        if not math.isfinite(value):
            return False
        too_low = self.low is not None and (value <= self.low if self.low_open else value < self.low)
        return not too_low and not (self.high is not None and value > self.high)


PPO_BOUNDS = {
    "learning_rate": Bound("float", 0.0, 1.0, low_open=True),
    "n_steps": Bound("int", 1, 1_000_000),
    "batch_size": Bound("int", 2, 10_000_000),
    "n_epochs": Bound("int", 1, 1000),
    "gamma": Bound("float", 0.0, 1.0, low_open=True),
    "gae_lambda": Bound("float", 0.0, 1.0),
    "clip_range": Bound("float", 0.0, 10.0, low_open=True),
    "clip_range_vf": Bound("float", 0.0, 1e6, low_open=True, nullable=True),
    "normalize_advantage": Bound("bool"),
    "ent_coef": Bound("float", 0.0, 10.0),
    "vf_coef": Bound("float", 0.0, 10.0),
    "max_grad_norm": Bound("float", 0.0, 1e6, low_open=True),
    "target_kl": Bound("float", 0.0, 10.0, low_open=True, nullable=True),
    "stats_window_size": Bound("int", 1, 1_000_000),
}
TRAIN_EXTRA = "giwbc train needs the train extra (torch, stable-baselines3): pip install 'giwbc[train]'"


def json_object(text: str, option: str) -> dict[str, Any]:
    """``text`` as a JSON object whose numbers are finite; ``ConfigError`` naming ``option`` otherwise."""

    def refuse(constant: str) -> Any:
        raise ConfigError(f"{option}: {constant} is not a finite number")

    try:
        value = json.loads(text, parse_constant=refuse)
    except json.JSONDecodeError as error:
        raise ConfigError(f"{option}: not JSON ({error.msg} at column {error.colno}): {text!r}") from None
    if not isinstance(value, dict):
        raise ConfigError(f"{option}: expected a JSON object ({{\"key\": value, ...}}), got {text!r}")
    return value


def ppo_parameters() -> dict[str, inspect.Parameter]:
    """stable-baselines3 PPO's constructor parameters (``UnavailableError`` without the train extra)."""
    try:
        from stable_baselines3 import PPO
    except ImportError:
        raise UnavailableError(TRAIN_EXTRA) from None
    return {name: p for name, p in inspect.signature(PPO.__init__).parameters.items() if name != "self"}


def check_ppo(ppo: dict[str, Any], n_envs: int) -> int:
    """Refuse an unknown, reserved or out-of-range PPO option; the rollout size ``n_envs × n_steps``."""
    parameters = ppo_parameters()
    for key, value in ppo.items():
        if key in RESERVED_PPO:
            raise ConfigError(f"--ppo: {key!r} cannot be set here ({RESERVED_PPO[key]})")
        if key not in parameters:
            known = sorted(set(parameters) - set(RESERVED_PPO))
            raise ConfigError(f"--ppo: {key!r} is not a stable-baselines3 PPO option (known: {', '.join(known)})")
        bound = PPO_BOUNDS.get(key)
        if bound is not None and not bound.accepts(value):
            raise ConfigError(f"--ppo: {key} must be {bound.describe()}, got {json.dumps(value)}")
    n_steps = int(ppo.get("n_steps", parameters["n_steps"].default))
    rollout = n_steps * n_envs
    if rollout < 2:
        raise ConfigError(f"a PPO rollout (n_envs × n_steps = {n_envs} × {n_steps}) must hold at least 2 steps")
    return rollout


def module_id(env_id: str) -> str:
    """``giwbc.envs:giwbc/X``: worker processes register the ids themselves, whatever the start method."""
    return env_id if ":" in env_id or not env_id.startswith("giwbc/") else f"giwbc.envs:{env_id}"


def describe_env(env_id: str, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The environment's deployment description (task layout, joints, rates, gains)."""
    import gymnasium

    env = gymnasium.make(module_id(env_id), **env_kwargs)
    try:
        return env.unwrapped.describe()
    finally:
        env.close()


def check_env(env_id: str, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The description of a registered giwbc environment made with ``env_kwargs``; ``ConfigError``
    for an unknown id, options it does not take, or an environment that cannot describe itself."""
    import gymnasium

    import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)

    name = env_id.split(":", 1)[-1]
    giwbc_ids = sorted(key for key in gymnasium.registry if key.startswith("giwbc/"))
    if name not in gymnasium.registry:
        raise ConfigError(f"--env: unknown environment {env_id!r} (giwbc's: {', '.join(giwbc_ids)})")
    try:
        return describe_env(env_id, env_kwargs)
    except GiwbcError:
        raise
    except AttributeError:
        raise ConfigError(f"--env: {env_id} cannot describe itself for deployment: train a giwbc environment ({', '.join(giwbc_ids)})") from None
    except (TypeError, ValueError, KeyError, gymnasium.error.Error) as error:
        raise ConfigError(f"--env-kwargs: {env_id} refuses {json.dumps(env_kwargs)}: {error}") from None


@dataclass(frozen=True)
class Checkpoint:
    """What a ``--resume`` checkpoint holds, read without loading its weights."""

    path: Path
    num_timesteps: int
    env_id: str | None  # from its run's config.json (None: not found)


def check_checkpoint(path: str | Path, described: dict[str, Any], env_id: str, normalize: bool) -> Checkpoint:
    """A stable-baselines3 checkpoint ``.zip`` of this environment (observation and action sizes,
    and its run's env id when its config.json is found), with its normalizer when the run normalizes."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"--resume: no checkpoint at {path}")
    if path.stat().st_size == 0:
        raise ConfigError(f"--resume: {path} is empty")
    not_checkpoint = f"--resume: {path} is not a checkpoint written by giwbc train (a step_N.zip or policy.zip)"
    try:
        with zipfile.ZipFile(path) as archive:
            if not {"data", "policy.pth"} <= set(archive.namelist()):
                raise ConfigError(not_checkpoint)
            damaged = archive.testzip()  # every member's CRC: a truncated or altered checkpoint
            if damaged is not None:
                raise ConfigError(f"--resume: {path} is corrupted ({damaged} fails its checksum)")
            data = json.loads(archive.read("data"))
        observation, action = data["observation_space"]["_shape"], data["action_space"]["_shape"]
        steps = int(data["num_timesteps"])
    except (zipfile.BadZipFile, zlib.error, json.JSONDecodeError, KeyError, TypeError, ValueError, OSError) as error:
        if isinstance(error, GiwbcError):
            raise
        raise ConfigError(not_checkpoint) from None
    sizes = (len(described["observation_names"]), len(described["action_names"]))
    if (list(observation), list(action)) != ([sizes[0]], [sizes[1]]):
        raise ConfigError(f"--resume: {path} is of another environment ({observation[0] if observation else '?'} observations and "
                          f"{action[0] if action else '?'} actions, {env_id} has {sizes[0]} and {sizes[1]}); "
                          "--warm-start begins a run from another environment's checkpoint")
    run_env = _run_env_id(path)
    if run_env is not None and run_env.split(":", 1)[-1] != env_id.split(":", 1)[-1]:
        raise ConfigError(f"--resume: {path} is a checkpoint of a {run_env} run, not {env_id}; "
                          "--warm-start begins a run from another environment's checkpoint")
    if normalize:
        normalizer = path.with_suffix(".vecnormalize.pkl")
        if not normalizer.is_file():
            raise MissingFileError(f"--resume: its normalizer {normalizer} is missing (saved beside every checkpoint)")
        try:
            with normalizer.open("rb") as file:
                pickle.load(file)
        except Exception:  # a truncated or foreign pickle raises any of a dozen types
            raise ConfigError(f"--resume: its normalizer {normalizer} is corrupted") from None
    return Checkpoint(path, steps, run_env)


def _run_env_id(checkpoint: Path) -> str | None:
    """The env id in the config.json of the checkpoint's run folder (``checkpoints/..`` or beside it)."""
    for folder in (checkpoint.parent.parent, checkpoint.parent) if checkpoint.parent.name == "checkpoints" else (checkpoint.parent,):
        config = folder / "config.json"
        if config.is_file():
            try:
                value = json.loads(config.read_text()).get("env_id")
            except (json.JSONDecodeError, AttributeError, OSError):
                return None
            return value if isinstance(value, str) else None
    return None


# --- the run folder ------------------------------------------------------------------------------
RUN_FILES = ("config.json", "progress.csv", "policy.zip", "policy.vecnormalize.pkl", "policy.onnx")


def run_files(out: Path) -> list[Path]:
    """The files of an earlier run in ``out`` (its configuration, curve, final policy and checkpoints)."""
    files = [out / name for name in RUN_FILES if (out / name).is_file()]
    checkpoints = out / "checkpoints"
    if checkpoints.is_dir():
        files += sorted(p for p in checkpoints.iterdir() if p.name.startswith("step_") and p.is_file())
    return files


def check_out(out: Path, resume: str | None, overwrite: bool) -> list[Path]:
    """The earlier run's files ``out`` holds that this run will replace; ``ConfigError`` when ``out``
    holds a run and this is neither a resume of it nor an ``overwrite`` (nothing of it is lost)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out: {out} is a file, not a run folder")
    files = run_files(out)
    if resume is not None and Path(resume).resolve().is_relative_to(out.resolve()):
        return []  # a resume of the run in out continues it in place (its checkpoint kept)
    if not files or overwrite:
        return files
    latest = latest_checkpoint(out)
    hint = f"--resume {latest} to continue it, " if latest is not None else "(it has no checkpoint to --resume) "
    raise ConfigError(f"--out: {out} already holds a run ({len(files)} files, e.g. {files[0].name}): give {hint}"
                      "another --out, or --overwrite to replace it")


def latest_checkpoint(out: Path) -> Path | None:
    """The checkpoint of the most steps in ``out/checkpoints`` (None: none)."""
    steps = []
    for path in (out / "checkpoints").glob("step_*.zip"):
        try:
            steps.append((int(path.stem.removeprefix("step_")), path))
        except ValueError:
            continue
    return max(steps)[1] if steps else None


def clear_run(files: list[Path]) -> None:
    """Remove an earlier run's files (``--overwrite``), so none of its checkpoints mixes with the new run's."""
    for path in files:
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)


def planned_steps(total: int, start: int, rollout: int) -> int:
    """The steps a run ends at: PPO collects whole rollouts until it reaches ``total`` from ``start``."""
    return start + max(0, math.ceil((total - start) / rollout)) * rollout


def steps_note(total: int, start: int, rollout: int, n_envs: int, resume: str | None) -> str:
    """The one line saying, before training, how many steps the run really takes and why."""
    planned = planned_steps(total, start, rollout)
    n_steps = rollout // n_envs
    if start >= total:
        return f"training 0 steps: {resume} is already at step {start} >= --timesteps {total} (its policy exported as it is)"
    line = (f"training {planned - start} steps: whole rollouts of n_envs × n_steps = {n_envs} × {n_steps} = {rollout}")
    if resume is not None:
        line += f", from step {start} of {resume} to step {planned}"
    if planned != total:
        line += f" (--timesteps {total} rounded up to {planned})"
    return line


__all__ = ["Bound", "Checkpoint", "PPO_BOUNDS", "RESERVED_PPO", "check_checkpoint", "check_env", "check_out", "check_ppo",
           "clear_run", "describe_env", "json_object", "latest_checkpoint", "module_id", "planned_steps", "run_files",
           "steps_note"]
