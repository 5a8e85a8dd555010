"""The yaw momentum the limbs make, damped: a swinging leg's twist taken by the trunk and arms, not the floor.

A walking leg swinging forward at the hip's lateral offset, and the CoM accelerated by a stance foot
beside it, carry angular momentum about the vertical. With the base's heading held by its
orientation task, the only other source of the yaw moment that momentum needs is the stance foot:
the whole-body QP plans 10-20 N m of yaw moment on it at every lift-off (traced on the G1, 0.3 m/s).
A floor that grips in yaw holds that; a compliant one creeps (MuJoCo's soft contact: a moment far
inside the friction cone turns the loaded foot, 5 -> 55 deg in 0.16 s on the soft_floor plant) and
the robot falls a few steps later.

:class:`LimbYawMomentumTask` (one row) asks the **joints' share** of the centroidal angular
momentum about the vertical, ``L_z,joints = A_g[z, joints] v_joints``, to decay at rate ``kd``
(no position level): what the limbs add to the yaw momentum beyond the whole robot turning with its
base. The QP then counter-rotates the trunk (waist yaw) and the arms against the swing leg, as a
walking person swings the arms, instead of asking the floor. The base's own rotation (a heading
held, a turn commanded) has no part in it: turning in place is left to the base task.

The drift is the full centroidal drift's z row (``Ȧ_g v``): it differs from the joints' share's
(``Ȧ_j v_j``) by the rate of the locked robot's momentum at the base's rate, small while the base
turns at fractions of a rad/s; the task is a damping term, not a constraint.
"""

from __future__ import annotations

import numpy as np

from giwbc.control.kinodynamics import Kinodynamics
from giwbc.control.tasks import WbcTask


class LimbYawMomentumTask(WbcTask):
    """``L̇_z,joints → −kd L_z,joints`` (world vertical, about the CoM): see the module docstring."""

    def __init__(self, name: str = "limb_yaw_momentum", *, weight: float = 1.0, kd: float = 20.0) -> None:
        super().__init__(name, 1, weight=weight, kp=0.0, kd=kd)
        self._base = 6  # floating-base columns left out (set at bind)

    def bind(self, kin: Kinodynamics) -> None:
        super().bind(kin)
        self._base = kin.n_base if kin.free_flyer else 0

    def momentum(self, kin: Kinodynamics) -> float:
        """The joints' share of the yaw momentum now (kg m² / s)."""
        b = self._base
        return float(kin.centroidal_map[5, b:] @ kin.v[b:])

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        b = self._base
        rows[0, :b] = 0.0
        rows[0, b:] = kin.centroidal_map[5, b:]
        error[0] = 0.0
        drift[0] = kin.centroidal_drift[5]


__all__ = ["LimbYawMomentumTask"]
