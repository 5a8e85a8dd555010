"""Randomization configs: a list of entries, each a parameter, a distribution, an operation and targets.

As a dict (or the same in TOML, under an optional ``[randomization]`` table)::

    {
        "physics_every": 1,        # episodes between physics resamples (Gym-Ignition: every N rollouts)
        "push_horizon": 60.0,      # seconds of push schedule drawn per episode
        "imu_profile": "mems",     # optional: the IMU's turn-on errors drawn per episode (imu_profiles.py)
        "parameters": [
            {"parameter": "link_mass", "distribution": "uniform", "low": 0.9, "high": 1.1,
             "operation": "scale", "regex": ".*_(hip|knee)_.*"},
            {"parameter": "ground_friction", "distribution": "uniform", "low": 0.4, "high": 1.2,
             "operation": "absolute"},
            {"parameter": "link_com", "distribution": "gaussian", "mean": 0.0, "std": [0.01, 0.01, 0.0],
             "operation": "add", "links": ["pelvis", "torso_link"]},
        ],
    }

Operations: ``absolute`` (value = draw), ``scale`` (value = nominal * draw), ``add`` (value =
nominal + draw); entries apply in order, a later one seeing the earlier ones' result. Targets:
``links`` / ``joints`` (names) and/or ``regex`` (``re.fullmatch`` on names); none means all. One
draw per target, or one for all with ``shared = true``. Results are clipped to the parameter's
physical range (a gaussian mass stays positive). Pushes: ``push_interval``, ``push_force`` and
``push_duration`` entries (``absolute`` only) are drawn per push; ``push_force`` takes ``link``.
"""

from __future__ import annotations

import difflib
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.randomization.distributions import KINDS, Distribution, RandomizationError
from giwbc.randomization.imu_profiles import imu_profile_entries
from giwbc.randomization.parameters import PARAMETERS, PUSH_PARAMETERS, Nominal
from giwbc.robot.description import RobotDescription
from giwbc.util.toml import load_toml, parse_toml

_TOP_KEYS = {"physics_every", "push_horizon", "parameters", "imu_profile"}
_ENTRY_KEYS = {"parameter", "distribution", "operation", "links", "joints", "regex", "shared", "link", "name"}


@dataclass(frozen=True)
class Entry:
    """One validated config entry, its targets resolved to indices into the nominal arrays."""

    parameter: str
    distribution: Distribution
    operation: str
    targets: np.ndarray  # indices into Nominal.links / Nominal.joints; empty for a global parameter
    shared: bool
    where: str
    link: str | None = None  # push_force only

    def apply(self, values: np.ndarray, rng: np.random.Generator) -> None:
        """Draw and apply this entry to ``values`` (the parameter's full array), in place."""
        spec = PARAMETERS[self.parameter]
        scoped = spec.scope != "global"
        count = 1 if self.shared or not scoped else len(self.targets)
        draw = self.distribution.sample(rng, (count, spec.size))
        view = values.reshape(-1, spec.size)  # rows: targets (or the one global row)
        rows = self.targets if scoped else np.zeros(1, dtype=int)
        current = view[rows]
        if self.operation == "absolute":
            result = np.broadcast_to(draw, current.shape)
        elif self.operation == "scale":
            result = current * draw
        else:
            result = current + draw
        view[rows] = spec.clip(result)


@dataclass(frozen=True)
class RandomizationConfig:
    """A validated list of entries for one robot description."""

    entries: tuple[Entry, ...]
    nominal: Nominal
    physics_every: int = 1
    push_horizon: float = 60.0

    @classmethod
    def from_dict(cls, config: dict[str, Any], description: RobotDescription) -> "RandomizationConfig":
        if not isinstance(config, dict):
            raise RandomizationError(f"a randomization config is a dict, got {type(config).__name__}")
        config = config.get("randomization", config)
        unknown = set(config) - _TOP_KEYS
        if unknown:
            raise RandomizationError(f"randomization config: unknown keys {sorted(unknown)}; expected {sorted(_TOP_KEYS)}")
        every = config.get("physics_every", 1)
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise RandomizationError(f"randomization config: 'physics_every' must be an integer >= 1, got {every!r}")
        horizon = config.get("push_horizon", 60.0)
        if isinstance(horizon, bool) or not isinstance(horizon, (int, float)) or not 0 < horizon < math.inf:
            raise RandomizationError(f"randomization config: 'push_horizon' must be a positive number of seconds, got {horizon!r}")
        raw = config.get("parameters", [])
        if not isinstance(raw, list):
            raise RandomizationError("randomization config: 'parameters' must be a list of entries")
        if "imu_profile" in config:
            raw = imu_profile_entries(str(config["imu_profile"])) + raw
        nominal = Nominal.from_description(description)
        entries = tuple(_parse_entry(table, index, nominal) for index, table in enumerate(raw))
        given = {e.parameter for e in entries}
        if given & set(PUSH_PARAMETERS) and not {"push_force", "push_interval"} <= given:
            raise RandomizationError("randomization config: pushes need both a 'push_force' and a 'push_interval' entry")
        return cls(entries, nominal, every, float(horizon))

    @classmethod
    def from_toml(cls, source: str | os.PathLike[str], description: RobotDescription) -> "RandomizationConfig":
        """From a TOML file path, or TOML text (anything containing a newline or '=')."""
        text = str(source)
        if isinstance(source, Path) or ("\n" not in text and "=" not in text):
            return cls.from_dict(load_toml(Path(source), RandomizationError), description)
        return cls.from_dict(parse_toml(text, "randomization config", RandomizationError), description)

    @property
    def parameters(self) -> frozenset[str]:
        return frozenset(e.parameter for e in self.entries)

    def group(self, group: str) -> tuple[Entry, ...]:
        return tuple(e for e in self.entries if PARAMETERS[e.parameter].group == group)


