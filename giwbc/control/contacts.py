"""Rigid contacts of the whole-body QP: force variables, friction constraints and ramping.

A contact is a rigid body (a foot) pinned to the environment at a *contact frame* (the sole
centre, z along the sole normal). The friction cone is expressed in that frame: it is the
ground's as long as the foot is flat on the ground, which the motion rows keep it. Working in
the contact frame (``LOCAL`` Jacobian) rather than world axes makes every friction row constant.
It contributes to the QP

* ``n_force`` force variables, expressed in the contact frame;
* 6 **motion rows** ``J q̈ = −J̇ v − Kp e − Kd J v`` (contact frame, ``LOCAL`` Jacobian): the foot
  does not accelerate (optional feedback on its pose drift);
* ``n_ineq`` **friction rows** ``l ≤ F f ≤ u`` — constant matrices, only the normal-force bounds
  change (ramping), since the variables live in the contact frame;
* its generalized force ``Jᵀ Φ f`` in the equation of motion, ``Φ`` (6 × n_force) the constant map
  from the variables to the contact-frame wrench about the contact origin.

Two models of a flat rectangular foot (both exact for 4 corner point contacts with linearized
friction pyramids ``|f_t1|, |f_t2| ≤ μ f_n``):

* :class:`SurfaceContact` (default) — 6 variables, the wrench ``(f, τ)`` at the sole centre,
  constrained to the **contact wrench cone** of the rectangle: the set of wrenches the 4 corner
  forces can produce with each corner inside its pyramid (16 face inequalities, Caron, Pham and
  Nakamura, RSS 2015), plus bounds on the total normal force. Corner forces inside their pyramids
  reproducing a wrench are recovered on demand by :func:`corner_forces_from_wrench` (exact: the
  cone is the span of the 16 pyramid edges). Half the variables of the corner model, hence the
  faster QP.
* :class:`CornerContact` — 12 variables, one 3D force per corner, 5 rows per corner (4 pyramid
  faces and the normal-force bounds ``f_min ≤ f_n ≤ f_max`` *per corner*).

Ramping: adding or removing a contact at run time moves its ``activation`` linearly between 0
and 1 over a ramp time, and caps the contact's total normal force at ``activation · F`` (the lower
bound becomes ``min(min_normal_force, cap)``): ``F`` is the normal force the contact carried when
its removal started, or the robot's weight when it is added, so the load is transferred evenly
over the whole ramp and torques stay continuous. The controller owns the ramp clock.
"""

from __future__ import annotations

import abc
import itertools
import math

import numpy as np
import pinocchio as pin
from scipy.optimize import nnls

from giwbc.control.kinodynamics import LOCAL, Kinodynamics
from giwbc.control.sole import FULL, RollDetector, SoleSupport, SoleRectangle, hull_2d, polygon_centroid, scale_polygon

_frame_jacobian = pin.getFrameJacobian
_classical_acceleration = pin.getFrameClassicalAcceleration

DEFAULT_FRICTION = 0.8
DEFAULT_MAX_NORMAL_FORCE = 2000.0  # N, per contact (SurfaceContact) or per corner (CornerContact)


def pyramid_matrix(mu: float) -> np.ndarray:
    """(4, 3) rows ``F`` with ``F f ≤ 0`` ⇔ ``|f_x| ≤ μ f_z`` and ``|f_y| ≤ μ f_z`` (contact frame)."""
    return np.array([[1.0, 0.0, -mu], [-1.0, 0.0, -mu], [0.0, 1.0, -mu], [0.0, -1.0, -mu]])


def wrench_cone_matrix(half_length: float, half_width: float, mu: float) -> np.ndarray:
    """(16, 6) face matrix ``W`` of the contact wrench cone of a ``2X × 2Y`` rectangle: ``W w ≤ 0``.

    ``w = (f_x, f_y, f_z, τ_x, τ_y, τ_z)`` about the rectangle centre in the contact frame. Rows:
    ``|f_x|, |f_y| ≤ μ f_z`` (friction), ``|τ_x| ≤ Y f_z``, ``|τ_y| ≤ X f_z`` (centre of pressure
    inside the rectangle) and 8 rows bounding the yaw torque
    ``τ_min ≤ τ_z ≤ τ_max``, ``τ_max = μ(X+Y) f_z − |Y f_x + μ τ_x| − |X f_y + μ τ_y|``,
    ``τ_min = −μ(X+Y) f_z + |Y f_x − μ τ_x| + |X f_y − μ τ_y|``.
    """
    x, y = float(half_length), float(half_width)
    rows = []
    for s in (1.0, -1.0):
        rows += [[s, 0, -mu, 0, 0, 0], [0, s, -mu, 0, 0, 0], [0, 0, -y, s, 0, 0], [0, 0, -x, 0, s, 0]]
    yaw = -mu * (x + y)
    for s1, s2 in itertools.product((1.0, -1.0), (1.0, -1.0)):
        rows.append([s1 * y, s2 * x, yaw, s1 * mu, s2 * mu, 1.0])
        rows.append([s1 * y, s2 * x, yaw, -s1 * mu, -s2 * mu, -1.0])
    return np.array(rows, dtype=float)


