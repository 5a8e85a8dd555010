"""Closed-form rigid-body dynamics of small planar systems, derived and written out by hand.

These models are the ground truth that Pinocchio models and controllers are unit-tested
against, so nothing here calls a dynamics library: every mass matrix, Coriolis term and
gravity term is the hand-derived expression (derivations in the class docstrings).

Shared conventions (all models):

* Equations of motion ``M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`` with ``τ`` the generalized force.
  ``coriolis(q, qd)`` returns the *vector* ``C(q, q̇) q̇``; ``coriolis_matrix(q, qd)`` returns a
  matrix ``C`` with that product and with ``Ṁ − 2C`` skew-symmetric (Christoffel form).
  ``gravity(q)`` is ``g(q) = ∂V/∂q`` (so it appears on the left-hand side).
* Every model moves in the world **x–z plane**; gravity is ``gravity`` m/s² along **−z**;
  every revolute joint rotates about **+y**. By the right-hand rule a positive rotation about
  +y turns +z towards +x and −z towards −x, i.e. a body-frame vector ``(bx, bz)`` maps to
  ``(bx cos θ + bz sin θ, −bx sin θ + bz cos θ)`` in world (x, z).
* Potential energy is ``Σ mᵢ · gravity · zᵢ`` with ``zᵢ`` the world height of body i's centre of
  mass (zero at the world origin), the same reference Pinocchio uses, so ``energy`` matches
  ``pin.computeKineticEnergy + pin.computePotentialEnergy`` of the twins in ``pinocchio_models``.
* Inertias are scalar moments about the body's centre of mass, about the y axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

STANDARD_GRAVITY: float = 9.81
"""Default gravity magnitude, m/s²; equal to Pinocchio's default ``model.gravity``."""

__all__ = [
    "STANDARD_GRAVITY",
    "AnalyticModel",
    "SimplePendulum",
    "DoublePendulum",
    "CartPole",
    "PlanarFloatingBody",
    "PlanarFloatingArm",
    "rotate_y",
]


def rotate_y(angle: float, vector_xz: np.ndarray) -> np.ndarray:
    """World (x, z) of a body-frame vector ``(bx, bz)`` after a rotation ``angle`` about +y."""
    c, s = np.cos(angle), np.sin(angle)
    bx, bz = vector_xz
    return np.array([bx * c + bz * s, -bx * s + bz * c])


def _perp(r: np.ndarray) -> np.ndarray:
    """``d/dθ rotate_y(θ, b) = (r_z, −r_x)`` where ``r = rotate_y(θ, b)``.

    Also the linear velocity of a point at offset ``r`` on a body spinning at unit rate about +y.
    """
    return np.array([r[1], -r[0]])


