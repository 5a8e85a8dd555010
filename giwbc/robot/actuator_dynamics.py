"""What a real motor does to a torque command between the controller and the joint.

Two effects, both per physics step and vectorized over the actuated joints:

- **lag**: the current loop and the driver make the delivered torque follow the command through a
  first-order lag of time constant ``lag`` (s): ``tau += (1 - exp(-dt / lag)) (command - tau)``,
  the exact discretization of ``d tau / dt = (command - tau) / lag`` with the command held over
  the step (0: no lag);
- **torque-speed envelope**: a motor driven at speed ``w`` in the direction of its torque (the
  motoring quadrants) has less torque left as its back-EMF eats the bus voltage. The available
  torque is the peak (the effort limit) up to ``knee_speed`` (rad/s), then falls linearly to 0 at
  ``no_load_speed`` (rad/s); braking (torque against the motion) keeps the peak. ``inf`` speeds
  turn it off.

The command is whatever the actuator would have produced: the torque of a torque command, or
``kp (q_ref - q) + kd (v_ref - v) + tau_ff`` of an impedance command evaluated at the step's
state (the driver's PD runs behind the same current loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from giwbc.errors import RobotDescriptionError


@dataclass(frozen=True)
class ActuatorDynamics:
    """Per actuated joint (arrays in the order of the description's actuated joints)."""

    lag: np.ndarray  # first-order time constant, s (0: none)
    peak_torque: np.ndarray  # N m, the effort limit
    knee_speed: np.ndarray  # rad/s, full torque up to this speed
    no_load_speed: np.ndarray  # rad/s, no torque left at this speed (motoring)

    def __post_init__(self) -> None:
        n = len(self.lag)
        for name in ("lag", "peak_torque", "knee_speed", "no_load_speed"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (n,) or np.any(np.isnan(value)) or np.any(value < 0):
                raise RobotDescriptionError(f"actuator dynamics: {name} must be {n} non-negative numbers, got {value}")
            object.__setattr__(self, name, value)
        if np.any(self.no_load_speed <= self.knee_speed) and np.any(np.isfinite(self.no_load_speed)):
            bad = np.flatnonzero((self.no_load_speed <= self.knee_speed) & np.isfinite(self.no_load_speed))
            if len(bad):
                raise RobotDescriptionError(f"actuator dynamics: no_load_speed must exceed knee_speed (actuators {bad.tolist()})")

    @property
    def active(self) -> bool:
        return bool(np.any(self.lag > 0) or np.any(np.isfinite(self.no_load_speed)))

    def retention(self, dt: float) -> np.ndarray:
        """Fraction of last step's torque kept over a step of ``dt`` s (``exp(-dt / lag)``; 0 without lag)."""
        with np.errstate(divide="ignore"):
            return np.where(self.lag > 0, np.exp(-dt / np.where(self.lag > 0, self.lag, 1.0)), 0.0)

    def available(self, torque: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """``torque`` clamped to the envelope at joint ``speed`` (rad/s)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            span = self.no_load_speed - self.knee_speed
            fraction = np.where(np.isfinite(span), np.clip((self.no_load_speed - np.abs(speed)) / span, 0.0, 1.0), 1.0)
        motoring = torque * speed > 0
        limit = np.where(motoring, self.peak_torque * fraction, self.peak_torque)
        return np.clip(torque, -limit, limit)


def no_dynamics(peak_torque: np.ndarray) -> ActuatorDynamics:
    """Ideal actuators: no lag, no envelope."""
    n = len(peak_torque)
    return ActuatorDynamics(np.zeros(n), np.asarray(peak_torque, float), np.full(n, math.inf), np.full(n, math.inf))
