"""The QP data and its solver backends.

A :class:`QpProblem` is plain numpy, inspectable and solver-agnostic::

    minimise ½ xᵀ H x + gᵀ x   subject to   A x = b,   l ≤ C x ≤ u,   lb ≤ x ≤ ub (optional)

(``±inf`` marks a missing bound). Backends, by name (:func:`make_solver`):

* ``"proxsuite"`` (default, alias ``"proxqp"``) — one persistent ``proxsuite.proxqp.dense.QP``:
  ``init`` once per problem *structure*, then ``update`` in place and solve warm-started from
  the previous tick's primal-dual solution. The hot path never rebuilds the solver.
* ``"osqp"`` — one persistent ``osqp.OSQP``: ``setup`` once per sparsity pattern (the problem's
  structural masks ``H_pattern`` / ``AC_pattern``), then ``update(Px=…, Ax=…, q=…, l=…, u=…)``
  with the values gathered from the dense arrays by precomputed indices; OSQP warm-starts itself.
* any other name of ``qpsolvers.available_solvers`` (or ``"qpsolvers:<name>"``) — the generic,
  one-shot ``qpsolvers.solve_problem`` path, warm-started with ``initvals`` where supported. Not
  for the real-time loop.

``solve`` never raises on a numerical failure: it returns a :class:`QpSolution` whose
``status`` says what happened (the controller turns that into a safe fallback).
"""

from __future__ import annotations

import abc
import enum
import math
import time
from dataclasses import dataclass, field

import numpy as np

DEFAULT_SOLVER = "proxsuite"


class QpStatus(enum.Enum):
    SOLVED = "solved"
    INACCURATE = "solved_inaccurate"  # usable, below the solver's own accuracy target
    MAX_ITER = "max_iterations"
    PRIMAL_INFEASIBLE = "primal_infeasible"
    DUAL_INFEASIBLE = "dual_infeasible"
    FAILED = "failed"  # solver error or non-finite solution


USABLE = (QpStatus.SOLVED, QpStatus.INACCURATE)


@dataclass
class QpProblem:
    """``min ½xᵀHx + gᵀx  s.t.  Ax = b,  l ≤ Cx ≤ u,  lb ≤ x ≤ ub``, dense numpy arrays.

    ``H_pattern`` and ``AC_pattern`` (optional boolean masks of ``H`` and of ``[A; C]``) mark the
    entries that can ever be non-zero for this structure; sparse backends use them as their fixed
    sparsity pattern. ``structure`` is a token that changes whenever dimensions or patterns do.
    """

    H: np.ndarray
    g: np.ndarray
    A: np.ndarray
    b: np.ndarray
    C: np.ndarray
    l: np.ndarray
    u: np.ndarray
    lb: np.ndarray | None = None
    ub: np.ndarray | None = None
    H_pattern: np.ndarray | None = field(default=None, repr=False)
    AC_pattern: np.ndarray | None = field(default=None, repr=False)
    structure: int = 0

    @property
    def n(self) -> int:
        return self.H.shape[0]

    @property
    def n_eq(self) -> int:
        return self.A.shape[0]

    @property
    def n_in(self) -> int:
        return self.C.shape[0]

    @property
    def has_bounds(self) -> bool:
        return self.lb is not None

    def copy(self) -> "QpProblem":
        """A deep copy (a controller's problem arrays are overwritten at the next tick)."""
        copy = lambda a: None if a is None else np.array(a)  # noqa: E731
        return QpProblem(
            *(np.array(a) for a in (self.H, self.g, self.A, self.b, self.C, self.l, self.u)),
            copy(self.lb),
            copy(self.ub),
            copy(self.H_pattern),
            copy(self.AC_pattern),
            self.structure,
        )

    def validate(self) -> None:
        """``ValueError`` for inconsistent shapes or non-finite matrices (bounds may be ±inf)."""
        n = self.n
        expected = {"H": (n, n), "g": (n,), "A": (self.n_eq, n), "b": (self.n_eq,), "C": (self.n_in, n), "l": (self.n_in,), "u": (self.n_in,)}
        if self.lb is not None or self.ub is not None:
            expected.update(lb=(n,), ub=(n,))
        for name, shape in expected.items():
            value = getattr(self, name)
            if value is None or value.shape != shape:
                raise ValueError(f"QP {name} has shape {None if value is None else value.shape}, expected {shape}")
        for name in ("H", "g", "A", "b", "C"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"QP {name} is not finite")

    def objective(self, x: np.ndarray) -> float:
        return float(0.5 * x @ self.H @ x + self.g @ x)

    def violation(self, x: np.ndarray) -> float:
        """Largest constraint violation of ``x`` (equalities, inequalities and bounds)."""
        worst = float(np.max(np.abs(self.A @ x - self.b), initial=0.0))
        cx = self.C @ x
        worst = max(worst, float(np.max(self.l - cx, initial=0.0)), float(np.max(cx - self.u, initial=0.0)))
        if self.lb is not None and self.ub is not None:
            worst = max(worst, float(np.max(self.lb - x, initial=0.0)), float(np.max(x - self.ub, initial=0.0)))
        return worst