def rectangle_corners(half_length: float, half_width: float) -> np.ndarray:
    """(4, 3) corners in the contact frame: front-left, front-right, back-left, back-right."""
    x, y = half_length, half_width
    return np.array([[x, y, 0.0], [x, -y, 0.0], [-x, y, 0.0], [-x, -y, 0.0]])


def corner_wrench_map(corners: np.ndarray) -> np.ndarray:
    """(6, 3k) ``Φ`` mapping k stacked corner forces to the wrench about the origin."""
    corners = np.asarray(corners, dtype=float)
    phi = np.zeros((6, 3 * len(corners)))
    for i, corner in enumerate(corners):
        phi[:3, 3 * i : 3 * i + 3] = np.eye(3)
        phi[3:, 3 * i : 3 * i + 3] = pin.skew(corner)
    return phi


def pyramid_generators(corners: np.ndarray, mu: float) -> np.ndarray:
    """(6, 4k) wrenches of the 4 pyramid edges ``(±μ, ±μ, 1)`` at each corner."""
    columns = []
    for corner in np.asarray(corners, dtype=float):
        for a, b in itertools.product((mu, -mu), (mu, -mu)):
            force = np.array([a, b, 1.0])
            columns.append(np.concatenate([force, np.cross(corner, force)]))
    return np.array(columns).T


def corner_forces_from_wrench(
    wrench: np.ndarray, half_length: float, half_width: float, mu: float
) -> tuple[np.ndarray, float]:
    """Corner forces (4, 3) inside their pyramids whose wrench is ``wrench`` (contact frame).

    Non-negative least squares over the 16 pyramid edges: the residual (returned) is 0 exactly
    when ``wrench`` lies in the contact wrench cone. Diagnostic, not for the hot path.
    """
    corners = rectangle_corners(half_length, half_width)
    generators = pyramid_generators(corners, mu)
    scale = max(1.0, float(np.abs(wrench).max()))
    weights, residual = nnls(generators, np.asarray(wrench, dtype=float) / scale)
    forces = np.zeros((4, 3))
    for i in range(4):
        forces[i] = generators[:3, 4 * i : 4 * i + 4] @ weights[4 * i : 4 * i + 4] * scale
    return forces, float(residual * scale)


