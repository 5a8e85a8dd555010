"""Agent, controller and physics rates, and the integer ratios between them.

A step of the agent spans a whole number of controller ticks, and a controller tick a whole number
of physics steps: otherwise the agent's period would drift against the simulation clock (Gym-Ignition
only warned about it; we refuse it with an error naming the nearest valid rates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from giwbc.errors import RateError

_RELATIVE_TOLERANCE = 1e-9


def _check_positive(name: str, rate: float) -> float:
    rate = float(rate)
    if not math.isfinite(rate) or rate <= 0:
        raise RateError(f"{name} rate must be a positive finite number of Hz, got {rate!r}")
    return rate


def integer_ratio(fast: float, slow: float, fast_name: str, slow_name: str) -> int:
    """``fast / slow`` as an int, or a :class:`RateError` suggesting the nearest valid ``slow`` rates."""
    ratio = fast / slow
    steps = round(ratio)
    if steps >= 1 and abs(ratio - steps) <= _RELATIVE_TOLERANCE * ratio:
        return int(steps)
    if ratio < 1:
        raise RateError(
            f"{slow_name} rate {slow:g} Hz is faster than the {fast_name} rate {fast:g} Hz; "
            f"it must divide it (at most {fast:g} Hz)"
        )
    below, above = math.floor(ratio), math.ceil(ratio)
    raise RateError(
        f"{fast_name} rate {fast:g} Hz / {slow_name} rate {slow:g} Hz = {ratio:.6g} is not an integer; "
        f"nearest valid {slow_name} rates: {fast / above:.6g} Hz ({above} {fast_name} steps) "
        f"or {fast / below:.6g} Hz ({below} {fast_name} steps)"
    )


@dataclass(frozen=True)
class Rates:
    """Agent, controller and physics rates (Hz), checked for integer ratios at construction.

    ``controller`` ticks happen on physics steps ``0, k, 2k, ...`` (``k = physics_per_controller``)
    and every agent step starts on a controller tick (``controller / agent`` is an integer too).
    """

    agent: float
    controller: float
    physics: float

    def __post_init__(self) -> None:
        for name in ("agent", "controller", "physics"):
            object.__setattr__(self, name, _check_positive(name, getattr(self, name)))
        integer_ratio(self.physics, self.agent, "physics", "agent")
        integer_ratio(self.physics, self.controller, "physics", "controller")
        integer_ratio(self.controller, self.agent, "controller", "agent")

    @classmethod
    def from_timestep(cls, timestep: float, agent: float, controller: float | None = None) -> "Rates":
        """Rates for a physics ``timestep`` (s); the controller defaults to the agent rate."""
        if not math.isfinite(timestep) or timestep <= 0:
            raise RateError(f"physics timestep must be positive, got {timestep!r}")
        return cls(agent=agent, controller=agent if controller is None else controller, physics=1.0 / timestep)

    @cached_property
    def physics_per_agent(self) -> int:
        """Physics steps in one agent step."""
        return integer_ratio(self.physics, self.agent, "physics", "agent")

    @cached_property
    def physics_per_controller(self) -> int:
        """Physics steps between two controller ticks."""
        return integer_ratio(self.physics, self.controller, "physics", "controller")

    @property
    def agent_dt(self) -> float:
        return self.physics_per_agent / self.physics

    @property
    def controller_dt(self) -> float:
        return self.physics_per_controller / self.physics

    @property
    def physics_dt(self) -> float:
        return 1.0 / self.physics

    def as_dict(self) -> dict[str, float]:
        """The rates in Hz, for metadata (ONNX export, logs)."""
        return {"agent_hz": self.agent, "controller_hz": self.controller, "physics_hz": self.physics}
