"""Draw concrete parameter values from a config with the environment's generator.

A sample holds absolute values for every parameter of its group (nominal where no entry
applies), so applying it never depends on what was applied before: re-applying from nominal
cannot accumulate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from giwbc.randomization.config import RandomizationConfig
from giwbc.randomization.parameters import PARAMETERS, PUSH_PARAMETERS


@dataclass(frozen=True)
class Push:
    """A horizontal push: world force on ``link`` from ``start`` for ``duration`` seconds (episode time)."""

    start: float
    duration: float
    force: np.ndarray
    link: str


@dataclass(frozen=True)
class Sample:
    """Values of one group (``physics`` or ``episode``); ``randomized`` names those an entry touched."""

    group: str
    values: dict[str, np.ndarray]
    randomized: frozenset[str]
    pushes: tuple[Push, ...] = ()
    noise_seed: int = 0  # seeds the per-reading sensor noise of the episode

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def scalar(self, name: str) -> float:
        return float(self.values[name].reshape(-1)[0])


def sample_group(config: RandomizationConfig, group: str, rng: np.random.Generator) -> Sample:
    """Apply every entry of ``group`` in order, starting from the nominal values."""
    values = {name: config.nominal.values[name].copy() for name, spec in PARAMETERS.items() if spec.group == group}
    entries = config.group(group)
    for entry in entries:
        if entry.parameter not in PUSH_PARAMETERS:
            entry.apply(values[entry.parameter], rng)
    if "link_mass" in values:
        values["link_mass"][config.nominal.values["link_mass"] == 0] = 0.0  # frames without mass stay massless
    pushes: tuple[Push, ...] = ()
    noise_seed = 0
    if group == "episode":
        pushes = _push_schedule(config, rng)
        noise_seed = int(rng.integers(2**63))
    randomized = frozenset(e.parameter for e in entries)
    return Sample(group, values, randomized, pushes, noise_seed)


def _push_schedule(config: RandomizationConfig, rng: np.random.Generator) -> tuple[Push, ...]:
    """Pushes up to the config's horizon: wait, push, wait, ... each draw from its entry."""
    entries = {e.parameter: e for e in config.entries if e.parameter in PUSH_PARAMETERS}
    if "push_force" not in entries:
        return ()
    nominal = config.nominal.values

    def draw(name: str) -> float:
        spec = PARAMETERS[name]
        if name not in entries:
            return float(nominal[name][0])
        return float(spec.clip(entries[name].distribution.sample(rng, (1,)))[0])

    pushes, time = [], 0.0
    while True:
        time += draw("push_interval")
        if time >= config.push_horizon:
            return tuple(pushes)
        duration, magnitude, angle = draw("push_duration"), draw("push_force"), rng.uniform(0.0, 2.0 * np.pi)
        force = magnitude * np.array([np.cos(angle), np.sin(angle), 0.0])
        pushes.append(Push(time, duration, force, entries["push_force"].link))
        time += duration
