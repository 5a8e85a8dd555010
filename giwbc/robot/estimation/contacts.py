"""Contact detection: a low-passed force threshold with hysteresis (a Schmitt trigger) per foot.

A foot goes into contact when its normal force rises above ``on_force`` and leaves it when the
force falls below ``off_force`` (< ``on_force``), so noise around one threshold cannot chatter;
a first-order low-pass (``time_constant``) first takes the spikes off forces estimated from noisy
joint efforts. The forces come from joint efforts
(:class:`~giwbc.robot.estimation.kinematics.LegKinematics`) or foot force sensors; a
controller's contact plan can override the result per update.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ContactDetector"]


class ContactDetector:
    """Per-foot contact flags from normal forces (N), low-passed, with hysteresis, and a
    confidence that a foot carries enough load not to slip (0 at ``off_force``, 1 from
    ``full_force`` up)."""

    def __init__(
        self,
        n_feet: int,
        on_force: float,
        off_force: float,
        time_constant: float = 0.01,
        full_force: float | None = None,
        initial: bool = True,
    ) -> None:
        if not 0 <= off_force < on_force:
            raise ValueError(f"contact thresholds need 0 <= off_force < on_force, got off={off_force}, on={on_force}")
        full_force = 2.0 * on_force if full_force is None else full_force
        if full_force <= off_force:
            raise ValueError(f"full_force ({full_force}) must exceed off_force ({off_force})")
        self.full_force = full_force
        if time_constant < 0:
            raise ValueError(f"time_constant must be >= 0, got {time_constant}")
        self.on_force = on_force
        self.off_force = off_force
        self.time_constant = time_constant
        self.initial = initial
        self.n_feet = n_feet
        self.reset()

    def reset(self) -> None:
        self.contacts = np.full(self.n_feet, self.initial)
        self.forces: np.ndarray | None = None  # low-passed normal forces; None until the first update

    def update(self, normal_forces: np.ndarray, dt: float, valid: np.ndarray | None = None) -> np.ndarray:
        """New flags from ``normal_forces`` measured ``dt`` s after the previous ones; feet whose
        force is not ``valid`` (or not finite) keep their flag. Returns a new array each update."""
        if self.forces is None:
            self.forces = np.where(np.isfinite(normal_forces), normal_forces, 0.0)
        else:
            alpha = 1.0 if self.time_constant == 0 else dt / (self.time_constant + dt)
            step = alpha * (normal_forces - self.forces)
            if valid is not None:
                step = np.where(valid, step, 0.0)
            self.forces = np.where(np.isfinite(step), self.forces + step, self.forces)
        if valid is None:
            self.contacts = (self.contacts | (self.forces > self.on_force)) & ~(self.forces < self.off_force)
        else:
            rising = (self.forces > self.on_force) & valid
            falling = (self.forces < self.off_force) & valid
            self.contacts = (self.contacts | rising) & ~falling
        return self.contacts

    def confidence(self) -> np.ndarray:
        """Per foot, in [0, 1]: how loaded the foot is between ``off_force`` and ``full_force``."""
        if self.forces is None:
            return np.ones(self.n_feet)
        return np.clip((self.forces - self.off_force) / (self.full_force - self.off_force), 0.0, 1.0)
