"""Pytest-friendly assertions for dynamics models and controllers.

Anything with ``nq``, ``nv``, ``mass_matrix(q)``, ``coriolis(q, qd)`` (the vector ``C(q, q̇) q̇``)
and ``gravity(q)`` is a :class:`DynamicsModel`: the closed-form models in
``giwbc.testing.analytic``, a ``pinocchio.Model`` wrapped in :class:`PinocchioDynamics`, or a
user's own model. The helpers raise ``AssertionError`` with the worst mismatch and the full state
that produced it, so a failing test says *what* disagrees *where*.

Randomness: every helper takes a ``numpy.random.Generator`` (``np.random.default_rng(seed)``)
and draws only from it; nothing touches global random state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
import pinocchio as pin

__all__ = [
    "DynamicsModel",
    "PinocchioDynamics",
    "StateBatch",
    "random_states",
    "assert_dynamics_match",
    "assert_computed_torque",
    "assert_mass_matrix_spd",
    "assert_lagrangian_consistency",
    "assert_skew_symmetry",
    "assert_energy_conserved",
    "rk4_rollout",
]

ControllerFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@runtime_checkable
class DynamicsModel(Protocol):
    """What the comparison helpers need: ``M q̈ + C(q, q̇) q̇ + g(q) = τ``."""

    nq: int
    nv: int

    def mass_matrix(self, q: np.ndarray) -> np.ndarray: ...

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray: ...

    def gravity(self, q: np.ndarray) -> np.ndarray: ...


class PinocchioDynamics:
    """Adapter exposing a ``pinocchio.Model`` through the :class:`DynamicsModel` protocol.

    ``M`` from ``crba`` (symmetrized from its upper triangle), ``g`` from
    ``computeGeneralizedGravity``, ``C q̇ = rnea(q, q̇, 0) − g``, ``inverse_dynamics`` is ``rnea``,
    ``forward_dynamics`` is ``aba``. Owns one ``pinocchio.Data``, so an instance is not
    thread-safe; every result is copied out of it.
    """

    def __init__(self, model: pin.Model) -> None:
        self.model = model
        self.data = model.createData()

    def __repr__(self) -> str:
        return f"PinocchioDynamics({self.model.name or 'model'!s}, nq={self.nq}, nv={self.nv})"

    @property
    def nq(self) -> int:
        return int(self.model.nq)

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        upper = np.triu(pin.crba(self.model, self.data, np.asarray(q, dtype=float)))
        return upper + np.triu(upper, 1).T

    def gravity(self, q: np.ndarray) -> np.ndarray:
        return pin.computeGeneralizedGravity(self.model, self.data, np.asarray(q, dtype=float)).copy()

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        bias = pin.rnea(self.model, self.data, q, np.asarray(qd, dtype=float), np.zeros(self.nv)).copy()
        return bias - self.gravity(q)

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return pin.computeCoriolisMatrix(self.model, self.data, np.asarray(q, dtype=float), np.asarray(qd, dtype=float)).copy()

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        args = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
        return pin.rnea(self.model, self.data, *args).copy()

    def forward_dynamics(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        args = (np.asarray(x, dtype=float) for x in (q, qd, tau))
        return pin.aba(self.model, self.data, *args).copy()

    def potential_energy(self, q: np.ndarray) -> float:
        return float(pin.computePotentialEnergy(self.model, self.data, np.asarray(q, dtype=float)))

    def energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        q = np.asarray(q, dtype=float)
        kinetic = pin.computeKineticEnergy(self.model, self.data, q, np.asarray(qd, dtype=float))
        return float(kinetic) + self.potential_energy(q)

    def random_configuration(self, rng: np.random.Generator, scale: float = np.pi) -> np.ndarray:
        """``integrate(neutral, v)`` with ``v ~ U(−scale, scale)``: valid on any joint manifold
        (quaternions included) and equal to ``v`` itself for revolute/prismatic chains."""
        v = rng.uniform(-scale, scale, self.nv)
        return pin.integrate(self.model, pin.neutral(self.model), v)


class StateBatch(NamedTuple):
    """``n`` random states, one per row: ``q`` is ``(n, nq)``, ``qd`` and ``qdd`` are ``(n, nv)``."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def _require_generator(rng: object) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"pass a seeded numpy.random.Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
    return rng