@dataclass
class QpSolution:
    """What a backend returns: the primal solution (NaN when none), a status and diagnostics."""

    x: np.ndarray
    status: QpStatus
    iterations: int = 0
    solver: str = ""
    message: str = ""
    solve_time: float = 0.0  # seconds, wall clock, update + solve

    @property
    def ok(self) -> bool:
        return self.status in USABLE


class QpSolver(abc.ABC):
    """A QP backend. Persistent backends keep their factorization/warm start between calls."""

    name = "abstract"

    @abc.abstractmethod
    def solve(self, problem: QpProblem) -> QpSolution:
        """Solve ``problem`` (re-initialising internally when its ``structure`` changed)."""

    def reset(self) -> None:
        """Forget any warm start (the next solve starts cold)."""

    def _failure(self, n: int, status: QpStatus, message: str, start: float, iterations: int = 0) -> QpSolution:
        return QpSolution(np.full(n, np.nan), status, iterations, self.name, message, time.perf_counter() - start)


# --- active-set guess ------------------------------------------------------------------------------
class ActiveSetGuess:
    """Solve the QP with last tick's active set as equalities and keep the result only if it is
    provably optimal.

    One dense KKT solve (LAPACK ``dgesv``) of ``[[H, Aᵀ, C_aᵀ], [A, 0, 0], [C_a, 0, 0]]`` with
    ``C_a`` the inequality rows active at the previous solution; the candidate is accepted when it
    satisfies every inequality (to ``tolerance``) and the multipliers of the active rows have the
    right signs — then all KKT conditions hold and, the QP being convex, the candidate *is* its
    optimum (to machine precision, tighter than the iterative solver). When it is not, up to
    ``steps − 1`` primal-dual active-set corrections are tried. The active set of a balance
    controller rarely changes from one tick to the next, so most ticks end here; when the guess
    fails the caller runs the full solver and hands its active set back (:meth:`learn`).
    Problems with variable bounds are not handled (always the full solver).
    """

    def __init__(self, tolerance: float = 1e-8, steps: int = 3) -> None:
        from scipy.linalg import lapack

        self.steps = int(steps)
        self._gesv = lapack.dgesv
        self.tolerance = float(tolerance)
        self.active = np.zeros(0, dtype=np.int64)
        self.upper = np.zeros(0, dtype=bool)
        self._buffers: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.hits = 0
        self.tries = 0

    def reset(self) -> None:
        self.active = np.zeros(0, dtype=np.int64)
        self.upper = np.zeros(0, dtype=bool)

    def learn(self, problem: QpProblem, x: np.ndarray, z: np.ndarray) -> None:
        """Active set of a solution from its inequality multipliers ``z`` (positive: upper bound)."""
        active = np.flatnonzero(np.abs(z) > 1e-10)
        self.active = active
        self.upper = z[active] > 0

    def try_solve(self, p: QpProblem) -> np.ndarray | None:
        """The optimum if last tick's active set — or one corrected by up to ``steps − 1``
        primal-dual active-set updates (add the violated rows, drop the rows whose multiplier has
        the wrong sign) — is provably optimal; else None (the caller runs the full solver)."""
        if p.lb is not None:
            return None
        self.tries += 1
        for _ in range(self.steps):
            x, violated, wrong = self._solve_active(p)
            if x is not None and violated is None:
                self.hits += 1
                return x
            if x is None:
                return None
            keep = np.ones(len(self.active), dtype=bool) if wrong is None else ~wrong
            new_rows, new_upper = violated
            self.active = np.concatenate([self.active[keep], new_rows])
            self.upper = np.concatenate([self.upper[keep], new_upper])
        return None

    def _solve_active(self, p: QpProblem) -> tuple[np.ndarray | None, tuple | None, np.ndarray | None]:
        """KKT solve with the current active set: ``(x, violated rows, wrong-sign mask)``;
        ``x`` is None when the system is singular."""
        n, ne, active = p.n, p.n_eq, self.active
        k = len(active)
        key = (n, ne, k)
        buffers = self._buffers.get(key)
        if buffers is None:
            buffers = self._buffers[key] = (np.zeros((n + ne + k, n + ne + k)), np.zeros(n + ne + k))
        K, rhs = buffers
        K[:n, :n] = p.H
        K[n:, n:] = 0.0
        K[n : n + ne, :n] = p.A
        K[:n, n : n + ne] = p.A.T
        np.negative(p.g, out=rhs[:n])
        rhs[n : n + ne] = p.b
        upper = self.upper
        if k:
            rows = p.C[active]
            K[n + ne :, :n] = rows
            K[:n, n + ne :] = rows.T
            rhs[n + ne :] = np.where(upper, p.u[active], p.l[active])
        # K is symmetric: its transpose is a Fortran-ordered view LAPACK factorises in place.
        _, _, solution, info = self._gesv(K.T, rhs, overwrite_a=1, overwrite_b=1)
        if info != 0:
            return None, None, None
        x = solution[:n]
        if not math.isfinite(float(x @ x)):
            return None, None, None
        tol = self.tolerance
        if ne and np.abs(p.A @ x - p.b).max() > 1e3 * tol:  # an ill-conditioned system: do not trust it
            return None, None, None
        wrong = None
        if k:
            multipliers = solution[n + ne :]
            wrong = np.where(upper, multipliers < -tol, multipliers > tol) & (p.l[active] != p.u[active])
            if not wrong.any():
                wrong = None
        cx = p.C @ x
        over, under = cx - p.u, p.l - cx
        if over.max(initial=-1.0) > tol or under.max(initial=-1.0) > tol:
            up = np.flatnonzero(over > tol)
            down = np.flatnonzero(under > tol)
            rows = np.concatenate([up, down])
            return np.array(x), (rows, np.concatenate([np.ones(len(up), bool), np.zeros(len(down), bool)])), wrong
        if wrong is not None:
            return np.array(x), (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)), wrong
        return np.array(x), None, None