class Contact(abc.ABC):
    """A rigid contact at a frame fixed to a link of the model (see the module docstring).

    ``link`` names a model frame (usually the link); ``offset`` is the contact frame's placement
    in it (the sole centre for a foot). Gains ``kp``/``kd`` add feedback to the motion rows
    (``kp`` on the pose drift from where the contact was made, ``kd`` on the contact twist).
    """

    n_motion = 6

    def __init__(
        self,
        name: str,
        link: str,
        *,
        offset: pin.SE3 | np.ndarray | None = None,
        mu: float = DEFAULT_FRICTION,
        min_normal_force: float = 0.0,
        max_normal_force: float = DEFAULT_MAX_NORMAL_FORCE,
        kp: float = 0.0,
        kd: float = 0.0,
    ) -> None:
        if not (math.isfinite(mu) and mu > 0):
            raise ValueError(f"contact {name!r}: friction coefficient mu must be > 0, got {mu}")
        if not (0.0 <= min_normal_force <= max_normal_force):
            raise ValueError(
                f"contact {name!r}: need 0 <= min_normal_force <= max_normal_force, got {min_normal_force}, {max_normal_force}"
            )
        if kp < 0 or kd < 0:
            raise ValueError(f"contact {name!r}: gains must be >= 0")
        self.name = name
        self.link = link
        if offset is None:
            offset = pin.SE3.Identity()
        elif not isinstance(offset, pin.SE3):
            offset = pin.SE3(np.eye(3), np.asarray(offset, dtype=float).reshape(3))
        self.offset = offset
        self.mu = float(mu)
        self.min_normal_force = float(min_normal_force)
        self.max_normal_force = float(max_normal_force)
        self.kp = float(kp)
        self.kd = float(kd)
        self.reference: pin.SE3 | None = None  # contact-frame placement when the contact was made
        self.joint_id = -1
        self.placement = offset  # contact frame in the parent joint frame, set by bind
        self._bound: tuple | None = None  # (kin, link, offset matrix) of the last bind
        self.jacobian = np.zeros((6, 0))
        self.drift = np.zeros(6)
        if not hasattr(self, "support"):
            self.support: SoleSupport | None = None  # a sole with reduced supports (WrenchConeContact)
        self.support_mode = FULL
        self.friction_version = 0  # bumped when the friction rows' matrix changes (a support switch)
        self._friction = self.friction_matrix()
        self.phi = self.wrench_map()  # constant: None (identity) or (6, n_force)
        self._twist = np.zeros(6)

    @property
    def feedback(self) -> bool:
        """True when the motion rows carry pose or velocity feedback."""
        return self.kp > 0.0 or self.kd > 0.0

    # --- what a model provides -------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def n_force(self) -> int: ...

    @abc.abstractmethod
    def friction_matrix(self) -> np.ndarray:
        """(n_ineq, n_force) constant rows of the friction constraints."""

    @abc.abstractmethod
    def friction_bounds(self, lower: np.ndarray, upper: np.ndarray, limit: float | None = None) -> None:
        """Fill the (n_ineq,) bounds of the friction rows; ``limit`` caps the contact's total
        normal force below its nominal bounds (ramping), ``None`` for the nominal bounds."""

    @abc.abstractmethod
    def wrench_map(self) -> np.ndarray | None:
        """(6, n_force) ``Φ`` from the variables to the contact-frame wrench; None for identity."""

    @abc.abstractmethod
    def nominal_force(self, normal_force: float) -> np.ndarray:
        """Force variables carrying ``normal_force`` evenly (reference for regularisation)."""

    @property
    def n_ineq(self) -> int:
        return self._friction.shape[0]

    def friction_pattern(self) -> np.ndarray:
        """Structural non-zeros of the friction rows over every support they may switch to."""
        return self.friction_matrix() != 0

    def support_polygon(self) -> np.ndarray | None:
        """(k, 2) polygon the CoP must stay in now (contact frame); None for a contact without a sole."""
        return None

    # --- binding and per-tick terms -----------------------------------------------------------
    def bind(self, kin: Kinodynamics) -> None:
        """Resolve the link in a model (called by the controller when the contact is added)."""
        frame = kin.model.frames[kin.frame_id(self.link)]
        self.joint_id = int(frame.parentJoint)
        self.placement = frame.placement * self.offset
        self._bound = (kin, self.link, self.offset.homogeneous)

    def is_bound(self, kin: Kinodynamics) -> bool:
        """Bound to ``kin`` with its present link and offset (a walker re-makes its feet's
        contacts at every touch-down: binding them again would give the same numbers)."""
        bound = self._bound
        return bound is not None and bound[0] is kin and bound[1] == self.link and np.array_equal(bound[2], self.offset.homogeneous)

    def placement_in_world(self, kin: Kinodynamics) -> pin.SE3:
        return kin.data.oMi[self.joint_id] * self.placement

    def update(self, kin: Kinodynamics) -> None:
        """Contact-frame Jacobian (6, nv) and drift ``J̇ v`` (6,) for the current state."""
        model, data = kin.model, kin.data
        self.jacobian = pin.getFrameJacobian(model, data, self.joint_id, self.placement, LOCAL)
        self.drift = pin.getFrameClassicalAcceleration(model, data, self.joint_id, self.placement, LOCAL).vector

    def assemble(self, kin: Kinodynamics, motion: np.ndarray, rhs: np.ndarray, columns: np.ndarray) -> None:
        """The controller's hot path, :meth:`update` and :meth:`motion_target` in one: the
        contact-frame Jacobian into ``motion`` (6, nv), ``−J̇ v − Kp e − Kd J v`` into ``rhs`` (6,)
        and ``−JᵀΦ`` into ``columns`` (nv, n_force). The twist is ``J v`` (one product instead of
        a third Pinocchio call)."""
        model, data = kin.model, kin.data
        J = self.jacobian = _frame_jacobian(model, data, self.joint_id, self.placement, LOCAL)
        drift = self.drift = _classical_acceleration(model, data, self.joint_id, self.placement, LOCAL).vector
        motion[...] = J
        if self.kd > 0.0:
            twist = self._twist
            J.dot(kin.v, out=twist)  # (ndarray.dot: np.dot without its dispatch)
            np.multiply(twist, -self.kd, out=rhs)
            rhs -= drift
        else:
            np.negative(drift, out=rhs)
        if self.kp > 0.0 and self.reference is not None:
            rhs -= self.kp * pin.log6(self.reference.actInv(self.placement_in_world(kin))).vector
        phi = self.phi
        if phi is None:
            np.negative(J.T, out=columns)
        else:
            np.matmul(J.T, phi, out=columns)
            np.negative(columns, out=columns)

    def motion_target(self, kin: Kinodynamics, out: np.ndarray) -> None:
        """Right-hand side of the motion rows: ``−J̇ v − Kp e − Kd J v`` (call after update)."""
        if self.kd > 0.0:
            # The contact twist J v, read from the velocities of the Pinocchio pass.
            twist = pin.getFrameVelocity(kin.model, kin.data, self.joint_id, self.placement, LOCAL).vector
            np.multiply(twist, -self.kd, out=out)
            out -= self.drift
        else:
            np.negative(self.drift, out=out)
        if self.kp > 0.0 and self.reference is not None:
            out -= self.kp * pin.log6(self.reference.actInv(self.placement_in_world(kin))).vector

    def wrench_in_contact_frame(self, forces: np.ndarray) -> np.ndarray:
        """The 6D wrench ``(f, τ)`` about the contact origin, contact frame, from the variables."""
        phi = self.wrench_map()
        return np.array(forces, dtype=float) if phi is None else phi @ forces

    def wrench_in_world(self, kin: Kinodynamics, forces: np.ndarray) -> np.ndarray:
        """The wrench about the contact origin with world axes (force, torque)."""
        rotation = self.placement_in_world(kin).rotation
        wrench = self.wrench_in_contact_frame(forces)
        return np.concatenate([rotation @ wrench[:3], rotation @ wrench[3:]])

    def normal_force(self, forces: np.ndarray) -> float:
        return float(self.wrench_in_contact_frame(forces)[2])

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, link={self.link!r}, mu={self.mu})"