def random_states(
    model: DynamicsModel,
    rng: np.random.Generator,
    n: int,
    *,
    q_scale: float = np.pi,
    qd_scale: float = 2.0,
    qdd_scale: float = 5.0,
) -> StateBatch:
    """Uniform random states: ``q ∈ [−q_scale, q_scale]`` (through ``model.random_configuration``
    when the model has one), ``q̇ ∈ [−qd_scale, qd_scale]``, ``q̈ ∈ [−qdd_scale, qdd_scale]``."""
    rng = _require_generator(rng)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    sampler = getattr(model, "random_configuration", None)
    if callable(sampler):
        q = np.stack([np.asarray(sampler(rng, q_scale), dtype=float) for _ in range(n)])
    else:
        q = rng.uniform(-q_scale, q_scale, (n, model.nq))
    qd = rng.uniform(-qd_scale, qd_scale, (n, model.nv))
    qdd = rng.uniform(-qdd_scale, qdd_scale, (n, model.nv))
    return StateBatch(q, qd, qdd)


# -- reporting ---------------------------------------------------------------------------------
def _fmt(x: np.ndarray | float) -> str:
    return np.array2string(np.asarray(x, dtype=float), precision=10, separator=", ", max_line_width=200)


def _label(model: object) -> str:
    return type(model).__name__ if not isinstance(model, PinocchioDynamics) else repr(model)


class _Worst:
    """Tracks the worst violation of ``|a − b| ≤ atol + rtol |b|`` over many comparisons."""

    def __init__(self, rtol: float, atol: float) -> None:
        self.rtol, self.atol = rtol, atol
        self.ratio = -np.inf
        self.report = ""

    def update(self, a: np.ndarray, b: np.ndarray, context: Callable[[], str]) -> None:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        if a.shape != b.shape:
            raise AssertionError(f"shape mismatch: {a.shape} vs {b.shape}\n{context()}")
        if a.size == 0:
            return
        err = np.abs(a - b)
        bound = self.atol + self.rtol * np.abs(b)
        ratio = np.where(np.isfinite(err), err / bound, np.inf)
        idx = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[idx] > self.ratio:
            self.ratio = float(ratio[idx])
            self.report = (
                f"worst entry {list(map(int, idx))}: {float(a[idx])!r} vs {float(b[idx])!r}, "
                f"|diff| = {err[idx]:.3e} (allowed {bound[idx]:.3e} = atol {self.atol:g} + rtol {self.rtol:g}·|ref|)\n"
                f"{context()}"
            )

    @property
    def failed(self) -> bool:
        return self.ratio > 1.0


def _state_text(index: int, n: int, **arrays: np.ndarray) -> str:
    lines = [f"state {index + 1}/{n}:"]
    lines += [f"  {name} = {_fmt(value)}" for name, value in arrays.items()]
    return "\n".join(lines)


