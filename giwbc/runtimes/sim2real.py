"""Sim-to-real knobs of a simulated runtime: observation noise, action latency, actuator delay, pushes.

Every knob counts time in physics steps, the only clock a simulation has, and every random draw
goes through the runtime's seeded ``numpy.random.Generator`` so that seeded runs stay bit-identical.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, ImuReading, Robot

if TYPE_CHECKING:
    from giwbc.robot.mujoco_robot import MujocoRobot


@dataclass(frozen=True)
class PushConfig:
    """Random horizontal pushes on a link (the base by default), as a real robot gets from people.

    A push lasts ``duration`` s with a magnitude uniform in ``force`` (N) and a uniform random
    direction in the horizontal plane; the wait before each push is uniform in ``interval`` (s),
    counted from the end of the previous one (from the reset for the first).
    """

    interval: tuple[float, float] = (1.0, 3.0)
    duration: float = 0.1
    force: tuple[float, float] = (40.0, 120.0)
    link: str | None = None

    def __post_init__(self) -> None:
        low, high = self.interval
        if not (0 < low <= high and math.isfinite(high)):
            raise ValueError(f"push interval must satisfy 0 < low <= high, got {self.interval}")
        if not (0 <= self.force[0] <= self.force[1] and math.isfinite(self.force[1])):
            raise ValueError(f"push force must satisfy 0 <= low <= high, got {self.force}")
        if not (0 < self.duration < math.inf):
            raise ValueError(f"push duration must be positive, got {self.duration}")


@dataclass(frozen=True)
class SimToReal:
    """What separates the simulation from the robot, to train a policy that survives the gap.

    - ``observation_noise``: standard deviation of Gaussian noise added to each observation
      entry (a scalar, or one value per entry);
    - ``action_latency``: physics steps between the agent's ``step(action)`` and the task receiving it;
    - ``actuator_delay``: physics steps between the controller's command and the actuators applying it;
    - ``pushes``: random external wrenches on the base, or ``None``.
    """

    observation_noise: float | tuple[float, ...] = 0.0
    action_latency: int = 0
    actuator_delay: int = 0
    pushes: PushConfig | None = None

    def __post_init__(self) -> None:
        noise = np.asarray(self.observation_noise, dtype=float)
        if noise.ndim > 1 or not np.all(np.isfinite(noise)) or np.any(noise < 0):
            raise ValueError(f"observation_noise must be one or a vector of finite stds >= 0, got {self.observation_noise}")
        for name in ("action_latency", "actuator_delay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} is a number of physics steps (int >= 0), got {value!r}")

    def noise_std(self, size: int) -> np.ndarray:
        """The noise standard deviation per observation entry."""
        noise = np.asarray(self.observation_noise, dtype=float)
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
        noise = values.pop("observation_noise", 0.0)
        return cls(observation_noise=tuple(noise) if isinstance(noise, (list, np.ndarray)) else noise, pushes=pushes, **values)


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


def _copy_impedance(command: ImpedanceCommand) -> ImpedanceCommand:
    return replace(command, **{name: np.array(getattr(command, name), dtype=float) for name in ("q_ref", "v_ref", "kp", "kd", "tau_ff")})


class DelayedCommandRobot(Robot):
    """A Robot whose commands reach the wrapped robot ``delay`` physics steps late; reads pass through.

    The runtime calls :meth:`release` at every physics step a command falls due (see :meth:`next_tick`),
    so a task or controller commanding it sees the actuator delay of a real bus and driver.
    """

    def __init__(self, robot: Robot, delay: int) -> None:
        self.inner = robot
        self.delay = int(delay)
        self._tick = 0
        self._pending: deque[tuple[int, str, Any]] = deque()

    def clear(self) -> None:
        self._pending.clear()
        self._tick = 0

    def set_tick(self, tick: int) -> None:
        """The physics step at which commands given from now on are issued."""
        self._tick = tick

    def release(self, tick: int) -> None:
        """Apply to the wrapped robot every command due at or before ``tick``, in order."""
        while self._pending and self._pending[0][0] <= tick:
            _, kind, payload = self._pending.popleft()
            if kind == "torques":
                self.inner.set_joint_torques(payload)
            else:
                self.inner.set_joint_impedance(payload)

    def next_tick(self) -> float:
        return self._pending[0][0] if self._pending else math.inf

    # --- commands: queued ---------------------------------------------------------------------
    def set_joint_torques(self, torques: np.ndarray) -> None:
        torques = np.array(torques, dtype=float)
        if torques.shape != (self.dofs,) or not np.all(np.isfinite(torques)):
            raise ValueError(f"expected {self.dofs} finite joint torques, got {torques}")
        self._pending.append((self._tick + self.delay, "torques", torques))

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        command.validate(self.dofs)
        self._pending.append((self._tick + self.delay, "impedance", _copy_impedance(command)))

    # --- reads: pass through ------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.inner.name

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.inner.joint_names

    @property
    def floating_base(self) -> bool:
        return self.inner.floating_base

    def time(self) -> float:
        return self.inner.time()

    def joint_positions(self) -> np.ndarray:
        return self.inner.joint_positions()

    def joint_velocities(self) -> np.ndarray:
        return self.inner.joint_velocities()

    def joint_efforts(self) -> np.ndarray:
        return self.inner.joint_efforts()

    def base_state(self) -> BaseState:
        return self.inner.base_state()

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        return self.inner.link_pose(link)

    def contact_wrench(self, link: str) -> ContactWrench:
        return self.inner.contact_wrench(link)

    def imu(self) -> ImuReading:
        return self.inner.imu()

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.inner.generalized_state()


class PushSchedule:
    """Draws push times, directions and magnitudes and applies them through ``set_external_wrench``."""

    def __init__(self, config: PushConfig, link: str, physics_dt: float) -> None:
        self.config = config
        self.link = link
        self.dt = physics_dt
        self.force = np.zeros(3)
        self._start = math.inf
        self._end = math.inf
        self.count = 0

    def reset(self, rng: np.random.Generator, robot: "MujocoRobot") -> None:
        self.force = np.zeros(3)
        self.count = 0
        robot.set_external_wrench(self.link, self.force)
        self._end = math.inf
        self._start = self._ticks(rng.uniform(*self.config.interval))

    def _ticks(self, seconds: float) -> int:
        return max(1, int(round(seconds / self.dt)))

    def next_tick(self) -> float:
        return min(self._start, self._end)

    def update(self, tick: int, rng: np.random.Generator, robot: "MujocoRobot") -> None:
        """Start or end a push falling due at ``tick``."""
        if tick >= self._end:
            self.force = np.zeros(3)
            robot.set_external_wrench(self.link, self.force)
            self._end = math.inf
            self._start = tick + self._ticks(rng.uniform(*self.config.interval))
        if tick >= self._start:
            angle = rng.uniform(0.0, 2.0 * np.pi)
            magnitude = rng.uniform(*self.config.force)
            self.force = magnitude * np.array([np.cos(angle), np.sin(angle), 0.0])
            robot.set_external_wrench(self.link, self.force)
            self.count += 1
            self._start = math.inf
            self._end = tick + self._ticks(self.config.duration)