class RectangleContact(Contact):
    """Shared part of the two flat-foot models: a ``2X × 2Y`` rectangle at the contact frame."""

    def __init__(self, name: str, link: str, half_length: float, half_width: float, **kwargs: object) -> None:
        if not (half_length > 0 and half_width > 0):
            raise ValueError(f"contact {name!r}: half_length and half_width must be > 0")
        self.half_length = float(half_length)
        self.half_width = float(half_width)
        super().__init__(name, link, **kwargs)  # type: ignore[arg-type]

    @property
    def corners(self) -> np.ndarray:
        """(4, 3) corners in the contact frame."""
        return rectangle_corners(self.half_length, self.half_width)

    @classmethod
    def from_rectangle(cls, rectangle: object, *, scale: float = 1.0, **kwargs: object) -> "RectangleContact":
        """Build from a :class:`giwbc.robot.description.ContactRectangle` (sole centre as offset),
        its sides scaled by ``scale``."""
        offset = pin.SE3(np.eye(3), np.asarray(rectangle.center, dtype=float))  # type: ignore[attr-defined]
        return cls(
            rectangle.name,  # type: ignore[attr-defined]
            rectangle.link,  # type: ignore[attr-defined]
            scale * rectangle.half_length,  # type: ignore[attr-defined]
            scale * rectangle.half_width,  # type: ignore[attr-defined]
            offset=offset,
            **kwargs,
        )

    def corner_forces(self, forces: np.ndarray) -> np.ndarray:
        """(4, 3) corner forces in the contact frame reproducing the variables' wrench."""
        raise NotImplementedError