# -- model vs model ----------------------------------------------------------------------------
def assert_dynamics_match(
    model_a: DynamicsModel,
    model_b: DynamicsModel,
    rng: np.random.Generator,
    n_states: int = 20,
    *,
    rtol: float = 1e-9,
    atol: float = 1e-9,
    check_forward: bool = True,
    check_energy: bool = False,
    **state_scales: float,
) -> None:
    """Assert ``M``, ``C(q, q̇) q̇`` and ``g`` (and, where both models have them,
    ``inverse_dynamics``, ``forward_dynamics`` and optionally ``energy``) agree at random states.

    ``model_b`` is the reference for the relative tolerance. Forward dynamics is checked at
    ``τ = M_a q̈ + C_a q̇ + g_a`` so torques have realistic size; both models must return ``q̈``.
    ``state_scales`` go to :func:`random_states`.
    """
    if (model_a.nq, model_a.nv) != (model_b.nq, model_b.nv):
        raise AssertionError(
            f"dimension mismatch: {_label(model_a)} has (nq, nv) = ({model_a.nq}, {model_a.nv}), "
            f"{_label(model_b)} has ({model_b.nq}, {model_b.nv})"
        )
    states = random_states(model_a, rng, n_states, **state_scales)
    both = lambda name: callable(getattr(model_a, name, None)) and callable(getattr(model_b, name, None))  # noqa: E731
    checks: dict[str, Callable[[DynamicsModel, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]] = {
        "mass matrix M(q)": lambda m, q, qd, qdd, tau: m.mass_matrix(q),
        "Coriolis vector C(q, qd) qd": lambda m, q, qd, qdd, tau: m.coriolis(q, qd),
        "gravity g(q)": lambda m, q, qd, qdd, tau: m.gravity(q),
    }
    if both("inverse_dynamics"):
        checks["inverse dynamics tau(q, qd, qdd)"] = lambda m, q, qd, qdd, tau: m.inverse_dynamics(q, qd, qdd)
    if check_forward and both("forward_dynamics"):
        checks["forward dynamics qdd(q, qd, tau)"] = lambda m, q, qd, qdd, tau: m.forward_dynamics(q, qd, tau)
    if check_energy and both("energy"):
        checks["energy E(q, qd)"] = lambda m, q, qd, qdd, tau: np.array(m.energy(q, qd))

    worst = {name: _Worst(rtol, atol) for name in checks}
    for i, (q, qd, qdd) in enumerate(zip(*states)):
        tau = model_a.mass_matrix(q) @ qdd + model_a.coriolis(q, qd) + model_a.gravity(q)
        context = lambda: _state_text(i, n_states, q=q, qd=qd, qdd=qdd, tau=tau)  # noqa: B023,E731
        for name, fn in checks.items():
            worst[name].update(fn(model_a, q, qd, qdd, tau), fn(model_b, q, qd, qdd, tau), context)
    failures = [f"{name}:\n  {w.report}" for name, w in worst.items() if w.failed]
    if failures:
        header = f"dynamics of {_label(model_a)} (a) and {_label(model_b)} (b, reference) disagree ({n_states} random states)"
        raise AssertionError(header + "\n" + "\n".join(failures))


def assert_computed_torque(
    controller_fn: ControllerFn,
    analytic_model: DynamicsModel,
    rng: np.random.Generator,
    n_states: int = 20,
    *,
    rtol: float = 1e-9,
    atol: float = 1e-9,
    **state_scales: float,
) -> None:
    """Assert ``controller_fn(q, q̇, q̈_des)`` equals the computed torque ``M q̈ + C q̇ + g``.

    On failure the message names the worst entry, the state, and — when the residual is one of
    the terms omitted, doubled or sign-flipped — which term the controller gets wrong.
    """
    states = random_states(analytic_model, rng, n_states, **state_scales)
    worst = _Worst(rtol, atol)
    for i, (q, qd, qdd) in enumerate(zip(*states)):
        terms = {
            "M(q) qdd": analytic_model.mass_matrix(q) @ qdd,
            "C(q, qd) qd": analytic_model.coriolis(q, qd),
            "g(q)": analytic_model.gravity(q),
        }
        expected = sum(terms.values())
        actual = np.asarray(controller_fn(q.copy(), qd.copy(), qdd.copy()), dtype=float)

        # Called at once by ``worst.update`` (only when this state is the new worst).
        def context() -> str:
            text = _state_text(i, n_states, q=q, qd=qd, qdd_des=qdd, tau_controller=actual, tau_expected=expected)  # noqa: B023
            if actual.shape == expected.shape:  # noqa: B023
                residual = actual - expected
                for term_name, term in terms.items():
                    scale = atol + rtol * np.abs(expected)
                    if np.any(np.abs(term) > scale):
                        for factor, verb in ((-1.0, "omits"), (1.0, "doubles"), (-2.0, "flips the sign of")):
                            if np.all(np.abs(residual - factor * term) <= scale):
                                text += f"\n  hint: the controller {verb} the {term_name} term"
            return text

        worst.update(actual, expected, context)
    if worst.failed:
        raise AssertionError(
            f"controller torque != M qdd + C qd + g of {_label(analytic_model)} ({n_states} random states)\n  {worst.report}"
        )


# -- physical consistency of one model ---------------------------------------------------------
def assert_mass_matrix_spd(model: DynamicsModel, rng: np.random.Generator, n_states: int = 20, *, rtol: float = 1e-12) -> None:
    """Assert ``M(q)`` is symmetric and positive definite at random configurations."""
    states = random_states(model, rng, n_states)
    for i, q in enumerate(states.q):
        mass = np.asarray(model.mass_matrix(q), dtype=float)
        scale = max(float(np.abs(mass).max()), np.finfo(float).tiny)
        asym = float(np.abs(mass - mass.T).max())
        if asym > rtol * scale:
            raise AssertionError(f"M(q) not symmetric: max |M − Mᵀ| = {asym:.3e}\n{_state_text(i, n_states, q=q)}\nM = {_fmt(mass)}")
        eig_min = float(np.linalg.eigvalsh(0.5 * (mass + mass.T)).min())
        if eig_min <= 0.0:
            raise AssertionError(f"M(q) not positive definite: min eigenvalue {eig_min:.3e}\n{_state_text(i, n_states, q=q)}\nM = {_fmt(mass)}")


def _directional_derivative(fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray, direction: np.ndarray, step: float) -> np.ndarray:
    """Central difference ``(f(x + h d) − f(x − h d)) / 2h``."""
    return (np.asarray(fn(x + step * direction)) - np.asarray(fn(x - step * direction))) / (2.0 * step)


def assert_lagrangian_consistency(
    model: DynamicsModel,
    rng: np.random.Generator,
    n_states: int = 10,
    *,
    step: float = 1e-5,
    rtol: float = 1e-6,
    atol: float = 1e-6,
) -> None:
    """Assert ``C q̇`` and ``g`` follow from ``M`` and ``V`` by Lagrange's equations.

    With ``L = ½ q̇ᵀ M(q) q̇ − V(q)``: ``g = ∇V`` and ``C q̇ = Ṁ q̇ − ½ ∇_q(q̇ᵀ M q̇)``, both by
    central finite differences. Needs ``model.potential_energy(q)``; only for ``nq == nv``
    models whose coordinates are plain vectors. This pins the hand-written ``C q̇`` and ``g`` to the
    hand-written ``M`` and ``V`` without trusting any other implementation.
    """
    if model.nq != model.nv:
        raise ValueError("finite differences in q need nq == nv")
    states = random_states(model, rng, n_states)
    eye = np.eye(model.nv)
    worst_g, worst_c = _Worst(rtol, atol), _Worst(rtol, atol)
    for i, (q, qd, _) in enumerate(zip(*states)):
        context = lambda: _state_text(i, n_states, q=q, qd=qd)  # noqa: B023,E731
        grad_v = np.array([_directional_derivative(model.potential_energy, q, e, step) for e in eye])
        worst_g.update(model.gravity(q), grad_v, context)
        m_dot = _directional_derivative(model.mass_matrix, q, qd, step)
        grad_ke = np.array([_directional_derivative(lambda x: qd @ model.mass_matrix(x) @ qd, q, e, step) for e in eye])  # noqa: B023
        worst_c.update(model.coriolis(q, qd), m_dot @ qd - 0.5 * grad_ke, context)
    failures = []
    if worst_g.failed:
        failures.append(f"g(q) != dV/dq:\n  {worst_g.report}")
    if worst_c.failed:
        failures.append(f"C(q, qd) qd != dM/dt qd - 1/2 d(qd' M qd)/dq:\n  {worst_c.report}")
    if failures:
        raise AssertionError(f"{_label(model)} violates Lagrange's equations\n" + "\n".join(failures))


def assert_skew_symmetry(
    model: DynamicsModel,
    rng: np.random.Generator,
    n_states: int = 10,
    *,
    step: float = 1e-6,
    atol: float = 1e-6,
) -> None:
    """Assert ``q̇ᵀ (Ṁ − 2C) q̇ = 0`` (``Ṁ`` by finite differences along ``q̇``).

    The scalar identity is the power balance ``d/dt T = q̇ᵀ(τ − g)`` and holds for any valid
    ``C q̇``. If the model has ``coriolis_matrix(q, qd)``, also assert ``C q̇`` equals
    ``coriolis(q, qd)`` and that the whole matrix ``Ṁ − 2C`` is skew-symmetric.
    """
    if model.nq != model.nv:
        raise ValueError("finite differences in q need nq == nv")
    states = random_states(model, rng, n_states)
    coriolis_matrix = getattr(model, "coriolis_matrix", None)
    for i, (q, qd, _) in enumerate(zip(*states)):
        m_dot = _directional_derivative(model.mass_matrix, q, qd, step)
        scale = 1.0 + float(np.abs(m_dot).max()) * float(qd @ qd)
        power = float(qd @ m_dot @ qd - 2.0 * qd @ model.coriolis(q, qd))
        if abs(power) > atol * scale:
            raise AssertionError(f"qdᵀ(Ṁ − 2C)qd = {power:.3e} != 0 for {_label(model)}\n{_state_text(i, n_states, q=q, qd=qd)}")
        if callable(coriolis_matrix):
            c_mat = np.asarray(coriolis_matrix(q, qd), dtype=float)
            mismatch = float(np.abs(c_mat @ qd - model.coriolis(q, qd)).max())
            if mismatch > atol * scale:
                raise AssertionError(f"coriolis_matrix(q, qd) @ qd != coriolis(q, qd) (max diff {mismatch:.3e})\n{_state_text(i, n_states, q=q, qd=qd)}")
            n_mat = m_dot - 2.0 * c_mat
            asym = float(np.abs(n_mat + n_mat.T).max())
            if asym > atol * scale:
                raise AssertionError(
                    f"Ṁ − 2C not skew-symmetric for {_label(model)}: max |N + Nᵀ| = {asym:.3e}\n"
                    f"{_state_text(i, n_states, q=q, qd=qd)}\nṀ − 2C = {_fmt(n_mat)}"
                )


# -- simulation --------------------------------------------------------------------------------
def rk4_rollout(
    model: DynamicsModel,
    q0: np.ndarray,
    qd0: np.ndarray,
    dt: float,
    n_steps: int,
    tau: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Classic RK4 on ``(q, q̇)`` with constant ``tau`` (zero by default), ``nq == nv`` only.

    Returns ``(qs, qds)`` of shape ``(n_steps + 1, nv)``, initial state included.
    """
    if model.nq != model.nv:
        raise ValueError("rk4_rollout integrates q additively: nq == nv only")
    tau = np.zeros(model.nv) if tau is None else np.asarray(tau, dtype=float)
    accel = model.forward_dynamics  # type: ignore[attr-defined]
    qs = np.empty((n_steps + 1, model.nv))
    qds = np.empty((n_steps + 1, model.nv))
    q, qd = np.asarray(q0, dtype=float).copy(), np.asarray(qd0, dtype=float).copy()
    qs[0], qds[0] = q, qd
    half = 0.5 * dt
    for k in range(n_steps):
        # Stage k evaluates (q̇_k, a_k); each position slope q̇_k is the previous stage's velocity.
        a1 = accel(q, qd, tau)
        qd2 = qd + half * a1
        a2 = accel(q + half * qd, qd2, tau)
        qd3 = qd + half * a2
        a3 = accel(q + half * qd2, qd3, tau)
        qd4 = qd + dt * a3
        a4 = accel(q + dt * qd3, qd4, tau)
        q = q + dt / 6.0 * (qd + 2.0 * qd2 + 2.0 * qd3 + qd4)
        qd = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        qs[k + 1], qds[k + 1] = q, qd
    return qs, qds


def assert_energy_conserved(
    model: DynamicsModel,
    q0: np.ndarray,
    qd0: np.ndarray,
    *,
    duration: float = 2.0,
    dt: float = 1e-3,
    rtol: float = 1e-6,
) -> float:
    """Simulate unforced with RK4 and assert the energy drift stays below ``rtol``.

    Drift is ``max_t |E(t) − E(0)|`` over ``max(|E(0)|, max_t T(t))`` (kinetic energy guards
    against ``E(0) ≈ 0``). Returns the relative drift. Needs ``forward_dynamics``, ``energy``
    and ``kinetic_energy``.
    """
    n_steps = int(round(duration / dt))
    qs, qds = rk4_rollout(model, q0, qd0, dt, n_steps)
    energies = np.array([model.energy(q, qd) for q, qd in zip(qs, qds)])  # type: ignore[attr-defined]
    kinetic = np.array([model.kinetic_energy(q, qd) for q, qd in zip(qs, qds)])  # type: ignore[attr-defined]
    scale = max(abs(float(energies[0])), float(kinetic.max()), np.finfo(float).tiny)
    deviation = np.abs(energies - energies[0])
    k = int(np.argmax(deviation))
    drift = float(deviation[k]) / scale
    if drift > rtol:
        raise AssertionError(
            f"energy of {_label(model)} drifts by {drift:.3e} (relative) > {rtol:g} in an unforced RK4 run "
            f"(dt = {dt:g}, worst at t = {k * dt:.4f} s: E = {energies[k]!r} vs E0 = {energies[0]!r})\n"
            f"  q0 = {_fmt(q0)}\n  qd0 = {_fmt(qd0)}"
        )
    return drift
