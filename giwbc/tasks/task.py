"""The Task interface: the logic of a learning problem, independent of robot backend and runtime.

As in Gym-Ignition, a Task turns the agent's action into references, and the robot's state into an
observation, a reward and the end of an episode. It reads and commands the robot only through the
:class:`~giwbc.robot.interface.Robot` interface (and, when it has one, its whole-body controller),
so the same task object runs in any simulated runtime or on the real robot.

The runtime drives it:

- once: :meth:`Task.bind` (robot, rates) creates the spaces;
- at reset: (a simulated runtime) draws the engine and the domain randomization and tells
  :meth:`randomized`; sets ``np_random`` (the runtime's seeded generator), asks
  :meth:`initial_state`, puts the robot there, then calls :meth:`reset_task`;
- at each agent step: :meth:`validate_action`, then :meth:`set_action` (after any action latency);
  :meth:`apply_command` at every controller tick; physics; then :meth:`get_observation`,
  :meth:`get_reward`, :meth:`is_terminated`, :meth:`is_truncated`, :meth:`get_info`.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces

from giwbc.robot.interface import Robot
from giwbc.errors import InvalidActionError

if TYPE_CHECKING:
    from giwbc.tasks.rates import Rates


@dataclass(frozen=True)
class ActionBlock:
    """A named slice of a residual action: ``size`` entries in [-1, 1], each times ``scale`` units."""

    name: str
    size: int
    scale: float | tuple[float, ...]
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        scale = np.asarray(self.scale, dtype=float)
        if self.size < 1 or scale.ndim > 1 or (scale.ndim == 1 and scale.shape != (self.size,)):
            raise ValueError(f"action block {self.name!r}: size {self.size} and scale {self.scale} disagree")
        if not np.all(np.isfinite(scale)) or np.any(scale < 0):
            raise ValueError(f"action block {self.name!r}: scales must be finite and >= 0, got {self.scale}")
        if self.labels and len(self.labels) != self.size:
            raise ValueError(f"action block {self.name!r}: {len(self.labels)} labels for {self.size} entries")

    def entry_names(self) -> tuple[str, ...]:
        return tuple(f"{self.name}/{label}" for label in self.labels) or tuple(f"{self.name}/{i}" for i in range(self.size))


class ResidualLayout:
    """The layout of a residual action over a controller: blocks of normalized entries.

    The policy outputs values in [-1, 1]; :meth:`split` clips them and multiplies by each entry's
    scale, giving residuals in physical units to add to the controller's references.
    """

    def __init__(self, blocks: tuple[ActionBlock, ...] | list[ActionBlock]) -> None:
        self.blocks = tuple(blocks)
        names = [b.name for b in self.blocks]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate action block names: {names}")
        self.size = sum(b.size for b in self.blocks)
        self.scales = np.concatenate([np.broadcast_to(np.asarray(b.scale, float), (b.size,)) for b in self.blocks])
        bounds = np.cumsum([0] + [b.size for b in self.blocks])
        self._slices = {b.name: slice(int(bounds[i]), int(bounds[i + 1])) for i, b in enumerate(self.blocks)}

    def space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(self.size,), dtype=np.float32)

    def split(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """Residuals in physical units, by block name."""
        scaled = np.minimum(np.maximum(action, -1.0), 1.0) * self.scales  # (np.clip's values, without its four Python calls)
        return {name: scaled[s] for name, s in self._slices.items()}

    def entry_names(self) -> tuple[str, ...]:
        return tuple(name for block in self.blocks for name in block.entry_names())

    def describe(self) -> dict[str, Any]:
        """Layout and scales, for deployment metadata."""
        return {
            "blocks": [{"name": b.name, "size": b.size, "offset": self._slices[b.name].start} for b in self.blocks],
            "scale": self.scales.tolist(),
            "names": list(self.entry_names()),
        }


class Task(abc.ABC):
    """Action → references, state → observation, reward, termination; robot-agnostic.

    Subclasses implement :meth:`create_spaces`, :meth:`reset_task`, :meth:`set_action`,
    :meth:`get_observation`, :meth:`get_reward` and :meth:`is_terminated`, and override
    :meth:`apply_command` when commands must be recomputed at the controller rate.
    Every random draw goes through :attr:`np_random`.
    """

    action_space: spaces.Box
    observation_space: spaces.Box

    def __init__(self) -> None:
        self._robot: Robot | None = None
        self._truth: Robot | None = None
        self._rates: Rates | None = None
        self._np_random: np.random.Generator | None = None

    # --- wiring (done by the runtime) --------------------------------------------------------
    def bind(self, robot: Robot, rates: Rates, truth: Robot | None = None) -> None:
        """Attach the robot and the rates, then create the spaces (called once by the runtime).
        ``truth``: where a simulation runs the task on measured or estimated quantities, the robot
        reporting the simulated truth (for reward, termination and info; None: ``robot``)."""
        self._robot = robot
        self._truth = truth
        self._rates = rates
        self.action_space, self.observation_space = self.create_spaces()

    @property
    def robot(self) -> Robot:
        if self._robot is None:
            raise RuntimeError(f"{type(self).__name__} is not bound to a robot; a runtime binds it")
        return self._robot

    @property
    def truth(self) -> Robot:
        """The robot reporting the true state: the simulation's (when the runtime gave one), else :attr:`robot`."""
        return self._truth if self._truth is not None else self.robot

    @property
    def rates(self) -> Rates:
        if self._rates is None:
            raise RuntimeError(f"{type(self).__name__} has no rates; a runtime binds them")
        return self._rates

    @property
    def np_random(self) -> np.random.Generator:
        """The runtime's seeded generator, handed over at every reset."""
        if self._np_random is None:
            raise RuntimeError(f"{type(self).__name__} has no random generator yet: reset the environment first")
        return self._np_random

    @np_random.setter
    def np_random(self, generator: np.random.Generator) -> None:
        self._np_random = generator

    # --- the task logic ------------------------------------------------------------------------
    @abc.abstractmethod
    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        """``(action_space, observation_space)``, once the robot and rates are known."""

    def randomized(self, drawn: Any) -> None:
        """The runtime applied a domain randomization (a :class:`~giwbc.randomization.Randomization`).

        Default: nothing. A task's own models (e.g. the WBC's Pinocchio model) stay nominal, as on
        hardware, where the true parameters are unknown; a task may opt in to use the sample.
        """

    def initial_state(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Where a simulated episode starts, ``(q, v)`` in Pinocchio's convention; ``None``: the default pose.

        A real-time runtime cannot teleport the robot and may ignore it.
        """
        return None

    @abc.abstractmethod
    def reset_task(self) -> None:
        """Clear the task's own state (references, last action, controller warm start)."""

    @abc.abstractmethod
    def set_action(self, action: np.ndarray) -> None:
        """Take a validated action (see :meth:`validate_action`) when it arrives (after any latency).

        Update the references of the controller, or command the robot directly when the command
        depends on the action alone (a cart force).
        """

    def apply_command(self) -> None:
        """Recompute and send the command from the references and the measured state.

        Called at every controller tick; a feedback controller (the WBC) lives here. Default: nothing.
        """

    def controller_failure(self) -> str | None:
        """Why the last controller tick fell back to a safe command (an infeasible QP, a state
        it could not use), or None. A simulation may go on on the fallback; a deployment stops
        on it. Default: None (no controller that can fall back)."""
        return None

    @abc.abstractmethod
    def get_observation(self) -> np.ndarray: ...

    @abc.abstractmethod
    def get_reward(self) -> float: ...

    @abc.abstractmethod
    def is_terminated(self) -> bool:
        """The episode reached a terminal state (fell, left the rail)."""

    def is_truncated(self) -> bool:
        """The episode was cut for a reason outside the MDP (time limits come from ``max_episode_steps``)."""
        return False

    def get_info(self) -> dict[str, Any]:
        """Diagnostics (new objects at every call)."""
        return {}

    # --- helpers ------------------------------------------------------------------------------
    def validate_action(self, action: Any) -> np.ndarray:
        """The action as a new float64 array clipped to the action space.

        Raises :class:`InvalidActionError` for a wrong shape, a non-numeric type or a NaN/inf entry:
        nothing is clipped away silently and nothing in the environment changes.
        """
        array = np.asarray(action)
        space = self.action_space
        if array.dtype.kind not in "biuf":
            raise InvalidActionError(f"action must be numeric, got dtype {array.dtype}")
        if array.shape != space.shape:
            raise InvalidActionError(f"action must have shape {space.shape}, got {array.shape}")
        array = array.astype(np.float64)
        finite = np.isfinite(array)
        if not finite.all():
            raise InvalidActionError(
                f"action has non-finite entries at indices {np.flatnonzero(~finite).tolist()}: {array}; "
                "the step was not taken and the environment is unchanged"
            )
        return np.minimum(np.maximum(array, space.low), space.high)

    def observation_names(self) -> tuple[str, ...]:
        """One name per observation entry (the observation layout exported with a policy)."""
        return tuple(f"obs/{i}" for i in range(int(np.prod(self.observation_space.shape))))

    def action_names(self) -> tuple[str, ...]:
        return tuple(f"action/{i}" for i in range(int(np.prod(self.action_space.shape))))

    def describe(self) -> dict[str, Any]:
        """What a deployment needs to run a policy trained on this task (JSON-serializable)."""
        return {
            "task": type(self).__name__,
            "observation_names": list(self.observation_names()),
            "action_names": list(self.action_names()),
            "observation_low": self.observation_space.low.tolist(),
            "observation_high": self.observation_space.high.tolist(),
            "rates": self.rates.as_dict(),
            "joint_names": list(self.robot.joint_names),
        }
