"""Rigid-body quantities of one state, computed once per control tick.

:class:`Kinodynamics` wraps a ``pinocchio.Model`` and its ``Data``. :meth:`Kinodynamics.update`
runs **one** Pinocchio pass, ``computeAllTerms`` (forward kinematics with velocity and with zero
joint acceleration, CRBA, non-linear effects, joint Jacobians, centre of mass and its Jacobian,
centroidal map and momentum). Measured on the G1 (nv = 35): 17 µs, against 13 µs for the lean
``crba(WORLD) + nonLinearEffects + jacobianCenterOfMass`` — but that set leaves ``data.a`` unset
(``nonLinearEffects`` only fills ``a_gf``), and restoring the frame drifts from ``a_gf`` costs
more Python calls than the 4 µs it saves. Everything else is read from ``Data``:

* ``M(q)`` (full symmetric matrix), ``h(q, v) = C(q, v) v + g(q)``, ``g(q)``;
* frame placements, Jacobians and drifts ``J̇ v`` — ``computeAllTerms`` leaves ``data.a`` at the
  joint accelerations obtained with ``q̈ = 0``, so the classical acceleration of a frame read from
  it *is* ``J̇ v``;
* CoM, its velocity, Jacobian and drift; centroidal momentum, map ``A_g`` and drift ``Ȧ_g v``.

Conventions: Pinocchio's. A free-flyer velocity is expressed in the base frame; frame Jacobians
are requested in an explicit ``pin.ReferenceFrame`` (``LOCAL_WORLD_ALIGNED`` for CoM-type and
world-frame tasks, ``LOCAL`` for contact wrenches expressed in the contact frame).

Arrays returned by the accessors are **views into ``Data``**: valid until the next
:meth:`update`; copy them to keep them. The views are taken once (an attribute of a Pinocchio
``Data`` costs ~0.5–2 µs per access from Python; the arrays it returns are views of memory that
``Data`` never reallocates) and checked once, at the first update, to still be the live storage —
else every access falls back to reading ``Data``.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
LOCAL = pin.ReferenceFrame.LOCAL
WORLD = pin.ReferenceFrame.WORLD


def unactuated_dofs(model: pin.Model) -> int:
    """Velocity dimension of an unactuated root joint: 6 for a free flyer, else 0 (fixed base)."""
    if model.njoints > 1 and model.joints[1].shortname() == "JointModelFreeFlyer":
        return 6
    return 0


class Kinodynamics:
    """Dynamics and kinematics of one state of a ``pinocchio.Model``, refreshed by :meth:`update`.

    ``n_base`` leading velocity coordinates are the unactuated (floating-base) ones: detected as
    6 for a free-flyer root, 0 otherwise; pass it explicitly for other underactuated roots (e.g.
    the 3 coordinates of a planar ``PX → PZ → RY`` base).
    """

    def __init__(self, model: pin.Model, *, n_base: int | None = None) -> None:
        if not isinstance(model, pin.Model):
            raise TypeError(f"expected a pinocchio.Model, got {type(model).__name__}")
        self.model = model
        self.data = model.createData()
        self.nq = int(model.nq)
        self.nv = int(model.nv)
        self.n_base = unactuated_dofs(model) if n_base is None else int(n_base)
        if not 0 <= self.n_base <= self.nv:
            raise ValueError(f"n_base must be in [0, {self.nv}], got {self.n_base}")
        self.n_joints = self.nv - self.n_base
        self.free_flyer = unactuated_dofs(model) == 6
        # Joint coordinates after the base: single-DoF joints only (nq == nv for them).
        base_nq = 7 if self.free_flyer and self.n_base == 6 else self.n_base
        if self.nq - base_nq != self.n_joints:
            raise ValueError(
                "the joints after the base must all be single-DoF (nq == nv); "
                f"got nq={self.nq}, nv={self.nv}, n_base={self.n_base}"
            )
        self.q_shape, self.v_shape = (self.nq,), (self.nv,)
        self.joint_q = slice(base_nq, self.nq)
        self.joint_v = slice(self.n_base, self.nv)
        self.mass = float(sum(inertia.mass for inertia in model.inertias))
        self.gravity = np.array(model.gravity.linear, dtype=float)
        self._inverse_mass = 1.0 / self.mass if self.mass > 0 else 0.0
        self.q = pin.neutral(model)
        self.v = np.zeros(self.nv)
        self.stamp = 0  # incremented by every update; lazily computed terms compare against it
        self._com_drift_stamp = -1
        self._com_drift = np.zeros(3)
        self._centroidal_stamp = -1
        self._centroidal_drift = np.zeros(6)
        self._zero_v = np.zeros(self.nv)
        self._all_terms = pin.computeAllTerms
        self._rotations: dict[int, np.ndarray] = {}
        self._bind_views()
        self._views_checked = False
        self._views_live = True

    def _bind_views(self) -> None:
        data = self.data
        self._M, self._nle, self._Jcom = data.M, data.nle, data.Jcom
        self._com, self._vcom = data.com[0], data.vcom[0]
        self._rotations.clear()
        self._base_rotation = data.oMi[1].rotation if self.model.njoints > 1 else np.eye(3)

    def _check_views(self) -> None:
        """After the first pass: are the cached views still ``Data``'s storage? (else: no cache)."""
        data = self.data
        pairs = [(self._M, data.M), (self._nle, data.nle), (self._Jcom, data.Jcom), (self._com, data.com[0]), (self._vcom, data.vcom[0])]
        if self.model.njoints > 1:
            pairs.append((self._base_rotation, data.oMi[1].rotation))
        self._views_live = all(a.ctypes.data == b.ctypes.data and np.array_equal(a, b) for a, b in pairs)
        self._views_checked = True

    # --- the per-tick pass ---------------------------------------------------------------------
    def check_state(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q, v)`` as float arrays of the right shapes; ``ValueError`` for wrong shapes."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (self.nq,):
            raise ValueError(f"q has shape {q.shape}, expected ({self.nq},) for model {self.model.name!r}")
        if v.shape != (self.nv,):
            raise ValueError(f"v has shape {v.shape}, expected ({self.nv},) for model {self.model.name!r}")
        return q, v

    @staticmethod
    def is_finite(q: np.ndarray, v: np.ndarray) -> bool:
        """True when every entry of ``q`` and ``v`` is finite (one cheap reduction each)."""
        return math.isfinite(float(np.dot(q, q))) and math.isfinite(float(np.dot(v, v)))

    def update(self, q: np.ndarray, v: np.ndarray, *, checked: bool = False) -> None:
        """Compute every term for state ``(q, v)`` in one Pinocchio pass (``checked``: the
        caller already ran :meth:`check_state`)."""
        if not checked:
            q, v = self.check_state(q, v)
        self.q = q
        self.v = v
        self._all_terms(self.model, self.data, q, v)
        self.stamp += 1
        if not self._views_live:
            self._bind_views()  # the bindings return copies: read them again after every pass
        elif not self._views_checked:
            self._check_views()
            if not self._views_live:
                self._bind_views()

    # --- joint space ---------------------------------------------------------------------------
    @property
    def mass_matrix(self) -> np.ndarray:
        """``M(q)``, full symmetric (nv, nv) view."""
        return self._M

    @property
    def nonlinear_effects(self) -> np.ndarray:
        """``h(q, v) = C(q, v) v + g(q)`` (nv,) view."""
        return self._nle

    @property
    def generalized_gravity(self) -> np.ndarray:
        """``g(q)`` (nv,) view."""
        return self.data.g

    # --- frames --------------------------------------------------------------------------------
    def frame_id(self, name: str) -> int:
        """Frame id by name; ``KeyError`` naming the model when absent."""
        if not self.model.existFrame(name):
            raise KeyError(f"model {self.model.name!r} has no frame {name!r}")
        return int(self.model.getFrameId(name))

    def frame_placement(self, frame_id: int) -> pin.SE3:
        """World placement of a frame (updates ``data.oMf[frame_id]``)."""
        return pin.updateFramePlacement(self.model, self.data, frame_id)

    def frame_jacobian(self, frame_id: int, reference: pin.ReferenceFrame = LWA) -> np.ndarray:
        """(6, nv) Jacobian ``[linear; angular]`` of a frame, in ``reference`` coordinates."""
        return pin.getFrameJacobian(self.model, self.data, frame_id, reference)

    def frame_drift(self, frame_id: int, reference: pin.ReferenceFrame = LWA) -> np.ndarray:
        """``J̇ v`` of a frame: its classical acceleration at ``q̈ = 0`` (6,), ``[linear; angular]``."""
        return pin.getFrameClassicalAcceleration(self.model, self.data, frame_id, reference).vector

    def point_jacobian(self, joint_id: int, placement: pin.SE3, reference: pin.ReferenceFrame = LOCAL) -> np.ndarray:
        """(6, nv) Jacobian of a frame given by its placement in a joint frame (no model frame needed)."""
        return pin.getFrameJacobian(self.model, self.data, joint_id, placement, reference)

    def point_drift(self, joint_id: int, placement: pin.SE3, reference: pin.ReferenceFrame = LOCAL) -> np.ndarray:
        """``J̇ v`` (classical acceleration at ``q̈ = 0``) of a frame given by its joint placement."""
        return pin.getFrameClassicalAcceleration(self.model, self.data, joint_id, placement, reference).vector

    def joint_placement(self, joint_id: int) -> pin.SE3:
        return self.data.oMi[joint_id]

    def joint_rotation(self, joint_id: int) -> np.ndarray:
        """World rotation of a joint frame (3, 3), a view into ``Data`` refreshed by every update."""
        view = self._rotations.get(joint_id)
        if view is None:
            view = self._rotations[joint_id] = self.data.oMi[joint_id].rotation
        return view

    @property
    def base_rotation(self) -> np.ndarray:
        """World rotation of the first joint (the floating base), a view into ``Data``."""
        return self._base_rotation

    # --- centre of mass ------------------------------------------------------------------------
    @property
    def com(self) -> np.ndarray:
        return self._com

    @property
    def com_velocity(self) -> np.ndarray:
        return self._vcom

    @property
    def com_jacobian(self) -> np.ndarray:
        """(3, nv) Jacobian of the CoM (world coordinates)."""
        return self._Jcom

    @property
    def com_drift(self) -> np.ndarray:
        """``J̇_com v`` (3,): the CoM acceleration at ``q̈ = 0``, computed once per update.

        For a free flyer, from the base rows of ``h`` (no extra pass): at ``q̈ = 0`` they are the
        base wrench that, with gravity, produces the momentum rate, so ``m c̈ = R h[:3] + m g``.
        Other models run ``centerOfMass`` at acceleration level (``data.a`` holds ``q̈ = 0``).
        """
        if self._com_drift_stamp != self.stamp:
            out = self._com_drift
            if self.free_flyer and self.n_base == 6:
                np.dot(self.base_rotation, self.nonlinear_effects[:3], out=out)
                out *= self._inverse_mass
                out += self.gravity
            else:
                pin.centerOfMass(self.model, self.data, pin.KinematicLevel.ACCELERATION, False)
                out[:] = self.data.acom[0]
            self._com_drift_stamp = self.stamp
        return self._com_drift

    def com_drift_into(self, out: np.ndarray) -> None:
        """Write :attr:`com_drift` into ``out`` (3,) (the hot path: no intermediate copy)."""
        if self.free_flyer and self.n_base == 6:
            self._base_rotation.dot(self._nle[:3], out=out)
            out *= self._inverse_mass
            out += self.gravity
        else:
            out[...] = self.com_drift

    # --- centroidal momentum -------------------------------------------------------------------
    @property
    def centroidal_momentum(self) -> np.ndarray:
        """``h_G = A_g v`` (6,) ``[linear; angular]`` about the CoM, world axes."""
        return self.data.hg.vector

    @property
    def centroidal_map(self) -> np.ndarray:
        """``A_g`` (6, nv)."""
        return self.data.Ag

    @property
    def centroidal_drift(self) -> np.ndarray:
        """``Ȧ_g v`` (6,): the momentum rate at ``q̈ = 0``, computed once per update.

        For a free flyer it comes for free from the base rows of ``h``: at ``q̈ = 0`` they hold
        the base wrench (base frame) that produces the momentum rate against gravity; shifting it
        to the CoM in world axes and adding gravity back gives ``Ȧ_g v``. Other models use
        ``computeCentroidalMomentumTimeVariation`` on a scratch ``Data``.
        """
        if self._centroidal_stamp != self.stamp:
            out = self._centroidal_drift
            if self.free_flyer and self.n_base == 6:
                base = self.data.oMi[1]
                rotation = base.rotation
                force = rotation @ self.data.nle[:3]
                out[:3] = force + self.mass * self.gravity
                out[3:] = rotation @ self.data.nle[3:6] - np.cross(self.data.com[0] - base.translation, force)
            else:
                scratch = self.model.createData()
                pin.computeCentroidalMomentumTimeVariation(self.model, scratch, self.q, self.v, self._zero_v)
                out[:] = scratch.dhg.vector
            self._centroidal_stamp = self.stamp
        return self._centroidal_drift
