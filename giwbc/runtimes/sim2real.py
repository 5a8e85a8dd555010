"""Sim-to-real knobs of a simulated runtime: observation noise, action latency, actuator delay, pushes,
the state estimator in the loop.

Where each effect lives (one implementation each):

* ``observation_noise`` and ``action_latency`` act between the agent and the task (on the policy's
  observation and action), so the runtime applies them (:class:`ActionQueue` here);
* ``actuator_delay`` and ``pushes`` act on the robot, like the domain randomizer's
  ``actuator_latency`` and push schedule: they are turned into fixed randomization entries
  (:meth:`SimToReal.robot_entries`) that :class:`~giwbc.randomization.PerturbedRobot` applies,
  on either physics engine. Sensor noise is the robot's too (:mod:`giwbc.robot.noise`);
* ``estimator`` stands between the robot and the task (:mod:`giwbc.runtimes.estimated`).

Every knob counts time in physics steps, the only clock a simulation has, and every random draw
goes through the runtime's seeded ``numpy.random.Generator`` so that seeded runs stay bit-identical.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
from collections import deque
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.randomization import RandomizationConfig, RandomizationError
from giwbc.runtimes.estimated import EstimatorInLoop

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription

ROBOT_SIDE = frozenset({"actuator_latency", "push_interval", "push_force", "push_duration"})


@dataclass(frozen=True)
class PushConfig:
    """Random horizontal pushes on a link (the base by default), as a real robot gets from people.

    A push lasts ``duration`` s with a magnitude uniform in ``force`` (N) and a uniform random
    direction in the horizontal plane; the wait before each push is uniform in ``interval`` (s),
    counted from the end of the previous one (from the reset for the first). Pushes are drawn at
    reset for the first ``horizon`` seconds of the episode.
    """

    interval: tuple[float, float] = (1.0, 3.0)
    duration: float = 0.1
    force: tuple[float, float] = (40.0, 120.0)
    link: str | None = None
    horizon: float = 60.0

    def __post_init__(self) -> None:
        low, high = self.interval
        if not (0 < low <= high and math.isfinite(high)):
            raise ValueError(f"push interval must satisfy 0 < low <= high, got {self.interval}")
        if not (0 <= self.force[0] <= self.force[1] and math.isfinite(self.force[1])):
            raise ValueError(f"push force must satisfy 0 <= low <= high, got {self.force}")
        if not (0 < self.duration < math.inf):
            raise ValueError(f"push duration must be positive, got {self.duration}")
        if not (0 < self.horizon < math.inf):
            raise ValueError(f"push horizon must be a positive number of seconds, got {self.horizon}")

    def entries(self) -> list[dict[str, Any]]:
        """The same pushes as randomization config entries."""
        link = {"link": self.link} if self.link is not None else {}
        return [
            {"parameter": "push_interval", "distribution": "uniform", "low": self.interval[0], "high": self.interval[1], "operation": "absolute"},
            {"parameter": "push_duration", "distribution": "uniform", "low": self.duration, "high": self.duration, "operation": "absolute"},
            {"parameter": "push_force", "distribution": "uniform", "low": self.force[0], "high": self.force[1], "operation": "absolute", **link},
        ]


@dataclass(frozen=True)
class SimToReal:
    """What separates the simulation from the robot, to train a policy that survives the gap.

    - ``observation_noise``: standard deviation of Gaussian noise added to each observation
      entry (a scalar, one value per entry, or ``{pattern: std}`` over the task's observation
      names, ``fnmatch`` patterns such as ``"base_velocity/*"``: the entries an estimator errs on);
    - ``action_latency``: physics steps between the agent's ``step(action)`` and the task receiving it;
    - ``actuator_delay``: physics steps between the controller's command and the actuators applying it;
    - ``pushes``: random external wrenches on the base, or ``None``;
    - ``estimator``: the task reads its base from a state estimator fed with the measured sensors,
      calibrated at every reset (:class:`~giwbc.runtimes.estimated.EstimatorInLoop`), or ``None``.
    """

    observation_noise: float | tuple[float, ...] | Mapping[str, float] = 0.0
    action_latency: int = 0
    actuator_delay: int = 0
    pushes: PushConfig | None = None
    estimator: EstimatorInLoop | None = None

    def __post_init__(self) -> None:
        given = self.observation_noise
        noise = np.asarray(list(given.values()) if isinstance(given, Mapping) else given, dtype=float)
        if isinstance(given, Mapping) and not all(isinstance(k, str) and k for k in given):
            raise ValueError(f"observation_noise patterns must be non-empty strings, got {list(given)}")
        if noise.ndim > 1 or not np.all(np.isfinite(noise)) or np.any(noise < 0):
            raise ValueError(f"observation_noise must be one or a vector of finite stds >= 0, got {self.observation_noise}")
        for name in ("action_latency", "actuator_delay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} is a number of physics steps (int >= 0), got {value!r}")
        if self.pushes is not None and not isinstance(self.pushes, PushConfig):
            raise ValueError(f"pushes must be a PushConfig (or a dict of its fields) or None, got {self.pushes!r}")
        if self.estimator is not None and not isinstance(self.estimator, EstimatorInLoop):
            raise ValueError(f"estimator must be an EstimatorInLoop (or true, or a dict of its fields) or None, got {self.estimator!r}")

    def noise_std(self, size: int, names: Sequence[str] | None = None) -> np.ndarray:
        """The noise standard deviation per observation entry (``names``: the task's observation
        names, which a ``{pattern: std}`` noise needs; the last matching pattern wins)."""
        given = self.observation_noise
        if isinstance(given, Mapping):
            if names is None or len(names) != size:
                raise ValueError(f"observation_noise by name needs the task's {size} observation names, got {None if names is None else len(names)}")
            std = np.zeros(size)
            for pattern, value in given.items():
                hits = [i for i, name in enumerate(names) if fnmatch.fnmatchcase(name, pattern)]
                if not hits:
                    raise ValueError(f"observation_noise pattern {pattern!r} matches no observation entry (names look like {names[0]!r}, {names[-1]!r})")
                std[hits] = float(value)
            return std
        noise = np.asarray(given, dtype=float)
        if noise.ndim == 0:
            return np.full(size, float(noise))
        if noise.shape != (size,):
            raise ValueError(f"observation_noise has {noise.size} entries, the observation {size}")
        return noise

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "SimToReal":
        """Build from plain values (as ``gymnasium.make`` keyword arguments or a config file give them)."""
        values = dict(values)
        pushes = values.pop("pushes", None)
        if isinstance(pushes, dict):
            pushes = PushConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in pushes.items()})
        estimator = EstimatorInLoop.from_value(values.pop("estimator", None))
        noise = values.pop("observation_noise", 0.0)
        if isinstance(noise, Mapping):
            noise = MappingProxyType(dict(noise))
        elif isinstance(noise, (list, np.ndarray)):
            noise = tuple(noise)
        return cls(observation_noise=noise, pushes=pushes, estimator=estimator, **values)

    def robot_entries(self) -> list[dict[str, Any]]:
        """The robot-side knobs (actuator delay, pushes) as fixed randomization config entries."""
        entries = []
        if self.actuator_delay:
            delay = float(self.actuator_delay)
            entries.append({"parameter": "actuator_latency", "distribution": "uniform", "low": delay, "high": delay, "operation": "absolute"})
        if self.pushes is not None:
            entries += self.pushes.entries()
        return entries

    def merged_into(self, config: "RandomizationConfig | None", description: "RobotDescription") -> "RandomizationConfig | None":
        """``config`` with the robot-side knobs added in front (``None`` if neither has anything).

        A robot-side effect is set in one place: a config that also randomizes the actuator latency
        (with ``actuator_delay`` set) or pushes (with ``pushes`` set) is an error.
        """
        entries = self.robot_entries()
        if not entries:
            return config
        horizon = self.pushes.horizon if self.pushes is not None else 60.0
        knobs = RandomizationConfig.from_dict({"parameters": entries, "push_horizon": horizon}, description)
        if config is None:
            return knobs
        clashes = []
        if self.actuator_delay and "actuator_latency" in config.parameters:
            clashes.append("actuator_delay vs actuator_latency")
        push_entries = sorted(config.parameters & {"push_interval", "push_force", "push_duration"})
        if self.pushes is not None and push_entries:
            clashes.append(f"pushes vs {', '.join(push_entries)}")
        if clashes:
            raise RandomizationError(
                f"sim2real and the randomization config both set a robot-side effect ({'; '.join(clashes)}): "
                "set each in one place (e.g. sim2real={'pushes': None} to keep the config's pushes)"
            )
        push_horizon = horizon if self.pushes is not None else config.push_horizon
        return dataclasses.replace(config, entries=knobs.entries + config.entries, push_horizon=push_horizon)


@dataclass
class ActionQueue:
    """Actions in flight: each reaches the task ``latency`` physics steps after it was sent."""

    latency: int
    _pending: deque[tuple[int, np.ndarray]] = field(default_factory=deque)

    def clear(self) -> None:
        self._pending.clear()

    def push(self, tick: int, action: np.ndarray) -> None:
        self._pending.append((tick + self.latency, action))

    def pop_due(self, tick: int) -> list[np.ndarray]:
        """The actions due at or before ``tick``, oldest first."""
        due = []
        while self._pending and self._pending[0][0] <= tick:
            due.append(self._pending.popleft()[1])
        return due

    def next_tick(self) -> float:
        return self._pending[0][0] if self._pending else math.inf
