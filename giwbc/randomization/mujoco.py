"""Apply a physics sample to a MuJoCo model in place: no recompilation per episode.

:class:`MujocoApplier` snapshots the model's nominal arrays once and writes every sample from
them, so randomizations never accumulate; :meth:`MujocoApplier.restore` puts the nominal model
back. After changing masses, inertias or armature it calls ``mj_setConst`` (on a scratch
``MjData``) so the constants MuJoCo derives at compile time (subtree masses, the constraint
solver's inverse weights, actuator ``acc0``) match what compiling the randomized model would give.

Joints, actuators and links are found by name. A plant built elsewhere may have merged a link into
its parent (fixed joints; ``pelvis_contour_link`` into ``pelvis``): that link's mass and centre of
mass changes then go to the body that carries it (:func:`giwbc.robot.fixed_links.carrier`), as the
change of the merged body's total mass and mass-weighted centre of mass (its inertia scaled with its
mass); a link missing for any other reason is refused with one line naming it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import mujoco
import numpy as np

from giwbc.randomization.distributions import RandomizationError
from giwbc.randomization.parameters import Nominal
from giwbc.randomization.sampling import Sample
from giwbc.robot.actuator_dynamics import ActuatorDynamics, no_dynamics
from giwbc.robot.fixed_links import carrier

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

    def __init__(self, model: mujoco.MjModel, nominal: Nominal, floating_base: bool, urdf_path: str | None = None,
                 robot: Any = None) -> None:
        """``urdf_path``: the description's URDF, to place links the plant merged into their parents;
        ``robot``: the MujocoRobot stepping ``model`` (its actuator dynamics carry ``actuator_lag``)."""
        self.model = model
        self.robot = robot
        self._dynamics = getattr(robot, "actuator_dynamics", None)  # the plant's own (a variant's lag and envelope)
        self._iterations = int(model.opt.iterations)
        self._scratch = mujoco.MjData(model)
        self._nominal = {name: getattr(model, name).copy() for name in _SNAPSHOT}
        self._gravity = model.opt.gravity.copy()
        ids = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, link) for link in nominal.links])
        self._bodies = ids[ids >= 0]
        self._present = np.flatnonzero(ids >= 0)  # nominal link index of each entry of _bodies
        self._merged = self._merged_links(nominal, ids, urdf_path)
        if self._merged:  # a carrier's own link changes its body by the same deltas as the links merged into it
            own = np.isin(self._bodies, list(self._merged))
            for body, link in zip(self._bodies[own], self._present[own]):
                self._merged[int(body)].insert(0, (int(link), np.zeros(3), np.eye(3)))
            self._bodies, self._present = self._bodies[~own], self._present[~own]
        self._link_nominal = (nominal.values["link_mass"], nominal.values["link_com"])  # the URDF's, per link
        joint_ids = []
        for name in nominal.joints:
            joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if joint < 0:
                raise RandomizationError(f"cannot randomize this plant: it has no joint {name!r}")
            joint_ids.append(joint)
        self._dofs = model.jnt_dofadr[np.array(joint_ids, dtype=int)]
        index = {joint: i for i, joint in enumerate(joint_ids)}
        self._actuator_joint = np.array([index.get(int(j), -1) for j in model.actuator_trnid[:, 0]], dtype=int)
        if np.any(self._actuator_joint < 0):
            raise RandomizationError("cannot randomize this plant: an actuator drives a joint the description does not have")
        self._contact_geoms = np.flatnonzero((model.geom_contype != 0) | (model.geom_conaffinity != 0))
        self._dirty = False  # mass properties differ from nominal: mj_setConst due on the next apply

    def _merged_links(self, nominal: Nominal, ids: np.ndarray, urdf_path: str | None) -> dict[int, list[tuple[int, np.ndarray, np.ndarray]]]:
        """``body -> [(nominal link index, link position, link rotation in the body)]`` for links the plant merged."""
        merged: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}
        missing = np.flatnonzero(ids < 0)
        if not len(missing):
            return merged
        if urdf_path is None:
            raise RandomizationError(f"MuJoCo model has no body {nominal.links[missing[0]]!r} (and no description to find its carrier)")
        bodies = frozenset(self.model.body(i).name for i in range(self.model.nbody))
        for link in missing:
            try:
                held = carrier(urdf_path, bodies, nominal.links[link])
            except Exception as error:
                raise RandomizationError(f"cannot randomize this plant: {error}") from None
            body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, held.body)
            merged.setdefault(body, []).append((int(link), held.position, held.rotation))
        return merged

    def restore(self) -> None:
        """Write the nominal model back."""
        for name, value in self._nominal.items():
            getattr(self.model, name)[:] = value
        self.model.opt.gravity[:] = self._gravity
        self.model.opt.iterations = self._iterations
        if self.robot is not None:
            self.robot.set_actuator_dynamics(self._dynamics)
        self._set_const()
        self._dirty = False

    def apply(self, sample: Sample) -> None:
        """Write ``sample`` over the nominal model (parameters it did not randomize stay nominal)."""
        m, nominal = self.model, self._nominal
        for name, value in nominal.items():
            getattr(m, name)[:] = value
        m.opt.gravity[:] = self._gravity
        m.opt.iterations = self._iterations
        touched = sample.randomized
        bodies, present = self._bodies, self._present
        if "link_mass" in touched:
            mass = sample["link_mass"][present]
            nominal_mass = nominal["body_mass"][bodies]
            ratio = np.divide(mass, nominal_mass, out=np.ones_like(mass), where=nominal_mass > 0)
            m.body_mass[bodies] = mass
            m.body_inertia[bodies] = nominal["body_inertia"][bodies] * ratio[:, None]
        if "link_com" in touched:
            com = sample["link_com"][present]
            moved = np.any(np.abs(com - nominal["body_ipos"][bodies]) > 0, axis=1) & (m.body_mass[bodies] > 0)
            m.body_ipos[bodies[moved]] = com[moved]
            m.body_sameframe[bodies[moved]] = 0  # the inertial frame no longer coincides with the body's
        if self._merged and touched & {"link_mass", "link_com"}:
            self._apply_merged(sample)
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
        if "contact_timeconst" in touched:
            m.geom_solref[geoms, 0] = sample.scalar("contact_timeconst")
        if "contact_dampratio" in touched:
            m.geom_solref[geoms, 1] = sample.scalar("contact_dampratio")
        if "solver_iterations" in touched:
            m.opt.iterations = int(sample.scalar("solver_iterations"))
        if self.robot is not None:
            self.robot.set_actuator_dynamics(self._lagged(sample["actuator_lag"]) if "actuator_lag" in touched else self._dynamics)
        elif "actuator_lag" in touched:
            raise RandomizationError("actuator_lag needs the MujocoRobot of this model (DomainRandomizer passes it)")
        if touched & _MASS_PROPERTIES or self._dirty:
            self._set_const()
        self._dirty = bool(touched & _MASS_PROPERTIES)

    def _apply_merged(self, sample: Sample) -> None:
        """Merged links' mass and CoM changes onto their carrying bodies (after the carriers' own)."""
        m, nominal_links = self.model, self._link_nominal
        mass, com = sample["link_mass"], sample["link_com"]
        for body, links in self._merged.items():
            total, moment = float(m.body_mass[body]), m.body_mass[body] * m.body_ipos[body]
            for link, position, rotation in links:
                m0, c0 = nominal_links[0][link], nominal_links[1][link]
                total += mass[link] - m0
                moment = moment + mass[link] * (position + rotation @ com[link]) - m0 * (position + rotation @ c0)
            if total <= 0:
                raise RandomizationError(f"randomized links merged into body {m.body(body).name!r} leave it {total:.3g} kg")
            old = float(m.body_mass[body])
            m.body_inertia[body] = m.body_inertia[body] * (total / old if old > 0 else 1.0)
            m.body_mass[body] = total
            m.body_ipos[body] = moment / total
            m.body_sameframe[body] = 0

    def _lagged(self, lag: np.ndarray) -> ActuatorDynamics:
        """The plant's actuator dynamics (ideal: none) with ``lag`` (per joint, description order)."""
        by_joint = np.argsort(self._actuator_joint)  # actuators in the description's order of actuated joints
        base = self._dynamics or no_dynamics(self.model.actuator_forcerange[by_joint, 1].copy())
        return replace(base, lag=lag[self._actuator_joint[by_joint]])

    def _set_const(self) -> None:
        mujoco.mj_setConst(self.model, self._scratch)
