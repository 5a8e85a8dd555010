"""Two tasks on one cart-pole robot, the Gym-Ignition paper's example: balance and swing-up.

Both read the cart joint and the pole hinge through the Robot interface and command the cart
force directly when the action arrives (no controller, so no :meth:`~Task.apply_command`): the
action is the force normalized by ``max_force``.
Observation: ``[x, x_dot, cos θ, sin θ, θ_dot]`` with ``θ = 0`` the pole upright.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from giwbc.tasks.task import Task

OBSERVATION_NAMES = ("cart_position", "cart_velocity", "pole_cos", "pole_sin", "pole_velocity")


class CartPoleTask(Task):
    """What balance and swing-up share: joints, spaces, action → force, observation."""

    def __init__(
        self,
        max_force: float = 20.0,
        x_limit: float = 2.0,
        cart_joint: str = "linear",
        pole_joint: str = "pivot",
    ) -> None:
        super().__init__()
        if not max_force > 0 or not x_limit > 0:
            raise ValueError(f"max_force and x_limit must be positive, got {max_force}, {x_limit}")
        self.max_force = float(max_force)
        self.x_limit = float(x_limit)
        self.cart_joint, self.pole_joint = cart_joint, pole_joint
        self.force = 0.0
        self.last_action = np.zeros(1)
        self._state: tuple[float, tuple[float, float, float, float]] | None = None

    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        names = self.robot.joint_names
        for joint in (self.cart_joint, self.pole_joint):
            if joint not in names:
                raise ValueError(f"robot {self.robot.name!r} has no joint {joint!r}; it has {names}")
        self._cart, self._pole = names.index(self.cart_joint), names.index(self.pole_joint)
        self._torques = np.zeros(self.robot.dofs)
        high = np.array([self.x_limit + 0.5, 20.0, 1.0, 1.0, 50.0], dtype=np.float32)
        return spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32), spaces.Box(-high, high, dtype=np.float32)

    # --- state ----------------------------------------------------------------------------
    def state(self) -> tuple[float, float, float, float]:
        """``(x, x_dot, θ, θ_dot)`` with θ wrapped to (-π, π]; read once per robot time."""
        now = self.robot.time()
        if self._state is not None and self._state[0] == now:
            return self._state[1]
        q, v = self.robot.joint_positions(), self.robot.joint_velocities()
        theta = math.atan2(math.sin(q[self._pole]), math.cos(q[self._pole]))
        state = float(q[self._cart]), float(v[self._cart]), theta, float(v[self._pole])
        self._state = (now, state)
        return state

    def _start(self, pole_angle: float, spread: float) -> tuple[np.ndarray, np.ndarray]:
        x, x_dot, theta, theta_dot = self.np_random.uniform(-spread, spread, size=4)
        q, v = np.zeros(self.robot.dofs), np.zeros(self.robot.dofs)
        q[self._cart], q[self._pole] = x, pole_angle + theta
        v[self._cart], v[self._pole] = x_dot, theta_dot
        return q, v

    # --- Task -----------------------------------------------------------------------------
    def reset_task(self) -> None:
        self.force = 0.0
        self.last_action = np.zeros(1)
        self._state = None

    def set_action(self, action: np.ndarray) -> None:
        self.last_action = np.array(action, dtype=float)
        self.force = float(self.last_action[0]) * self.max_force
        self._torques[self._cart] = self.force
        self.robot.set_joint_torques(self._torques)

    def get_observation(self) -> np.ndarray:
        x, x_dot, theta, theta_dot = self.state()
        return np.array([x, x_dot, math.cos(theta), math.sin(theta), theta_dot], dtype=np.float32)

    def is_terminated(self) -> bool:
        return abs(self.state()[0]) > self.x_limit

    def get_info(self) -> dict[str, Any]:
        x, _, theta, _ = self.state()
        return {"cart_force": self.force, "pole_angle": theta, "cart_position": x}

    def observation_names(self) -> tuple[str, ...]:
        return OBSERVATION_NAMES

    def action_names(self) -> tuple[str, ...]:
        return ("cart_force",)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "action_scale": [self.max_force], "action_offset": [0.0], "action_unit": "N"}


class CartPoleBalance(CartPoleTask):
    """Keep the pole upright: +1 per step until the pole tilts past ``max_angle`` or the cart leaves the rail."""

    def __init__(self, max_angle: float = 0.2, initial_spread: float = 0.05, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.max_angle = float(max_angle)
        self.initial_spread = float(initial_spread)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._start(0.0, self.initial_spread)

    def get_reward(self) -> float:
        return 1.0

    def is_terminated(self) -> bool:
        x, _, theta, _ = self.state()
        return abs(theta) > self.max_angle or abs(x) > self.x_limit


class CartPoleSwingUp(CartPoleTask):
    """Swing the pole up from hanging down and hold it there, near the middle of the rail.

    Reward in [-0.02, 1]: ``(1 + cos θ)/2`` (uprightness) weighted down as the cart nears the rail
    ends, minus small penalties on pole speed and force. Terminates only if the cart leaves the rail.
    """

    def __init__(self, initial_spread: float = 0.1, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.initial_spread = float(initial_spread)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._start(np.pi, self.initial_spread)

    def get_reward(self) -> float:
        x, _, theta, theta_dot = self.state()
        upright = 0.5 * (1.0 + math.cos(theta))
        centered = 1.0 - 0.5 * min(1.0, (x / self.x_limit) ** 2)
        penalty = 0.01 * min(1.0, (theta_dot / 20.0) ** 2) + 0.01 * float(self.last_action[0] ** 2)
        return float(upright * centered - penalty)