class WrenchConeContact(Contact):
    """A sole with the 6D wrench as variables, inside the contact wrench cone of its support
    polygon (:class:`~giwbc.control.sole.SoleSupport`) and with the total normal force in
    ``[min_normal_force, activation · max_normal_force]``.

    The support is the whole polygon until :meth:`watch` finds the foot rolling: then it is the
    edge or corner the foot stands on (the friction rows switch in place, same row count), the
    CoP constrained there, and the motion rows get pose feedback ``roll_kp`` back towards the
    placement the contact was made at (the foot is not pushed further over). ``torsion`` (m):
    ``|τ_z| ≤ torsion · f_z`` on every support (:class:`~giwbc.control.sole.SoleSupport`); None: the
    yaw moment the polygon's friction allows."""

    def __init__(
        self,
        name: str,
        link: str,
        vertices: np.ndarray,
        *,
        full_rows: np.ndarray | None = None,
        roll: RollDetector | None = None,
        roll_kp: float = 0.0,
        roll_supports: bool = True,
        learn_step: float = 0.0,
        learn_min: float = 0.01,
        torsion: float | None = None,
        **kwargs: object,
    ) -> None:
        mu = float(kwargs.get("mu", DEFAULT_FRICTION))  # type: ignore[arg-type]
        if not (math.isfinite(mu) and mu > 0):
            raise ValueError(f"contact {name!r}: friction coefficient mu must be > 0, got {mu}")
        if not (math.isfinite(roll_kp) and roll_kp >= 0.0):
            raise ValueError(f"contact {name!r}: roll_kp must be >= 0, got {roll_kp}")
        if torsion is not None and not (math.isfinite(torsion) and torsion > 0.0):
            raise ValueError(f"contact {name!r}: torsion must be None or a lever arm > 0 m, got {torsion!r}")
        self.torsion = torsion
        self.support = SoleSupport(vertices, mu, full_rows=full_rows, torsion=torsion)
        self.roll = roll
        self.roll_kp = float(roll_kp)
        if not (math.isfinite(learn_step) and learn_step >= 0.0 and learn_min > 0.0):
            raise ValueError(f"contact {name!r}: learn_step must be >= 0 and learn_min > 0 m")
        self.roll_supports = bool(roll_supports)
        self.learn_step = float(learn_step)
        self.learn_min = float(learn_min)
        self.learn_corner = 0.5  # share of a step the edge along the roll moves too
        self.learned_rolls = 0  # support edges moved in so far
        self._armed = True
        polygon = self.support.polygon
        axis_aligned = len(polygon) == 4 and full_rows is not None
        self._extents = (float(polygon[:, 0].min()), float(polygon[:, 0].max()), float(polygon[:, 1].min()), float(polygon[:, 1].max())) if axis_aligned else None
        self._released_at: float | None = None
        self._base_kp: float | None = None
        Contact.__init__(self, name, link, **kwargs)  # type: ignore[arg-type]  (not the rectangle's: a SurfaceContact sets its sizes itself)

    @property
    def n_force(self) -> int:
        return 6

    def friction_matrix(self) -> np.ndarray:
        support = self.support
        rows = np.zeros((support.n_rows + 1, 6))  # type: ignore[union-attr]
        rows[:-1] = support.matrices[self.support_mode]  # type: ignore[union-attr]
        rows[-1, 2] = 1.0
        return rows

    def friction_pattern(self) -> np.ndarray:
        if self.roll is None:  # never switches support
            return self.friction_matrix() != 0
        pattern = np.zeros((self.support.n_rows + 1, 6), dtype=bool)  # type: ignore[union-attr]
        pattern[:-1] = self.support.pattern  # type: ignore[union-attr]
        pattern[-1, 2] = True
        return pattern

    def friction_bounds(self, lower: np.ndarray, upper: np.ndarray, limit: float | None = None) -> None:
        n = self.support.n_rows  # type: ignore[union-attr]
        count = self.support.counts[self.support_mode]  # type: ignore[union-attr]
        lower[:n] = -np.inf
        upper[:count] = 0.0
        upper[count:n] = np.inf  # padding rows of a support with fewer faces
        upper[n] = self.max_normal_force if limit is None else min(max(limit, 0.0), self.max_normal_force)
        lower[n] = min(self.min_normal_force, upper[n])

    def wrench_map(self) -> None:
        return None

    def nominal_force(self, normal_force: float) -> np.ndarray:
        force = np.zeros(6)
        force[2] = normal_force
        return force

    def support_polygon(self) -> np.ndarray:
        return self.support.modes[self.support_mode].polygon  # type: ignore[union-attr]

    def set_torsion(self, torsion: float) -> bool:
        """Bound the yaw moment at ``|τ_z| ≤ torsion · f_z`` from now on (the contact must have been
        built with a torsion); True when it changed (:attr:`friction_version` moved)."""
        if self.torsion is None:
            raise ValueError(f"contact {self.name!r}: built without torsion rows, give it a torsion to change later")
        if torsion == self.torsion:
            return False
        self.support.set_torsion(torsion)  # type: ignore[union-attr]
        self.torsion = float(torsion)
        self.friction_version += 1
        self._friction = self.friction_matrix()
        return True

    def set_support_mode(self, mode: int) -> bool:
        """Stand on support ``mode`` (:attr:`SoleSupport.modes`); True when it changed (the
        friction rows must be written again: :attr:`friction_version` moved)."""
        if mode == self.support_mode:
            return False
        if not 0 <= mode < len(self.support.modes):  # type: ignore[union-attr]
            raise ValueError(f"contact {self.name!r}: no support mode {mode}")
        if self._base_kp is None:
            self._base_kp = self.kp
        self.support_mode = mode
        self.kp = self._base_kp if mode == FULL else max(self._base_kp, self.roll_kp)
        self.friction_version += 1
        self._friction = self.friction_matrix()
        return True

    def watch(self, kin: Kinodynamics, t: float) -> bool:
        """Roll detection at time ``t`` (see :class:`~giwbc.control.sole.RollDetector`), from the
        contact frame's rotation since the contact was made and its angular velocity; True when
        the support changed. No-op without a detector or before the contact's reference is set."""
        roll, reference = self.roll, self.reference
        if roll is None or reference is None:
            return False
        placement = self.placement_in_world(kin)
        relative = reference.rotation.T @ placement.rotation
        omega = pin.getFrameVelocity(kin.model, kin.data, self.joint_id, self.placement, LOCAL).angular
        gradient = roll.tilt(relative, omega, roll.lookahead)
        tilt = math.hypot(float(gradient[0]), float(gradient[1]))
        if self.learn_step > 0.0:
            learned = False
            if tilt > roll.tilt_on and self._armed:
                self._armed = False
                learned = self.learn_roll(gradient)
            elif tilt < roll.tilt_off:
                self._armed = True
            if not self.roll_supports:
                return learned
        if not self.roll_supports:
            return False
        if tilt > roll.tilt_on:
            self._released_at = None
            return self.set_support_mode(self.support.mode_for_tilt(gradient))  # type: ignore[union-attr]
        if self.support_mode != FULL and tilt < roll.tilt_off:
            if self._released_at is None:
                self._released_at = t
            if t - self._released_at >= roll.release_time:
                self._released_at = None
                return self.set_support_mode(FULL)
        elif self.support_mode != FULL:
            self._released_at = None
        return False

    def learn_roll(self, gradient: np.ndarray) -> bool:
        """The sole rolled downhill along ``-gradient`` (contact frame): the edge it rolled over is
        beyond where it really touches. Move that edge of the support rectangle inward by
        ``learn_step`` (never closer than ``learn_min`` to the rectangle's opposite edge); the
        friction rows change (True) unless the edge cannot move."""
        extents = self._extents
        if extents is None:
            return False
        x_min, x_max, y_min, y_max = extents
        gx, gy = float(gradient[0]), float(gradient[1])
        major = max(abs(gx), abs(gy))
        # Both edges at the lowest corner move: the one across the roll by a step, the other by a
        # share of it (a foot rolling about a diagonal, as on a single heel point, loses that corner).
        sx = self.learn_step * min(1.0, abs(gx) / major + self.learn_corner)
        sy = self.learn_step * min(1.0, abs(gy) / major + self.learn_corner)
        least = self.learn_min
        if gy < 0.0:  # heights fall towards +y: rolled onto the +y side
            y_max = max(y_max - sy, y_min + least)
        else:
            y_min = min(y_min + sy, y_max - least)
        if gx < 0.0:  # towards the toe
            x_max = max(x_max - sx, x_min + least)
        else:
            x_min = min(x_min + sx, x_max - least)
        if (x_min, x_max, y_min, y_max) == extents:
            return False
        self._extents = (x_min, x_max, y_min, y_max)
        centre = np.array([0.5 * (x_min + x_max), 0.5 * (y_min + y_max)])
        rectangle = SoleRectangle(centre, np.array([1.0, 0.0]), 0.5 * (x_max - x_min), 0.5 * (y_max - y_min))
        self.support = SoleSupport(rectangle.corners(), self.mu, full_rows=rectangle.cone(self.mu), torsion=self.torsion)
        self.learned_rolls += 1
        self.support_mode = FULL
        self.friction_version += 1
        self._friction = self.friction_matrix()
        return True

    def reset_support(self) -> bool:
        """Back to the whole sole (a contact made again)."""
        self._released_at = None
        return self.set_support_mode(FULL)