# --- proxsuite -----------------------------------------------------------------------------------
class ProxsuiteSolver(QpSolver):
    """Persistent ``proxsuite.proxqp.dense.QP``, updated in place and warm-started every tick.

    Settings: ``eps_abs`` (default 1e-6), ``eps_rel`` (0), ``max_iter`` (bounds the worst case,
    default 300), ``backend`` (``"PrimalDualLDLT"``, measured fastest on the G1 problem with warm
    starts — fewer iterations than ``"PrimalLDLT"`` — or ``"Automatic"``), ``retry_cold`` (when a
    warm-started solve fails, re-initialise and solve once from scratch before reporting the
    failure: warm starts far from the new solution occasionally end in a spurious infeasibility
    verdict), ``active_set_guess`` (default True: first try last tick's active set with one KKT
    solve, see :class:`ActiveSetGuess`; proxsuite runs only when that is not provably optimal),
    plus any attribute of ``proxsuite.proxqp.Settings`` by name.
    """

    name = "proxsuite"

    def __init__(
        self,
        *,
        eps_abs: float = 1e-6,
        eps_rel: float = 0.0,
        max_iter: int = 300,
        backend: str = "PrimalDualLDLT",
        retry_cold: bool = True,
        active_set_guess: bool = True,
        **settings: object,
    ) -> None:
        import proxsuite

        self.retry_cold = retry_cold
        self.guess = ActiveSetGuess() if active_set_guess else None
        self._proxqp = proxsuite.proxqp
        self._settings = dict(eps_abs=eps_abs, eps_rel=eps_rel, max_iter=max_iter, verbose=False, **settings)
        self._backend = getattr(proxsuite.proxqp.dense.DenseBackend, backend)
        self.reset()
        out = proxsuite.proxqp.QPSolverOutput
        self._status = {
            out.PROXQP_SOLVED: QpStatus.SOLVED,
            out.PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE: QpStatus.INACCURATE,
            out.PROXQP_MAX_ITER_REACHED: QpStatus.MAX_ITER,
            out.PROXQP_PRIMAL_INFEASIBLE: QpStatus.PRIMAL_INFEASIBLE,
            out.PROXQP_DUAL_INFEASIBLE: QpStatus.DUAL_INFEASIBLE,
        }

    def reset(self) -> None:
        self._qp = None
        self._structure = None
        self._problem = None
        self._token = -1
        if getattr(self, "guess", None) is not None:
            self.guess.reset()

    def _init(self, p: QpProblem) -> None:
        dense = self._proxqp.dense
        qp = dense.QP(p.n, p.n_eq, p.n_in, p.has_bounds, dense.HessianType.Dense, self._backend)
        for key, value in self._settings.items():
            setattr(qp.settings, key, value)
        qp.settings.initial_guess = self._proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        if p.has_bounds:
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.u, p.lb, p.ub)
        else:
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.u)
        self._qp = qp

    def solve(self, problem: QpProblem) -> QpSolution:
        start = time.perf_counter()
        p = problem
        # Same problem object and structure token as last time: the hot path, no bookkeeping.
        cold = self._qp is None or p is not self._problem or p.structure != self._token
        guess = self.guess
        if guess is not None and not cold:
            x = guess.try_solve(p)
            if x is not None:
                return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start)
        if cold:
            key = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
            cold = self._qp is None or key != self._structure
        try:
            if cold:
                # First tick, new structure, or recovering from a failure: a cold init.
                self._init(p)
                self._structure = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
                self._qp.solve()
            else:
                if p.lb is not None:
                    self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u, p.lb, p.ub)
                else:
                    self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u)
                self._qp.solve()
        except Exception as error:  # proxsuite raises on malformed input; never inside the loop
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start)
        self._problem, self._token = p, p.structure
        status, iterations = self._status_of(self._qp.results)
        if status not in USABLE and self.retry_cold and not cold:
            # A warm start from a far-away previous solution can make proxsuite stall or
            # report a spurious infeasibility: retry once from scratch before giving up.
            try:
                self._init(p)
                self._qp.solve()
            except Exception as error:
                self.reset()
                return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start)
            status, more = self._status_of(self._qp.results)
            iterations += more
        if status not in USABLE:
            self.reset()  # do not warm-start from a failed solve
            return self._failure(p.n, status, f"proxsuite: {status.value}", start, iterations)
        results = self._qp.results
        x = np.array(results.x)
        if guess is not None:
            guess.learn(p, x, results.z)
        return QpSolution(x, status, iterations, self.name, "", time.perf_counter() - start)

    def _status_of(self, results: object) -> tuple[QpStatus, int]:
        info = results.info  # type: ignore[attr-defined]
        status = self._status.get(info.status, QpStatus.FAILED)
        if status in USABLE:
            x = results.x  # type: ignore[attr-defined]
            if not math.isfinite(float(x @ x)):
                status = QpStatus.FAILED
        return status, int(info.iter)