def _as_vector(x: np.ndarray | float | list[float], n: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have {n} entries, got shape {np.shape(x)}")
    return arr


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")


def _check_non_negative(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


def _check_finite(**values: float) -> None:
    for name, value in values.items():
        if not np.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")


class AnalyticModel:
    """Shared plumbing: inverse/forward dynamics and energy from the hand-written terms.

    Subclasses (frozen dataclasses) write out ``mass_matrix``, ``coriolis_matrix``,
    ``coriolis``, ``gravity``, ``potential_energy`` and ``actuation_matrix`` by hand; everything
    here is derived from those, so a model cannot be inconsistent with its own ``τ`` formula.
    The gravity magnitude field is ``gravity_acc`` (``gravity`` is the method ``g(q)``).
    """

    nq: ClassVar[int]
    nv: ClassVar[int]

    # -- to be provided by each model -------------------------------------------------------
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def gravity(self, q: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def potential_energy(self, q: np.ndarray) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def actuation_matrix(self) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- derived -----------------------------------------------------------------------------
    def _q(self, q: np.ndarray) -> np.ndarray:
        return _as_vector(q, self.nq, "q")

    def _v(self, v: np.ndarray, name: str = "qd") -> np.ndarray:
        return _as_vector(v, self.nv, name)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``τ = M(q) q̈ + C(q, q̇) q̇ + g(q)``."""
        q, qd, qdd = self._q(q), self._v(qd), self._v(qdd, "qdd")
        return self.mass_matrix(q) @ qdd + self.coriolis(q, qd) + self.gravity(q)

    def forward_dynamics(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q))`` (a linear solve, not an explicit inverse)."""
        q, qd, tau = self._q(q), self._v(qd), self._v(tau, "tau")
        rhs = tau - self.coriolis(q, qd) - self.gravity(q)
        return np.linalg.solve(self.mass_matrix(q), rhs)

    def kinetic_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        """``½ q̇ᵀ M(q) q̇``."""
        qd = self._v(qd)
        return 0.5 * float(qd @ self.mass_matrix(q) @ qd)

    def energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        """Total mechanical energy, kinetic + potential (see the module docstring for the zero)."""
        return self.kinetic_energy(q, qd) + self.potential_energy(q)


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimplePendulum(AnalyticModel):
    """One link on a revolute joint about +y at the world origin, ``q = [θ]``.

    The link points along its own −z axis, so ``θ = 0`` hangs straight down and a positive θ
    swings the centre of mass towards **−x**: ``p_com = (−c sin θ, −c cos θ)`` in world (x, z).

    ``M = I + m c²``, ``C q̇ = 0``, ``g = m g₀ c sin θ``, ``V = −m g₀ c cos θ``.
    A point mass is ``inertia = 0``; a uniform rod of length L is ``c = L/2, I = m L²/12``.
    No damping or friction: ``τ = M q̈ + C q̇ + g`` holds exactly.
    """

    mass: float = 1.0
    com_distance: float = 1.0
    inertia: float = 0.0
    gravity_acc: float = STANDARD_GRAVITY

    nq: ClassVar[int] = 1
    nv: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _check_positive(mass=self.mass)
        _check_non_negative(inertia=self.inertia, gravity_acc=self.gravity_acc)
        _check_finite(com_distance=self.com_distance)
        _check_positive(pivot_inertia=self.inertia + self.mass * self.com_distance**2)

    @classmethod
    def point_mass(cls, mass: float = 1.0, length: float = 1.0, gravity_acc: float = STANDARD_GRAVITY) -> SimplePendulum:
        """Ideal pendulum: all mass at distance ``length`` from the pivot."""
        return cls(mass=mass, com_distance=length, inertia=0.0, gravity_acc=gravity_acc)

    @classmethod
    def uniform_rod(cls, mass: float = 1.0, length: float = 1.0, gravity_acc: float = STANDARD_GRAVITY) -> SimplePendulum:
        """Thin uniform rod pivoting at one end."""
        return cls(mass=mass, com_distance=length / 2.0, inertia=mass * length**2 / 12.0, gravity_acc=gravity_acc)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        self._q(q)  # validates the shape
        return np.array([[self.inertia + self.mass * self.com_distance**2]])

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        self._q(q)
        self._v(qd)
        return np.zeros((1, 1))

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        self._q(q)
        self._v(qd)
        return np.zeros(1)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        (theta,) = self._q(q)
        return np.array([self.mass * self.gravity_acc * self.com_distance * np.sin(theta)])

    def potential_energy(self, q: np.ndarray) -> float:
        (theta,) = self._q(q)
        return -self.mass * self.gravity_acc * self.com_distance * float(np.cos(theta))

    def actuation_matrix(self) -> np.ndarray:
        return np.eye(1)

    def com_position(self, q: np.ndarray) -> np.ndarray:
        """World (x, z) of the centre of mass."""
        (theta,) = self._q(q)
        return rotate_y(theta, np.array([0.0, -self.com_distance]))


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DoublePendulum(AnalyticModel):
    """Two links in series, both joints revolute about +y, ``q = [q1, q2]`` (q2 relative).

    Joint 1 is at the world origin; each link points along its own −z, so ``q = 0`` hangs
    straight down and positive angles swing towards −x. Joint 2 sits ``length1`` down link 1.
    With ``mᵢ, lᵢ, cᵢ, Iᵢ`` = mass, length, CoM distance from the link's joint, inertia about the
    CoM, and ``s1 = sin q1``, ``s12 = sin(q1 + q2)``:

    ``p_com1 = (−c₁ s1, −c₁ cos q1)``, ``p_com2 = (−l₁ s1 − c₂ s12, −l₁ cos q1 − c₂ cos(q1+q2))``.

    ``M11 = I₁ + I₂ + m₁c₁² + m₂(l₁² + c₂² + 2 l₁ c₂ cos q2)``,
    ``M12 = I₂ + m₂(c₂² + l₁ c₂ cos q2)``, ``M22 = I₂ + m₂ c₂²``;
    with ``h = m₂ l₁ c₂ sin q2``: ``C q̇ = [−h(2 q̇1 q̇2 + q̇2²), h q̇1²]``,
    ``C = [[−h q̇2, −h(q̇1 + q̇2)], [h q̇1, 0]]``;
    ``g = [(m₁c₁ + m₂l₁) g₀ s1 + m₂c₂ g₀ s12, m₂c₂ g₀ s12]``, ``g₀ = gravity_acc``.
    ``length2`` does not enter the dynamics; it only places the tip (``tip_position``).
    """

    mass1: float = 1.0
    length1: float = 1.0
    com1: float = 0.5
    inertia1: float = 1.0 / 12.0
    mass2: float = 1.0
    length2: float = 1.0
    com2: float = 0.5
    inertia2: float = 1.0 / 12.0
    gravity_acc: float = STANDARD_GRAVITY

    nq: ClassVar[int] = 2
    nv: ClassVar[int] = 2

    def __post_init__(self) -> None:
        _check_positive(mass1=self.mass1, mass2=self.mass2)
        _check_non_negative(inertia1=self.inertia1, inertia2=self.inertia2, gravity_acc=self.gravity_acc)
        _check_finite(length1=self.length1, length2=self.length2, com1=self.com1, com2=self.com2)
        _check_positive(link2_pivot_inertia=self.inertia2 + self.mass2 * self.com2**2)

    def _h(self, q2: float) -> float:
        return self.mass2 * self.length1 * self.com2 * float(np.sin(q2))

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        _, q2 = self._q(q)
        m1, m2, l1, c1, c2 = self.mass1, self.mass2, self.length1, self.com1, self.com2
        coupling = m2 * l1 * c2 * np.cos(q2)
        m22 = self.inertia2 + m2 * c2**2
        m12 = m22 + coupling
        m11 = self.inertia1 + m1 * c1**2 + m2 * l1**2 + m22 + 2.0 * coupling
        return np.array([[m11, m12], [m12, m22]])

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, q2 = self._q(q)
        qd1, qd2 = self._v(qd)
        h = self._h(q2)
        return np.array([[-h * qd2, -h * (qd1 + qd2)], [h * qd1, 0.0]])

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, q2 = self._q(q)
        qd1, qd2 = self._v(qd)
        h = self._h(q2)
        return np.array([-h * (2.0 * qd1 * qd2 + qd2**2), h * qd1**2])

    def gravity(self, q: np.ndarray) -> np.ndarray:
        q1, q2 = self._q(q)
        g0 = self.gravity_acc
        s1, s12 = np.sin(q1), np.sin(q1 + q2)
        g2 = self.mass2 * self.com2 * g0 * s12
        g1 = (self.mass1 * self.com1 + self.mass2 * self.length1) * g0 * s1 + g2
        return np.array([g1, g2])

    def potential_energy(self, q: np.ndarray) -> float:
        q1, q2 = self._q(q)
        z1 = -self.com1 * np.cos(q1)
        z2 = -self.length1 * np.cos(q1) - self.com2 * np.cos(q1 + q2)
        return float(self.gravity_acc * (self.mass1 * z1 + self.mass2 * z2))

    def actuation_matrix(self) -> np.ndarray:
        return np.eye(2)

    def tip_position(self, q: np.ndarray) -> np.ndarray:
        """World (x, z) of the end of link 2."""
        q1, q2 = self._q(q)
        elbow = rotate_y(q1, np.array([0.0, -self.length1]))
        return elbow + rotate_y(q1 + q2, np.array([0.0, -self.length2]))


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CartPole(AnalyticModel):
    """Cart on a rail along +x carrying a pole on a passive hinge about +y, ``q = [x, θ]``.

    Sign convention (matches ``robots/cartpole/cartpole.urdf``: prismatic axis ``1 0 0``, hinge
    axis ``0 1 0``, pole CoM at ``+0.25`` on the pole's z axis):

    * ``x`` is the cart displacement along world +x;
    * ``θ = 0`` is the pole **upright** (CoM straight above the pivot); a positive θ is a
      right-handed rotation about +y, which tips the pole's top towards **+x**:
      ``p_com = (x + c sin θ, z_pivot + c cos θ)``.

    Lagrangian derivation, with ``M_t = m_cart + m_pole``, ``c`` the pivot→CoM distance and
    ``I`` the pole inertia about its CoM:
    ``T = ½ M_t ẋ² + m_p c cos θ ẋ θ̇ + ½ (I + m_p c²) θ̇²``, ``V = m_p g₀ c cos θ``, so

    ``M = [[M_t, m_p c cos θ], [m_p c cos θ, I + m_p c²]]``,
    ``C q̇ = [−m_p c sin θ θ̇², 0]`` (``C = [[0, −m_p c sin θ θ̇], [0, 0]]``),
    ``g = [0, −m_p g₀ c sin θ]`` — negative for small positive θ: gravity pushes the upright
    pole further over (``g`` sits on the left of ``M q̈ + C q̇ + g = τ``).
    ``pivot_height`` (world z of the pivot) and ``cart_com_offset`` (z of the cart's CoM relative
    to the pivot) only shift the potential energy by a constant; they make ``energy`` equal to
    that of the URDF (pivot at 0.55 m, cart CoM 0.05 m below it).
    """

    cart_mass: float = 1.0
    pole_mass: float = 0.2
    pole_com: float = 0.25
    pole_inertia: float = 0.0041708
    gravity_acc: float = STANDARD_GRAVITY
    pivot_height: float = 0.0
    cart_com_offset: float = 0.0

    nq: ClassVar[int] = 2
    nv: ClassVar[int] = 2

    def __post_init__(self) -> None:
        _check_positive(cart_mass=self.cart_mass, pole_mass=self.pole_mass)
        _check_non_negative(pole_inertia=self.pole_inertia, gravity_acc=self.gravity_acc)
        _check_finite(pole_com=self.pole_com, pivot_height=self.pivot_height, cart_com_offset=self.cart_com_offset)
        _check_positive(pole_pivot_inertia=self.pole_inertia + self.pole_mass * self.pole_com**2)

    @classmethod
    def from_urdf_parameters(cls) -> CartPole:
        """Exactly the parameters of ``robots/cartpole/cartpole.urdf``.

        cart 1 kg on joint ``linear`` (axis +x, at z = 0.5 above ``rail``), pole 0.2 kg on joint
        ``pivot`` (axis +y, 0.05 above the cart), pole CoM 0.25 m up the pole, pole
        ``iyy = 0.0041708`` kg·m² about its CoM; pivot at world height 0.5 + 0.05 = 0.55 m with
        the cart's CoM 0.05 m below it. Gravity is Pinocchio's default 9.81 m/s².
        """
        return cls(
            cart_mass=1.0,
            pole_mass=0.2,
            pole_com=0.25,
            pole_inertia=0.0041708,
            gravity_acc=STANDARD_GRAVITY,
            pivot_height=0.55,
            cart_com_offset=-0.05,
        )

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        _, theta = self._q(q)
        coupling = self.pole_mass * self.pole_com * np.cos(theta)
        return np.array(
            [
                [self.cart_mass + self.pole_mass, coupling],
                [coupling, self.pole_inertia + self.pole_mass * self.pole_com**2],
            ]
        )

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, theta = self._q(q)
        _, theta_d = self._v(qd)
        return np.array([[0.0, -self.pole_mass * self.pole_com * np.sin(theta) * theta_d], [0.0, 0.0]])

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, theta = self._q(q)
        _, theta_d = self._v(qd)
        return np.array([-self.pole_mass * self.pole_com * np.sin(theta) * theta_d**2, 0.0])

    def gravity(self, q: np.ndarray) -> np.ndarray:
        _, theta = self._q(q)
        return np.array([0.0, -self.pole_mass * self.gravity_acc * self.pole_com * np.sin(theta)])

    def potential_energy(self, q: np.ndarray) -> float:
        _, theta = self._q(q)
        z_pole = self.pivot_height + self.pole_com * np.cos(theta)
        z_cart = self.pivot_height + self.cart_com_offset
        return float(self.gravity_acc * (self.pole_mass * z_pole + self.cart_mass * z_cart))

    def actuation_matrix(self) -> np.ndarray:
        """Only the cart is driven (the URDF's ``pivot`` has zero effort)."""
        return np.array([[1.0], [0.0]])

    def pole_com_position(self, q: np.ndarray) -> np.ndarray:
        """World (x, z) of the pole's centre of mass."""
        x, theta = self._q(q)
        return np.array([x, self.pivot_height]) + rotate_y(theta, np.array([0.0, self.pole_com]))


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanarFloatingBody(AnalyticModel):
    """A free rigid body in the x–z plane, ``q = [x, z, θ]``, no actuation (3 DoF, nq = nv).

    ``(x, z)`` is the world position of the body-frame origin, ``θ`` its pitch about +y. The
    centre of mass sits at ``(com_x, com_z)`` in the body frame; ``r = rotate_y(θ, com)`` is its
    world offset from the origin and ``r⊥ = (r_z, −r_x) = ∂r/∂θ``. Then ``v_com = (ẋ, ż) + r⊥ θ̇``
    and ``∂r⊥/∂θ = −r``, giving

    ``M = [[m, 0, m r_z], [0, m, −m r_x], [m r_z, −m r_x, I + m|r|²]]``,
    ``C q̇ = [−m r_x θ̇², −m r_z θ̇², 0]`` (``C`` has only its last column, ``−m r θ̇``),
    ``g = [0, m g₀, −m g₀ r_x]``, ``V = m g₀ (z + r_z)``.
    With the CoM at the origin this is ``M = diag(m, m, I)``, ``C q̇ = 0``, ``g = [0, m g₀, 0]``.
    """

    mass: float = 2.0
    inertia: float = 0.05
    com_x: float = 0.0
    com_z: float = 0.0
    gravity_acc: float = STANDARD_GRAVITY

    nq: ClassVar[int] = 3
    nv: ClassVar[int] = 3

    def __post_init__(self) -> None:
        _check_positive(mass=self.mass, inertia=self.inertia)
        _check_non_negative(gravity_acc=self.gravity_acc)
        _check_finite(com_x=self.com_x, com_z=self.com_z)

    def _r(self, theta: float) -> np.ndarray:
        return rotate_y(theta, np.array([self.com_x, self.com_z]))

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        _, _, theta = self._q(q)
        m = self.mass
        rx, rz = self._r(theta)
        return np.array(
            [
                [m, 0.0, m * rz],
                [0.0, m, -m * rx],
                [m * rz, -m * rx, self.inertia + m * (rx**2 + rz**2)],
            ]
        )

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, _, theta = self._q(q)
        theta_d = self._v(qd)[2]
        out = np.zeros((3, 3))
        out[:2, 2] = -self.mass * self._r(theta) * theta_d
        return out

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        _, _, theta = self._q(q)
        theta_d = self._v(qd)[2]
        out = np.zeros(3)
        out[:2] = -self.mass * self._r(theta) * theta_d**2
        return out

    def gravity(self, q: np.ndarray) -> np.ndarray:
        _, _, theta = self._q(q)
        rx, _ = self._r(theta)
        mg = self.mass * self.gravity_acc
        return np.array([0.0, mg, -mg * rx])

    def potential_energy(self, q: np.ndarray) -> float:
        _, z, theta = self._q(q)
        return float(self.mass * self.gravity_acc * (z + self._r(theta)[1]))

    def actuation_matrix(self) -> np.ndarray:
        """No actuated coordinate: shape ``(3, 0)``."""
        return np.zeros((3, 0))


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanarFloatingArm(AnalyticModel):
    """Planar floating base plus one actuated revolute link, ``q = [x, z, θ, φ]`` (4 DoF).

    The smallest floating-base test case for a whole-body controller: three unactuated base
    coordinates (``x, z`` position of the base-frame origin, ``θ`` base pitch about +y) and one
    actuated joint ``φ`` about +y at ``(joint_x, joint_z)`` in the base frame. The link points
    along its own −z (``θ = φ = 0`` hangs it straight down, like a leg); its CoM is
    ``link_com`` down the link and its tip (``tip_position``, e.g. a foot) ``link_length``.

    Notation: ``ψ = θ + φ`` (link pitch), world offsets from the base origin
    ``r_b = rotate_y(θ, base_com)``, ``r_a = rotate_y(θ, joint)``, ``r_d = rotate_y(ψ, (0, −c))``,
    ``u = r_a + r_d`` (link CoM), ``⊥(r) = (r_z, −r_x)``, ``k = r_a,x r_d,z − r_a,z r_d,x``.
    CoM velocities: ``v_b = ṗ + ⊥(r_b) θ̇``, ``v_l = ṗ + ⊥(u) θ̇ + ⊥(r_d) φ̇``; so with
    ``m = m_b + m_l``::

        M = [[m,               0,                m_b r_bz + m_l u_z,      m_l r_dz],
             [0,               m,               −m_b r_bx − m_l u_x,     −m_l r_dx],
             [·,               ·,   I_b + I_l + m_b|r_b|² + m_l|u|²,  I_l + m_l u·r_d],
             [·,               ·,                                 ·,  I_l + m_l|r_d|²]]

        C q̇ = [−m_b θ̇² r_b − m_l (θ̇² r_a + ψ̇² r_d),  m_l k (ψ̇² − θ̇²),  −m_l k θ̇²]
        g   = [0,  m g₀,  −g₀ (m_b r_bx + m_l u_x),  −g₀ m_l r_dx]

    (the first entry of ``C q̇`` is the x–z pair). ``C = Σ m Jᵀ J̇`` over the two CoM Jacobians
    (angular Jacobians are constant in the plane), which makes ``Ṁ − 2C`` skew-symmetric.
    """

    base_mass: float = 3.0
    base_inertia: float = 0.06
    base_com_x: float = 0.0
    base_com_z: float = 0.0
    joint_x: float = 0.0
    joint_z: float = -0.1
    link_mass: float = 0.8
    link_com: float = 0.2
    link_inertia: float = 0.01
    link_length: float = 0.4
    gravity_acc: float = STANDARD_GRAVITY

    nq: ClassVar[int] = 4
    nv: ClassVar[int] = 4

    def __post_init__(self) -> None:
        _check_positive(base_mass=self.base_mass, base_inertia=self.base_inertia, link_mass=self.link_mass)
        _check_non_negative(link_inertia=self.link_inertia, gravity_acc=self.gravity_acc)
        _check_finite(
            base_com_x=self.base_com_x,
            base_com_z=self.base_com_z,
            joint_x=self.joint_x,
            joint_z=self.joint_z,
            link_com=self.link_com,
            link_length=self.link_length,
        )
        _check_positive(link_pivot_inertia=self.link_inertia + self.link_mass * self.link_com**2)

    def _offsets(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(r_b, r_a, r_d)`` world offsets (see the class docstring)."""
        _, _, theta, phi = self._q(q)
        r_b = rotate_y(theta, np.array([self.base_com_x, self.base_com_z]))
        r_a = rotate_y(theta, np.array([self.joint_x, self.joint_z]))
        r_d = rotate_y(theta + phi, np.array([0.0, -self.link_com]))
        return r_b, r_a, r_d

    def _com_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear (x, z) Jacobians of the base and link CoMs, each 2×4."""
        r_b, r_a, r_d = self._offsets(q)
        j_b = np.zeros((2, 4))
        j_l = np.zeros((2, 4))
        j_b[:, :2] = j_l[:, :2] = np.eye(2)
        j_b[:, 2] = _perp(r_b)
        j_l[:, 2] = _perp(r_a + r_d)
        j_l[:, 3] = _perp(r_d)
        return j_b, j_l

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        r_b, r_a, r_d = self._offsets(q)
        u = r_a + r_d
        mb, ml, il = self.base_mass, self.link_mass, self.link_inertia
        m = mb + ml
        m13 = mb * r_b[1] + ml * u[1]
        m23 = -mb * r_b[0] - ml * u[0]
        m14 = ml * r_d[1]
        m24 = -ml * r_d[0]
        m33 = self.base_inertia + il + mb * (r_b @ r_b) + ml * (u @ u)
        m34 = il + ml * (u @ r_d)
        m44 = il + ml * (r_d @ r_d)
        return np.array(
            [
                [m, 0.0, m13, m14],
                [0.0, m, m23, m24],
                [m13, m23, m33, m34],
                [m14, m24, m34, m44],
            ]
        )

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        qd = self._v(qd)
        theta_d, psi_d = qd[2], qd[2] + qd[3]
        r_b, r_a, r_d = self._offsets(q)
        j_b, j_l = self._com_jacobians(q)
        # Time derivatives of the Jacobians: d/dt ⊥(r) = −α̇ r for r rotating at rate α̇.
        jd_b = np.zeros((2, 4))
        jd_l = np.zeros((2, 4))
        jd_b[:, 2] = -theta_d * r_b
        jd_l[:, 2] = -theta_d * r_a - psi_d * r_d
        jd_l[:, 3] = -psi_d * r_d
        return self.base_mass * j_b.T @ jd_b + self.link_mass * j_l.T @ jd_l

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        qd = self._v(qd)
        theta_d, psi_d = qd[2], qd[2] + qd[3]
        r_b, r_a, r_d = self._offsets(q)
        mb, ml = self.base_mass, self.link_mass
        k = r_a[0] * r_d[1] - r_a[1] * r_d[0]
        out = np.empty(4)
        out[:2] = -mb * theta_d**2 * r_b - ml * (theta_d**2 * r_a + psi_d**2 * r_d)
        out[2] = ml * k * (psi_d**2 - theta_d**2)
        out[3] = -ml * k * theta_d**2
        return out

    def gravity(self, q: np.ndarray) -> np.ndarray:
        r_b, r_a, r_d = self._offsets(q)
        g0, mb, ml = self.gravity_acc, self.base_mass, self.link_mass
        return np.array(
            [
                0.0,
                (mb + ml) * g0,
                -g0 * (mb * r_b[0] + ml * (r_a[0] + r_d[0])),
                -g0 * ml * r_d[0],
            ]
        )

    def potential_energy(self, q: np.ndarray) -> float:
        z = self._q(q)[1]
        r_b, r_a, r_d = self._offsets(q)
        heights = self.base_mass * (z + r_b[1]) + self.link_mass * (z + r_a[1] + r_d[1])
        return float(self.gravity_acc * heights)

    def actuation_matrix(self) -> np.ndarray:
        """Only ``φ`` is actuated: ``τ = S u`` with ``S = [0, 0, 0, 1]ᵀ``."""
        return np.array([[0.0], [0.0], [0.0], [1.0]])

    def tip_position(self, q: np.ndarray) -> np.ndarray:
        """World (x, z) of the link tip (``link_length`` down the link)."""
        x, z, theta, phi = self._q(q)
        r_a = rotate_y(theta, np.array([self.joint_x, self.joint_z]))
        return np.array([x, z]) + r_a + rotate_y(theta + phi, np.array([0.0, -self.link_length]))

    def tip_jacobian(self, q: np.ndarray) -> np.ndarray:
        """2×4 Jacobian of ``tip_position``: ``[I₂, ⊥(r_a + r_t), ⊥(r_t)]``."""
        _, _, theta, phi = self._q(q)
        r_a = rotate_y(theta, np.array([self.joint_x, self.joint_z]))
        r_t = rotate_y(theta + phi, np.array([0.0, -self.link_length]))
        jac = np.zeros((2, 4))
        jac[:, :2] = np.eye(2)
        jac[:, 2] = _perp(r_a + r_t)
        jac[:, 3] = _perp(r_t)
        return jac