class PolygonContact(WrenchConeContact):
    """A sole given by its points (robot.toml ``sole``): the wrench cone of their convex hull."""

    @classmethod
    def from_sole(cls, rectangle: object, *, scale: float = 1.0, **kwargs: object) -> "PolygonContact":
        """Build from a :class:`giwbc.robot.description.ContactRectangle`'s sole points, the hull
        shrunk about its centroid by ``scale``. The contact frame sits at the hull's area centroid
        (:func:`sole_frame`): where a walker holds the CoP of a stance foot and puts its landings."""
        offset, vertices = sole_frame(rectangle)
        return cls(rectangle.name, rectangle.link, scale_polygon(vertices, scale), offset=offset, **kwargs)  # type: ignore[attr-defined]

    def corner_forces(self, forces: np.ndarray) -> np.ndarray:
        """(k, 3) forces at the polygon's vertices (contact frame) reproducing the wrench."""
        vertices = np.c_[self.support.polygon, np.zeros(len(self.support.polygon))]  # type: ignore[union-attr]
        generators = pyramid_generators(vertices, self.mu)
        scale = max(1.0, float(np.abs(forces).max()))
        weights, _ = nnls(generators, np.asarray(forces, dtype=float) / scale)
        return np.array([generators[:3, 4 * i : 4 * i + 4] @ weights[4 * i : 4 * i + 4] * scale for i in range(len(vertices))])


