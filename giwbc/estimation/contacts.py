"""Contact detection: a low-passed force threshold with hysteresis (a Schmitt trigger) per foot.

A foot goes into contact when its normal force rises above ``on_force`` and leaves it when the
force falls below ``off_force`` (< ``on_force``), so noise around one threshold cannot chatter;
a first-order low-pass (``time_constant``) first takes the spikes off forces estimated from noisy
joint efforts. The forces come from joint efforts
(:class:`~giwbc.estimation.kinematics.LegKinematics`) or foot force sensors; a
controller's contact plan can override the result per update.
"""

from __future__ import annotations

import numpy as np

from giwbc.estimation import kernels

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
        self._filtered = np.zeros(self.n_feet)  # low-passed normal forces, once started (the first update)
        self._started = False
        self._usable = np.ones(self.n_feet, dtype=bool)

    @property
    def forces(self) -> np.ndarray | None:
        """Low-passed normal forces (N); None until the first update."""
        return self._filtered.copy() if self._started else None

    def update(self, normal_forces: np.ndarray, dt: float, valid: np.ndarray | None = None) -> np.ndarray:
        """New flags from ``normal_forces`` measured ``dt`` s after the previous ones; feet whose
        force is not ``valid`` (or not finite) keep their flag. Returns a new array each update.

        One compiled call (:func:`giwbc.estimation.kernels.detect_contacts`)."""
        alpha = 1.0 if self.time_constant == 0 else dt / (self.time_constant + dt)
        contacts = np.empty(self.n_feet, dtype=bool)
        kernels.detect_contacts(np.asarray(normal_forces, float), self._usable if valid is None else np.asarray(valid, bool),
                                self._filtered, self._started, alpha, self.on_force, self.off_force, self.contacts, contacts)
        self._started = True
        self.contacts = contacts
        return contacts

    def confidence(self) -> np.ndarray:
        """Per foot, in [0, 1]: how loaded the foot is between ``off_force`` and ``full_force``."""
        return np.array(self.confidence_floats())

    def confidence_floats(self) -> list[float]:
        """:meth:`confidence` as Python floats."""
        if not self._started:
            return [1.0] * self.n_feet
        off, span = self.off_force, self.full_force - self.off_force
        return [min(max((force - off) / span, 0.0), 1.0) for force in self._filtered.tolist()]