def _parse_entry(table: Any, index: int, nominal: Nominal) -> Entry:
    if not isinstance(table, dict):
        raise RandomizationError(f"randomization entry #{index}: must be a table, got {table!r}")
    parameter = table.get("parameter")
    label = table.get("name", parameter)
    where = f"randomization entry #{index} ({label})"
    if parameter not in PARAMETERS:
        hint = difflib.get_close_matches(str(parameter), PARAMETERS, n=1)
        raise RandomizationError(
            f"{where}: unknown parameter {parameter!r}"
            + (f" (did you mean {hint[0]!r}?)" if hint else "")
            + f"; known: {', '.join(PARAMETERS)}"
        )
    spec = PARAMETERS[parameter]
    allowed = _ENTRY_KEYS | set(KINDS.get(table.get("distribution"), ()))
    unknown = set(table) - allowed
    if unknown:
        raise RandomizationError(f"{where}: unknown keys {sorted(unknown)}")
    distribution = Distribution.from_config(table, where)
    if distribution.components not in (0, spec.size) or (spec.size == 1 and distribution.components):
        raise RandomizationError(
            f"{where}: {parameter} has {spec.size} component(s); give scalar bounds"
            + (f" or lists of {spec.size}" if spec.size > 1 else "")
        )
    operation = table.get("operation")
    if operation not in spec.operations:
        why = " (its nominal value is 0, so 'scale' would change nothing)" if operation == "scale" else ""
        raise RandomizationError(f"{where}: operation must be one of {list(spec.operations)} for {parameter}{why}, got {operation!r}")
    shared = table.get("shared", False)
    if not isinstance(shared, bool):
        raise RandomizationError(f"{where}: 'shared' must be true or false, got {shared!r}")
    targets = _resolve_targets(table, spec.scope, nominal, where)
    link = table.get("link")
    if link is not None:
        if parameter != "push_force":
            raise RandomizationError(f"{where}: 'link' is for push_force entries; use 'links' to target links")
        if link not in nominal.links:
            raise RandomizationError(f"{where}: unknown link {link!r}{_suggest(link, nominal.links)}")
    elif parameter == "push_force":
        link = nominal.base_link
    return Entry(parameter, distribution, operation, targets, shared, where, link)


def _resolve_targets(table: dict[str, Any], scope: str, nominal: Nominal, where: str) -> np.ndarray:
    names = nominal.targets(scope)
    key = {"link": "links", "joint": "joints"}.get(scope)
    wrong = [k for k in ("links", "joints", "regex") if k in table and (scope == "global" or k not in (key, "regex"))]
    if wrong:
        target = "no targets" if scope == "global" else f"{key} (or a regex)"
        raise RandomizationError(f"{where}: {wrong[0]!r} does not apply: this parameter takes {target}")
    if scope == "global":
        return np.zeros(0, dtype=int)
    chosen: set[int] = set()
    listed = table.get(key)
    if listed is not None:
        if isinstance(listed, str) or not isinstance(listed, list):
            raise RandomizationError(f"{where}: {key!r} must be a list of names, got {listed!r}")
        for name in listed:
            if name not in names:
                raise RandomizationError(f"{where}: unknown {scope} {name!r}{_suggest(name, names)}")
            chosen.add(names.index(name))
    pattern = table.get("regex")
    if pattern is not None:
        try:
            compiled = re.compile(pattern)
        except (re.error, TypeError) as error:
            raise RandomizationError(f"{where}: invalid regex {pattern!r}: {error}") from None
        matched = {i for i, name in enumerate(names) if compiled.fullmatch(name)}
        if not matched:
            raise RandomizationError(f"{where}: regex {pattern!r} matches no {scope} name")
        chosen |= matched
    if listed is None and pattern is None:
        chosen = set(range(len(names)))
    return np.array(sorted(chosen), dtype=int)


def _suggest(name: str, names: tuple[str, ...]) -> str:
    hint = difflib.get_close_matches(str(name), names, n=1)
    return f" (did you mean {hint[0]!r}?)" if hint else ""