class SurfaceContact(WrenchConeContact, RectangleContact):
    """Flat rectangular foot with the 6D wrench as variables, inside the contact wrench cone of the
    rectangle (16 rows, closed form) and with the total normal force in
    ``[min_normal_force, activation · max_normal_force]``; rolls onto its edges and corners as a
    :class:`WrenchConeContact`."""

    def __init__(self, name: str, link: str, half_length: float, half_width: float, **kwargs: object) -> None:
        if not (half_length > 0 and half_width > 0):
            raise ValueError(f"contact {name!r}: half_length and half_width must be > 0")
        self.half_length = float(half_length)
        self.half_width = float(half_width)
        mu = float(kwargs.get("mu", DEFAULT_FRICTION))  # type: ignore[arg-type]
        vertices = rectangle_corners(half_length, half_width)[:, :2]
        full = wrench_cone_matrix(half_length, half_width, mu) if mu > 0 else None
        WrenchConeContact.__init__(self, name, link, vertices, full_rows=full, **kwargs)

    def corner_forces(self, forces: np.ndarray) -> np.ndarray:
        return corner_forces_from_wrench(forces, self.half_length, self.half_width, self.mu)[0]


class CornerContact(RectangleContact):
    """Flat foot with one 3D force per corner (12 variables, contact frame), each inside its
    friction pyramid, with ``min_normal_force ≤ f_n ≤ activation · max_normal_force`` per corner;
    with ``vertices`` ((k, 2), a sole polygon), one force per vertex instead."""

    def __init__(self, name: str, link: str, half_length: float, half_width: float, *, vertices: np.ndarray | None = None, **kwargs: object) -> None:
        self._vertices = None if vertices is None else np.c_[np.asarray(vertices, dtype=float).reshape(-1, 2), np.zeros(len(vertices))]
        super().__init__(name, link, half_length, half_width, **kwargs)

    @property
    def corners(self) -> np.ndarray:
        """(k, 3) force points in the contact frame (the rectangle's 4 corners by default)."""
        return rectangle_corners(self.half_length, self.half_width) if self._vertices is None else self._vertices

    @property
    def n_force(self) -> int:
        return 3 * len(self.corners)

    def friction_matrix(self) -> np.ndarray:
        k = len(self.corners)
        rows = np.zeros((5 * k, 3 * k))
        pyramid = pyramid_matrix(self.mu)
        for i in range(k):
            rows[5 * i : 5 * i + 4, 3 * i : 3 * i + 3] = pyramid
            rows[5 * i + 4, 3 * i + 2] = 1.0
        return rows

    def friction_bounds(self, lower: np.ndarray, upper: np.ndarray, limit: float | None = None) -> None:
        k = len(self.corners)
        maximum = self.max_normal_force if limit is None else min(max(limit, 0.0) / k, self.max_normal_force)
        minimum = min(self.min_normal_force, maximum)
        for i in range(k):
            lower[5 * i : 5 * i + 4] = -np.inf
            upper[5 * i : 5 * i + 4] = 0.0
            lower[5 * i + 4] = minimum
            upper[5 * i + 4] = maximum

    def wrench_map(self) -> np.ndarray:
        return corner_wrench_map(self.corners)



    def nominal_force(self, normal_force: float) -> np.ndarray:
        k = len(self.corners)
        force = np.zeros(3 * k)
        force[2::3] = normal_force / k
        return force

    def support_polygon(self) -> np.ndarray:
        return hull_2d(self.corners[:, :2])

    def corner_forces(self, forces: np.ndarray) -> np.ndarray:
        return np.asarray(forces, dtype=float).reshape(-1, 3).copy()


