"""Apply a physics sample to a MuJoCo model in place: no recompilation per episode.

:class:`MujocoApplier` snapshots the model's nominal arrays once and writes every sample from
them, so randomizations never accumulate; :meth:`MujocoApplier.restore` puts the nominal model
back. After changing masses, inertias or armature it calls ``mj_setConst`` (on a scratch
``MjData``) so the constants MuJoCo derives at compile time (subtree masses, the constraint
solver's inverse weights, actuator ``acc0``) match what compiling the randomized model would give.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from giwbc.randomization.parameters import Nominal
from giwbc.randomization.sampling import Sample

_SNAPSHOT = (
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_sameframe",
    "dof_damping",
    "dof_frictionloss",
    "dof_armature",
    "actuator_forcerange",
    "geom_friction",
    "geom_solref",
)
_MASS_PROPERTIES = frozenset({"link_mass", "link_com", "joint_armature"})


def dampratio_for_restitution(restitution: float) -> float:
    """Contact damping ratio whose mass-spring-damper rebound speed ratio is ``restitution``.

    MuJoCo's soft contacts have no restitution coefficient; with damping ratio ``zeta < 1``
    (``solref[1]``) a contact rebounds with ``e = exp(-zeta pi / sqrt(1 - zeta^2))``, so this is
    an approximation (solimp and the time constant shape the real rebound too). ``e = 0`` gives 1.
    """
    e = min(max(float(restitution), 0.0), 1.0)
    if e <= 0.0:
        return 1.0
    if e >= 1.0:
        return 0.0
    log_e = math.log(e)
    return -log_e / math.sqrt(math.pi**2 + log_e**2)


class MujocoApplier:
    """Writes physics samples into one ``MjModel`` (the model a :class:`MujocoRobot` steps)."""

    def __init__(self, model: mujoco.MjModel, nominal: Nominal, floating_base: bool) -> None:
        self.model = model
        self._scratch = mujoco.MjData(model)
        self._nominal = {name: getattr(model, name).copy() for name in _SNAPSHOT}
        self._gravity = model.opt.gravity.copy()
        self._bodies = np.array([self._id(mujoco.mjtObj.mjOBJ_BODY, link) for link in nominal.links])
        first = 1 if floating_base else 0
        joint_ids = np.arange(first, first + len(nominal.joints))
        self._dofs = model.jnt_dofadr[joint_ids]
        actuated = model.actuator_trnid[:, 0] - first
        self._actuator_joint = actuated.astype(int)
        self._contact_geoms = np.flatnonzero((model.geom_contype != 0) | (model.geom_conaffinity != 0))
        self._dirty = False  # mass properties differ from nominal: mj_setConst due on the next apply

    def _id(self, kind: mujoco.mjtObj, name: str) -> int:
        index = mujoco.mj_name2id(self.model, kind, name)
        if index < 0:
            raise KeyError(f"MuJoCo model has no body {name!r}")
        return index

    def restore(self) -> None:
        """Write the nominal model back."""
        for name, value in self._nominal.items():
            getattr(self.model, name)[:] = value
        self.model.opt.gravity[:] = self._gravity
        self._set_const()
        self._dirty = False

    def apply(self, sample: Sample) -> None:
        """Write ``sample`` over the nominal model (parameters it did not randomize stay nominal)."""
        m, nominal = self.model, self._nominal
        for name, value in nominal.items():
            getattr(m, name)[:] = value
        m.opt.gravity[:] = self._gravity
        touched = sample.randomized
        bodies = self._bodies
        if "link_mass" in touched:
            mass = sample["link_mass"]
            nominal_mass = nominal["body_mass"][bodies]
            ratio = np.divide(mass, nominal_mass, out=np.ones_like(mass), where=nominal_mass > 0)
            m.body_mass[bodies] = mass
            m.body_inertia[bodies] = nominal["body_inertia"][bodies] * ratio[:, None]
        if "link_com" in touched:
            com = sample["link_com"]
            moved = np.any(np.abs(com - nominal["body_ipos"][bodies]) > 0, axis=1) & (m.body_mass[bodies] > 0)
            m.body_ipos[bodies[moved]] = com[moved]
            m.body_sameframe[bodies[moved]] = 0  # the inertial frame no longer coincides with the body's
        dofs = self._dofs
        if "joint_damping" in touched:
            m.dof_damping[dofs] = sample["joint_damping"]
        if "joint_friction" in touched:
            m.dof_frictionloss[dofs] = sample["joint_friction"]
        if "joint_armature" in touched:
            m.dof_armature[dofs] = sample["joint_armature"]
        if "actuator_strength" in touched:
            effort = sample["actuator_strength"][self._actuator_joint]
            m.actuator_forcerange[:] = np.stack([-effort, effort], axis=1)
        geoms = self._contact_geoms
        if "ground_friction" in touched:
            # Floor and feet both get it: MuJoCo combines a pair by the maximum.
            m.geom_friction[geoms, 0] = sample.scalar("ground_friction")
        if "ground_restitution" in touched:
            m.geom_solref[geoms, 1] = dampratio_for_restitution(sample.scalar("ground_restitution"))
        if "gravity" in touched:
            m.opt.gravity[:] = sample["gravity"]
        if touched & _MASS_PROPERTIES or self._dirty:
            self._set_const()
        self._dirty = bool(touched & _MASS_PROPERTIES)

    def _set_const(self) -> None:
        mujoco.mj_setConst(self.model, self._scratch)