# --- osqp ------------------------------------------------------------------------------------------
def _csc_structure(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(indices, indptr, flat)`` of a CSC matrix with the entries of a boolean mask, and the
    flat (row-major) positions of those entries in the dense matrix, in CSC order."""
    cols, rows = np.nonzero(mask.T)  # column-major order: sorted by column, then row
    indptr = np.zeros(mask.shape[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(cols, minlength=mask.shape[1]), out=indptr[1:])
    return rows.astype(np.int64), indptr, rows * mask.shape[1] + cols


class OsqpSolver(QpSolver):
    """Persistent ``osqp.OSQP`` (ADMM), updated in place, warm-started by OSQP itself.

    The sparsity pattern is fixed at setup from the problem's structural masks; ``Px``/``Ax`` are
    gathered from the dense ``H`` and ``[A; C]`` with precomputed indices each tick. Bounds
    ``lb ≤ x ≤ ub`` become identity rows. Settings are OSQP's (defaults here: ``eps_abs`` =
    ``eps_rel`` = 1e-6, polishing on — it makes active constraints exact — ``max_iter`` 4000).
    ``active_set_guess`` (default True) puts the same :class:`ActiveSetGuess` in front of OSQP
    as in front of proxsuite.
    """

    name = "osqp"

    def __init__(self, *, active_set_guess: bool = True, **settings: object) -> None:
        import osqp
        import scipy.sparse

        self.guess = ActiveSetGuess() if active_set_guess else None
        self._osqp = osqp
        self._sparse = scipy.sparse
        defaults = dict(eps_abs=1e-6, eps_rel=1e-6, polishing=True, max_iter=4000, verbose=False, warm_starting=True)
        defaults.update(settings)
        self._settings = defaults
        self._solver = None
        self._structure: tuple | None = None

        def constant(name: str) -> int:
            return int(getattr(osqp.SolverStatus, name).value)

        self._status = {
            constant("OSQP_SOLVED"): QpStatus.SOLVED,
            constant("OSQP_SOLVED_INACCURATE"): QpStatus.INACCURATE,
            constant("OSQP_MAX_ITER_REACHED"): QpStatus.MAX_ITER,
            constant("OSQP_PRIMAL_INFEASIBLE"): QpStatus.PRIMAL_INFEASIBLE,
            constant("OSQP_PRIMAL_INFEASIBLE_INACCURATE"): QpStatus.PRIMAL_INFEASIBLE,
            constant("OSQP_DUAL_INFEASIBLE"): QpStatus.DUAL_INFEASIBLE,
            constant("OSQP_DUAL_INFEASIBLE_INACCURATE"): QpStatus.DUAL_INFEASIBLE,
        }

    def reset(self) -> None:
        self._solver = None
        self._structure = None
        if self.guess is not None:
            self.guess.reset()

    def _setup(self, p: QpProblem) -> None:
        n, m_ac = p.n, p.n_eq + p.n_in
        h_mask = np.ones((n, n), dtype=bool) if p.H_pattern is None else p.H_pattern.copy()
        h_mask |= np.eye(n, dtype=bool)  # keep the diagonal (OSQP adds sigma there anyway)
        h_mask = np.triu(h_mask)
        ac_mask = np.ones((m_ac, n), dtype=bool) if p.AC_pattern is None else p.AC_pattern
        if p.has_bounds:
            ac_mask = np.vstack([ac_mask, np.eye(n, dtype=bool)])
        h_indices, h_indptr, self._h_flat = _csc_structure(h_mask)
        a_indices, a_indptr, a_flat = _csc_structure(ac_mask)
        # Entries of [A; C] versus the constant identity rows of the bounds.
        from_ac = a_indices < m_ac
        self._a_from_ac = np.flatnonzero(from_ac)
        self._a_flat = a_flat[from_ac]
        self._ax = np.ones(len(a_indices))
        self._px = np.empty(len(h_indices))
        self._ac = np.empty((m_ac, n))
        self._q = np.empty(n)
        m = m_ac + (n if p.has_bounds else 0)
        self._l = np.empty(m)
        self._u = np.empty(m)
        self._gather(p)
        P = self._sparse.csc_matrix((self._px.copy(), h_indices, h_indptr), shape=(n, n))
        A = self._sparse.csc_matrix((self._ax.copy(), a_indices, a_indptr), shape=(m, n))
        solver = self._osqp.OSQP()
        solver.setup(P, self._q, A, self._l, self._u, **self._settings)
        self._solver = solver

    def _gather(self, p: QpProblem) -> None:
        ac = self._ac
        ac[: p.n_eq] = p.A
        ac[p.n_eq :] = p.C
        np.take(p.H, self._h_flat, out=self._px)
        self._ax[self._a_from_ac] = np.take(ac, self._a_flat)
        self._q[:] = p.g
        ne, mi = p.n_eq, p.n_eq + p.n_in
        self._l[:ne] = p.b
        self._u[:ne] = p.b
        self._l[ne:mi] = p.l
        self._u[ne:mi] = p.u
        if p.has_bounds:
            self._l[mi:] = p.lb
            self._u[mi:] = p.ub

    def solve(self, problem: QpProblem) -> QpSolution:
        start = time.perf_counter()
        p = problem
        key = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
        guess = self.guess
        if guess is not None and self._solver is not None and key == self._structure:
            x = guess.try_solve(p)
            if x is not None:
                return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start)
        try:
            if self._solver is None or key != self._structure:
                self._setup(p)
                self._structure = key
            else:
                self._gather(p)
                self._solver.update(q=self._q, l=self._l, u=self._u, Px=self._px, Ax=self._ax)
            result = self._solver.solve(raise_error=False)
        except Exception as error:
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"osqp error: {error}", start)
        status = self._status.get(int(result.info.status_val), QpStatus.FAILED)
        x = result.x
        if status in USABLE and (x is None or not np.all(np.isfinite(x))):
            status = QpStatus.FAILED
        if status not in USABLE:
            self.reset()
            return self._failure(p.n, status, f"osqp: {result.info.status}", start, int(result.info.iter))
        if guess is not None:
            # OSQP's multipliers of [A; C; bounds]: positive at an upper bound, negative at a lower.
            guess.learn(p, x, result.y[p.n_eq : p.n_eq + p.n_in])
        return QpSolution(np.array(x), status, int(result.info.iter), self.name, "", time.perf_counter() - start)


# --- generic qpsolvers path ------------------------------------------------------------------------
class QpsolversSolver(QpSolver):
    """Any backend of ``qpsolvers`` through its one-shot ``solve_problem`` (not for real time).

    ``l ≤ Cx ≤ u`` becomes ``G x ≤ h`` rows for the finite bounds; the previous solution is
    passed as ``initvals``.
    """

    def __init__(self, solver: str, **settings: object) -> None:
        import qpsolvers

        if solver not in qpsolvers.available_solvers:
            raise ValueError(f"qpsolvers backend {solver!r} is not installed; available: {qpsolvers.available_solvers}")
        self._qpsolvers = qpsolvers
        self.name = solver
        self._settings = settings
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        self._previous = None

    def solve(self, problem: QpProblem) -> QpSolution:
        start = time.perf_counter()
        p = problem
        upper, lower = np.isfinite(p.u), np.isfinite(p.l)
        G = np.vstack([p.C[upper], -p.C[lower]])
        h = np.concatenate([p.u[upper], -p.l[lower]])
        lb = None if p.lb is None else np.where(np.isfinite(p.lb), p.lb, -1e20)
        ub = None if p.ub is None else np.where(np.isfinite(p.ub), p.ub, 1e20)
        qp = self._qpsolvers.Problem(p.H, p.g, G if len(h) else None, h if len(h) else None, p.A if p.n_eq else None, p.b if p.n_eq else None, lb, ub)
        initvals = self._previous if self._previous is not None and len(self._previous) == p.n else None
        try:
            solution = self._qpsolvers.solve_problem(qp, solver=self.name, initvals=initvals, **self._settings)
        except Exception as error:
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"{self.name} error: {error}", start)
        x = solution.x
        if not solution.found or x is None or not np.all(np.isfinite(x)):
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"{self.name}: no solution found", start)
        self._previous = np.array(x)
        return QpSolution(np.array(x), QpStatus.SOLVED, 0, self.name, "", time.perf_counter() - start)


def available_solvers() -> list[str]:
    """Names :func:`make_solver` accepts on this machine."""
    import qpsolvers

    names = ["proxsuite", "osqp"]
    return names + [name for name in qpsolvers.available_solvers if name not in ("proxqp", "osqp")]


def make_solver(name: str = DEFAULT_SOLVER, **settings: object) -> QpSolver:
    """A QP backend by name: ``proxsuite`` (``proxqp``), ``osqp``, or ``qpsolvers:<name>``."""
    key = name.lower()
    if key in ("proxsuite", "proxqp"):
        return ProxsuiteSolver(**settings)  # type: ignore[arg-type]
    if key == "osqp":
        return OsqpSolver(**settings)
    if key.startswith("qpsolvers:"):
        return QpsolversSolver(key.split(":", 1)[1], **settings)
    import qpsolvers

    if key in qpsolvers.available_solvers:
        return QpsolversSolver(key, **settings)
    raise ValueError(f"unknown QP solver {name!r}; available: {available_solvers()}")