def sole_frame(rectangle: object) -> tuple[pin.SE3, np.ndarray]:
    """The contact frame of a sole given by points (robot.toml ``sole``) and the hull's vertices
    in it: origin at the hull's area centroid in the sole plane, axes the link's.

    The CoP a walker plans for a stance foot is that frame's origin; at the rectangle's centre,
    a sole that touches mostly through its forefoot (a heel point on the centreline) would have
    its planned CoP near the hull's narrow end, with no room to move sideways. For a symmetric
    sole the centroid is the rectangle's centre and nothing moves."""
    hull = hull_2d(rectangle.sole_points)  # type: ignore[attr-defined]
    centroid = polygon_centroid(hull)
    origin = np.asarray(rectangle.center, dtype=float).copy()  # type: ignore[attr-defined]
    origin[:2] += centroid
    return pin.SE3(np.eye(3), origin), hull - centroid


def foot_contacts(
    description: object, model: str = "surface", *, scale: float = 1.0, roll: RollDetector | None = None, roll_kp: float = 0.0,
    roll_supports: bool = True, learn_step: float = 0.0, torsion: float | None = None, **kwargs: object
) -> list[Contact]:
    """One contact per ``ContactRectangle`` of a robot description (``model``: surface | corners).

    A contact whose description gives ``sole`` points stands on their convex hull (a
    :class:`PolygonContact`, or corner forces at the hull's vertices); otherwise on its rectangle.
    ``scale`` (0, 1] shrinks the support about its centre: a margin that keeps the centre of
    pressure off the very edge of the real sole, where any model error rolls the foot. ``roll``
    (surface model): watch the feet for rolling and stand a rolled foot on its edge or corner
    (``roll_supports``), with pose feedback ``roll_kp``; ``learn_step`` (m, rectangular soles): move
    the edge a foot rolled over inward by this much at each roll (:class:`WrenchConeContact`);
    ``torsion`` (m, surface model): the yaw moment bound ``|τ_z| ≤ torsion · f_z``.
    """
    if model not in ("surface", "corners"):
        raise ValueError(f"unknown contact model {model!r}; choose from ['corners', 'surface']")
    if torsion is not None and model == "corners":
        raise ValueError("torsion bounds the surface contact model's yaw moment: the corners model has none to bound")
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"scale must be in (0, 1], got {scale}")
    contacts: list[Contact] = []
    for rectangle in description.contacts:  # type: ignore[attr-defined]
        sole = bool(getattr(rectangle, "sole", ()))
        if model == "corners":
            if sole:
                offset, vertices = sole_frame(rectangle)
                contact: Contact = CornerContact(
                    rectangle.name, rectangle.link, rectangle.half_length, rectangle.half_width, offset=offset,
                    vertices=scale_polygon(vertices, scale), **kwargs,
                )
            else:
                contact = CornerContact.from_rectangle(rectangle, scale=scale, **kwargs)
        elif sole:
            contact = PolygonContact.from_sole(rectangle, scale=scale, roll=roll, roll_kp=roll_kp, roll_supports=roll_supports, torsion=torsion, **kwargs)
        else:
            contact = SurfaceContact.from_rectangle(
                rectangle, scale=scale, roll=roll, roll_kp=roll_kp, roll_supports=roll_supports, learn_step=learn_step, torsion=torsion, **kwargs
            )
        contacts.append(contact)
    return contacts
