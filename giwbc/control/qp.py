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
    # ``[A; C] x`` when the backend computed it on the way (the KKT answers): the controller
    # reads its torques there. A view of the backend's buffer, valid until its next solve.
    rows: np.ndarray | None = field(default=None, repr=False)

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


# --- active-set guess and polish -------------------------------------------------------------------
class ActiveSetGuess:
    """Exact solutions of the QP from a guess of its active set, checked for optimality.

    One dense KKT solve (LAPACK ``dgesv``) of ``[[H, Aᵀ, C_aᵀ], [A, 0, 0], [C_a, 0, 0]]`` with
    ``C_a`` the inequality rows of the active set (variable bounds count as identity rows after
    the rows of ``C``); the candidate is accepted when it satisfies every inequality (to
    ``tolerance``), the equalities (to ``tolerance`` too: an ill-conditioned system is not
    trusted) and the multipliers of the active rows have the right signs — then all KKT
    conditions hold and, the QP being convex, the candidate *is* its optimum (to machine
    precision, tighter than an iterative solver). When it is not, up to ``steps − 1`` primal-dual
    active-set corrections (add the violated rows, drop the rows whose multiplier has the wrong
    sign) are tried.

    Two uses:

    * :meth:`try_solve` — *before* the backend, with last tick's active set: the active set of a
      balance controller rarely changes from one tick to the next, so most ticks end here;
    * :meth:`polish` — *after* the backend, from the rows tight at its (approximate) solution,
      with ``polish_steps`` regularised KKT solves: the answer becomes the exact optimum computed
      by the same deterministic KKT solve; :meth:`settle` is the fallback when no provably
      optimal active set is found (degenerate, nearly infeasible problems). This is what makes
      the proxsuite backend bit-reproducible: proxsuite's own iterates differ in the last bits
      from run to run (its Eigen kernels are vectorised differently depending on the alignment
      of its internal buffers), while the numpy/LAPACK operations here give identical results
      whatever the alignment of their operands (measured, and tested), and the backend's bits
      only enter through discrete decisions (which side of a threshold a row's slack falls).
      The active set is kept sorted, so the KKT system of a given active set is always the same.

    The active set found (by either) is the next tick's guess. ``hits``/``tries`` count the
    guesses, ``polished``/``polish_failures`` the polishes: diagnostics, not reset by
    :meth:`reset`. :attr:`rows` holds ``[A; C] x`` of the last answer (the controller reads its
    torques there).
    """

    def __init__(self, tolerance: float = 1e-8, steps: int = 3, polish_steps: int = 4, threshold: float = 1e-10) -> None:
        from scipy.linalg import lapack

        self.steps = int(steps)
        self.polish_steps = int(polish_steps)
        self.tolerance = float(tolerance)
        self.threshold = float(threshold)  # |multiplier| above which a backend's row counts as active
        self._gesv = lapack.dgesv
        self._layout: tuple | None = None
        self._prepared: QpProblem | None = None
        self._prepared_structure = -1
        self._prepared_arrays: tuple = (None, None, None, None)
        self.hits = 0
        self.tries = 0
        self.polished = 0
        self.polish_failures = 0
        self.reset()

    def reset(self) -> None:
        """Forget the active set (the next :meth:`try_solve` starts from an empty one)."""
        self._set_active(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))

    def _set_active(self, active: np.ndarray, upper: np.ndarray) -> None:
        order = np.argsort(active, kind="stable")
        self.active = np.ascontiguousarray(active[order], dtype=np.int64)
        self.upper = np.ascontiguousarray(upper[order], dtype=bool)
        self._stale = True  # per-active-set vectors to recompute

    @property
    def rows(self) -> np.ndarray:
        """``[A; C; I] x`` of the last answer (a view, overwritten by the next solve)."""
        return self._r

    def learn(self, problem: QpProblem, x: np.ndarray, z: np.ndarray) -> None:
        """Active set of a solution from its inequality multipliers ``z`` (rows of ``C``, then
        the variable bounds; positive: upper bound)."""
        active = np.flatnonzero(np.abs(z) > self.threshold)
        self._set_active(active, z[active] > 0)

    # --- per-tick preparation --------------------------------------------------------------------
    def _prepare(self, p: QpProblem) -> None:
        """Stacked ``[A; C; I]`` rows and their bounds for this tick (views when the problem's
        ``A`` and ``C`` are adjacent in one buffer, as the controller lays them out)."""
        arrays = self._prepared_arrays
        if p is self._prepared and p.A is arrays[0] and p.C is arrays[1] and p.l is arrays[2] and p.u is arrays[3] and p.structure == self._prepared_structure:
            # The same problem and arrays as last time (the controller's, refilled every tick).
            np.copyto(self._eq_limits, p.b)
            pair = self._lu_source[2]
            if pair is not None:
                np.copyto(self._in_limits, pair)
            else:
                self._in_limits[0] = p.l
                self._in_limits[1] = p.u
            if self._rows is not None:
                self._fill_rows(p)
            return
        n, ne, ni = p.n, p.n_eq, p.n_in
        bounds = p.lb is not None
        key = (n, ne, ni, bounds)
        if key != self._layout:
            m = ni + (n if bounds else 0)  # inequality rows, bounds included
            adjacent = (
                not bounds
                and ne > 0
                and p.A.flags.c_contiguous
                and p.C.flags.c_contiguous
                and p.A.ctypes.data + p.A.nbytes == p.C.ctypes.data
            )
            self._adjacent = adjacent
            self._rows = None if adjacent else np.zeros((ne + m, n))
            if bounds:
                self._rows[ne + ni :] = np.eye(n)  # type: ignore[index]
            self._m = m
            self._limits = np.zeros(2 * (ne + m))  # [lower; upper] limits of [A; C; I] x
            self._lo = self._limits[: ne + m]  # (equality rows: b in both)
            self._hi = self._limits[ne + m :]
            pair = self._limits.reshape(2, ne + m)
            self._eq_limits = pair[:, :ne]  # (2, ne) view: lower and upper limits of the equalities
            self._in_limits = pair[:, ne : ne + ni]
            self._r = np.zeros(ne + m)  # [A; C; I] x
            self._check = np.zeros(2 * (ne + m) + m)  # violations (both sides) and signed multipliers
            self._kkt: dict[int, tuple[np.ndarray, np.ndarray]] = {}
            self._layout = key
            self._source = (None, None)
            self._lu_source = (None, None, None)
            self._set_active(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))
        if self._adjacent:
            if self._source[0] is not p.A:  # a view spanning A and C (they are adjacent)
                self._source = (p.A, np.lib.stride_tricks.as_strided(p.A, shape=(ne + ni, n), strides=p.A.strides, writeable=False))
            self._stack = self._source[1]
        else:
            self._stack = self._rows
            self._fill_rows(p)
        np.copyto(self._eq_limits, p.b)
        l, u = p.l, p.u
        source = self._lu_source
        if source[0] is not l or source[1] is not u:  # a (2, n_in) view when l and u are adjacent (the controller's)
            adjacent = ni and l.flags.c_contiguous and u.flags.c_contiguous and u.ctypes.data - l.ctypes.data == l.nbytes
            pair = np.lib.stride_tricks.as_strided(l, shape=(2, ni), strides=(l.nbytes, l.itemsize), writeable=False) if adjacent else None
            source = self._lu_source = (l, u, pair)
        if source[2] is not None:
            self._in_limits[...] = source[2]
        else:
            self._in_limits[0] = l
            self._in_limits[1] = u
        self._prepared, self._prepared_structure = p, p.structure
        self._prepared_arrays = (p.A, p.C, p.l, p.u)

    def _fill_rows(self, p: QpProblem) -> None:
        """Copy ``A``, ``C`` and the bounds into the guess's own stacked buffers."""
        ne, ni = p.n_eq, p.n_in
        rows = self._rows
        rows[:ne] = p.A  # type: ignore[index]
        rows[ne : ne + ni] = p.C  # type: ignore[index]
        if p.lb is not None:
            self._lo[ne + ni :] = p.lb
            self._hi[ne + ni :] = p.ub

    def _refresh_active(self, p: QpProblem) -> None:
        """Vectors of the current active set (stacked row indices, right-hand-side indices,
        signs) and the views of its KKT buffers."""
        n, ne = p.n, p.n_eq
        active, upper = self.active, self.upper
        k = len(active)
        self._eq_rows = np.concatenate([np.arange(ne), ne + active])
        # The right-hand side of [A; C_a]: b, then the active bound of each row, from _limits.
        self._rhs_index = np.concatenate([np.arange(ne), np.where(upper, len(self._lo) + ne + active, ne + active)])
        # Multiplier signs, negated: − at an upper bound, + at a lower one, none for an equality row.
        same = self._lo[ne + active] + 0.0 == self._hi[ne + active]
        self._sign = np.where(same, 0.0, np.where(upper, -1.0, 1.0))
        if k not in self._kkt:
            size = n + ne + k
            K, rhs = np.zeros((size, size)), np.zeros(size)
            E = K[n:, :n]
            rows = len(self._r)
            check = self._check
            self._kkt[k] = (
                K, rhs, K.T, K[:n, :n], E, E.T, K[:n, n:], K[n:, n:],
                rhs[:n], rhs[n:], check[:rows], check[rows : 2 * rows], check[2 * rows : 2 * rows + k], check[: 2 * rows + k],
            )
        self._views = self._kkt[k]
        self._stale = False

    # --- the solve ---------------------------------------------------------------------------------
    def try_solve(self, p: QpProblem) -> np.ndarray | None:
        """The optimum if last tick's active set — or one corrected by up to ``steps − 1``
        primal-dual active-set updates — is provably optimal; else None (run the backend)."""
        self.tries += 1
        self._prepare(p)
        x = self._iterate(p, self.steps)
        if x is not None:
            self.hits += 1
        return x

    def polish(self, p: QpProblem, x: np.ndarray, slack: float = 1e-5) -> np.ndarray | None:
        """The exact optimum from an approximate solution ``x`` (a backend's): the rows within
        ``slack`` of a bound at ``x`` are the first active set, corrected by up to
        ``polish_steps − 1`` active-set updates (a row tight at ``x`` but inactive at the
        optimum has a wrong-sign multiplier and is dropped); None when no provably optimal
        active set is found (an infeasible or degenerate problem). The answer depends on ``x``
        only through which side of ``slack`` each row's slack falls — not on the backend's
        multipliers, which are far less reproducible near degenerate vertices."""
        self._tight(p, x, slack)
        # Rows tight at an approximate point are often linearly dependent (several faces of a
        # wrench cone at one vertex): every polish solve is regularised.
        x = self._iterate(p, self.polish_steps, regularized=True)
        if x is None:
            self.polish_failures += 1
        else:
            self.polished += 1
        return x

    def settle(self, p: QpProblem, x: np.ndarray, slack: float = 1e-5, feasibility: float = 1e-6) -> np.ndarray | None:
        """A point computed from ``x`` (an approximate solution, e.g. a backend's) through
        discrete decisions only: the rows within ``slack`` of a bound at ``x`` become the
        active set, and the answer is the KKT solution of that set — the optimum of the QP with
        those rows as equalities, the QP's own optimum when the set is right — if it satisfies
        every constraint to ``feasibility``; else None. Multiplier signs are not checked: where
        :meth:`polish` found no provably optimal active set (degenerate or nearly infeasible
        problems), this is a point within the backend's accuracy whose bits depend on ``x``
        only through which side of ``slack`` each row's slack falls."""
        active = self._tight(p, x, slack)
        for regularize in (False, True):
            y = self._solve_active(p, regularize, optimal=False, tol=feasibility)
            if y is not None:
                return y  # type: ignore[return-value]
        return None

    def _tight(self, p: QpProblem, x: np.ndarray, slack: float) -> np.ndarray:
        """Make the rows within ``slack`` of a bound at ``x`` the active set (sorted)."""
        self._prepare(p)
        ne = p.n_eq
        r = self._r
        np.dot(self._stack, np.asarray(x, dtype=float), out=r)
        above = (self._hi[ne:] - r[ne:]) <= slack
        below = (r[ne:] - self._lo[ne:]) <= slack
        active = np.flatnonzero(above | below)
        self._set_active(active, above[active])
        return active

    def _iterate(self, p: QpProblem, steps: int, regularized: bool = False) -> np.ndarray | None:
        """Up to ``steps`` KKT solves (each correction or regularised re-solve is one);
        ``regularized``: every solve regularised (see :meth:`_solve_active`)."""
        regularize = regularized
        for _ in range(steps):
            x = self._solve_active(p, regularize)
            if x is None:
                if regularize:
                    return None
                regularize = True  # singular: once more, regularised, with the same active set
            elif x is False:
                regularize = regularized
            else:
                return x
        return None

    def _solve_active(self, p: QpProblem, regularize: bool = False, optimal: bool = True, tol: float | None = None) -> np.ndarray | None | bool:
        """KKT solve with the current active set: the optimum, ``False`` after correcting the
        active set, or None (singular or ill-conditioned system: give up). ``optimal=False``:
        no multiplier check and no correction (a feasible point of the active set or None).

        ``regularize``: ``−δ I`` in the multiplier block, for a singular system (linearly
        dependent rows: a degenerate vertex, e.g. several faces of a contact wrench cone meeting
        at an edge, or the zeroed motion rows of a broken contact): dependent rows then share
        their multiplier, and the candidate violates them by ``δ |λ|`` (δ = 1e-4 · tolerance),
        well inside the tolerance it is checked against.
        """
        if self._stale:
            self._refresh_active(p)
        n, ne = p.n, p.n_eq
        k = len(self.active)
        stack = self._stack
        K, rhs, KT, K_H, K_E, K_ET_source, K_ET, K_Z, rhs_g, rhs_e, over, under, signed, checked = self._views
        # K is overwritten by the factorisation: every block is written again.
        np.copyto(K_H, p.H)
        stack.take(self._eq_rows, axis=0, out=K_E, mode="clip")  # (the method: no Python wrapper)
        np.copyto(K_ET, K_ET_source)
        K_Z.fill(0.0)
        if regularize:
            K_Z.flat[:: ne + k + 1] = -1e-4 * self.tolerance
        np.negative(p.g, out=rhs_g)
        self._limits.take(self._rhs_index, out=rhs_e, mode="clip")
        # K is symmetric: its transpose is a Fortran-ordered view LAPACK factorises in place.
        # (Eliminating the diagonal force block first makes the LU 12 rows smaller, 25 → 19 µs,
        # but costs eight more numpy calls than it saves: measured slower.)
        _, _, solution, info = self._gesv(KT, rhs, overwrite_a=1, overwrite_b=0)
        if info != 0:
            return None
        x = solution[:n]
        tol = self.tolerance if tol is None else tol
        r, check = self._r, self._check
        rows = len(r)
        np.dot(stack, x, out=r)
        np.subtract(r, self._hi, out=over)
        np.subtract(self._lo, r, out=under)
        if not optimal:
            checked = check[: 2 * rows]
            k = 0
        elif k:
            np.multiply(solution[n + ne :], self._sign, out=signed)
        worst = float(checked[checked.argmax()]) if rows or k else -math.inf  # (argmax: 4× faster than max)
        if worst <= tol:
            return x
        if not math.isfinite(worst) or (ne and max(check[:ne].max(), check[rows : rows + ne].max()) > tol):
            return None  # not finite, or the equalities do not hold: do not trust this system
        if not optimal:
            return None
        # Primal-dual active-set update: drop the wrong-sign rows, add the violated ones.
        keep = check[2 * rows : 2 * rows + k] <= tol
        violated = check[: 2 * rows].reshape(2, rows)[:, ne:] > tol  # rows: above, below
        violated[:, self.active] = False  # an active row stays (regularised solves bend them slightly)
        up = np.flatnonzero(violated[0])
        down = np.flatnonzero(violated[1])
        self._set_active(
            np.concatenate([self.active[keep], up, down]),
            np.concatenate([self.upper[keep], np.ones(len(up), dtype=bool), np.zeros(len(down), dtype=bool)]),
        )
        return False


# --- proxsuite -----------------------------------------------------------------------------------
class ProxsuiteSolver(QpSolver):
    """Persistent ``proxsuite.proxqp.dense.QP``, updated in place and warm-started every tick.

    Settings: ``eps_abs`` (default 1e-6), ``eps_rel`` (0), ``backend`` (``"PrimalDualLDLT"``,
    measured fastest on the G1 problem with warm starts, or ``"Automatic"``), plus any attribute
    of ``proxsuite.proxqp.Settings`` by name, and:

    * ``max_iter`` (default 10) and ``max_iter_in`` (default 10) — the **hard bound** of a tick.
      proxsuite 0.8 runs up to ``max_iter`` *outer* (proximal / BCL) iterations, each with up to
      ``max_iter_in`` *inner* semi-smooth Newton iterations (its default: 1500), and reports the
      inner ones in ``info.iter``: ``max_iter`` alone bounds nothing useful (a falling robot's QP
      ran 4734 inner iterations, 0.8 s, under ``max_iter=300``; an infeasible one 13 million,
      270 s, under proxsuite's defaults). Here ``max_iter`` is the budget of outer iterations of
      the whole tick, cold retry included, so a tick runs at most ``max_iter × (max_iter_in + 1)``
      inner ones (110: 2–5 ms on the G1 problem), plus at most ``steps + 2 · polish_steps`` KKT
      solves (:class:`ActiveSetGuess`, ~50 µs each). Measured need at ``eps_abs=1e-6``: ≤ 5 outer
      / 6 inner iterations warm (the balance replay), ≤ 10 / 46 cold from random states; the
      polish turns a nearly converged iterate into the exact optimum. Accurate offline solves
      (``eps_abs=1e-9``) want larger budgets.
    * ``retry_cold`` — when a warm-started solve fails, re-initialise and solve from scratch with
      the rest of the budget (warm starts far from the new solution occasionally end in a
      spurious infeasibility verdict).
    * ``active_set_guess`` (default True) — first try last tick's active set with one KKT solve
      (:class:`ActiveSetGuess`); proxsuite runs only when that is not provably optimal.
    * ``polish`` (default True) — after proxsuite, solve the KKT system of the rows tight at its
      iterate, corrected into a provably optimal active set (:meth:`ActiveSetGuess.polish`): the
      answer is then the exact optimum, computed deterministically. proxsuite alone is not
      bit-reproducible (its results differ by ~1e-14 with the memory layout of the process);
      polished answers are, its bits only deciding which side of ``max(10 eps_abs, 1e-5)`` a
      row's slack falls.
    * ``deterministic`` (default True) — where the polish finds no provably optimal active set
      (degenerate or nearly infeasible problems, typically a falling robot), the answer is the
      KKT point of the rows tight at proxsuite's iterate (:meth:`ActiveSetGuess.settle`),
      accepted when it satisfies every constraint to ``max(eps_abs, 1e-7)``, whatever proxsuite's
      own verdict: proxsuite's last bits then only matter through which side of
      ``max(10 eps_abs, 1e-5)`` a row's slack falls. ``False``: proxsuite's own solution and
      verdict.
    """

    name = "proxsuite"

    def __init__(
        self,
        *,
        eps_abs: float = 1e-6,
        eps_rel: float = 0.0,
        max_iter: int = 10,
        max_iter_in: int = 10,
        backend: str = "PrimalDualLDLT",
        retry_cold: bool = True,
        active_set_guess: bool = True,
        polish: bool = True,
        deterministic: bool = True,
        **settings: object,
    ) -> None:
        import proxsuite

        if int(max_iter) < 1 or int(max_iter_in) < 1:
            raise ValueError(f"max_iter and max_iter_in must be >= 1, got {max_iter}, {max_iter_in}")
        self.retry_cold = retry_cold
        self.max_iter = int(max_iter)
        self.max_iter_in = int(max_iter_in)
        self._kkt = ActiveSetGuess() if (active_set_guess or polish) else None
        self.guess = self._kkt if active_set_guess else None
        self._polish = bool(polish)
        self.deterministic = bool(deterministic)
        self._proxqp = proxsuite.proxqp
        self._settings = dict(eps_abs=eps_abs, eps_rel=eps_rel, max_iter=self.max_iter, max_iter_in=self.max_iter_in, verbose=False, **settings)
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
        self._rows = None
        if self._kkt is not None:
            self._kkt.reset()

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
                return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start, guess.rows)
        if cold:
            key = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
            cold = self._qp is None or key != self._structure
        try:
            if cold:
                # First tick, new structure, or recovering from a failure: a cold init.
                self._init(p)
                self._structure = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
            elif p.lb is not None:
                self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u, p.lb, p.ub)
            else:
                self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u)
            self._qp.settings.max_iter = self.max_iter
            self._qp.solve()
        except Exception as error:  # proxsuite raises on malformed input; never inside the loop
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start)
        self._problem, self._token = p, p.structure
        status, iterations, outer = self._status_of(self._qp.results)
        x, status = self._answer(p, status)
        left = self.max_iter - outer
        if x is None and self.retry_cold and not cold and left > 0:
            # A warm start from a far-away previous solution can make proxsuite stall or
            # report a spurious infeasibility: retry from scratch with the rest of the budget.
            try:
                self._init(p)
                self._qp.settings.max_iter = left
                self._qp.solve()
            except Exception as error:
                self.reset()
                return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start, iterations)
            status, more, _ = self._status_of(self._qp.results)
            iterations += more
            x, status = self._answer(p, status)
        if x is None:
            self.reset()  # do not warm-start from a failed solve
            if status in USABLE:  # proxsuite's point, but no feasible KKT point near it
                return self._failure(p.n, QpStatus.FAILED, f"proxsuite: {status.value}, but no KKT point near its iterate is feasible", start, iterations)
            return self._failure(p.n, status, f"proxsuite: {status.value}", start, iterations)
        return QpSolution(x, status, iterations, self.name, "", time.perf_counter() - start, self._rows)

    def _answer(self, p: QpProblem, status: QpStatus) -> tuple[np.ndarray | None, QpStatus]:
        """The tick's answer from proxsuite's results: polished (exact, deterministic); else,
        when ``deterministic``, settled (:meth:`ActiveSetGuess.settle`: the KKT point of the rows
        tight at proxsuite's iterate, whatever proxsuite's verdict, accepted if feasible); else
        proxsuite's own solution when usable; else None."""
        results = self._qp.results  # type: ignore[union-attr]
        kkt = self._kkt
        self._rows = None
        if kkt is not None and self._polish:
            # The iterate is accurate to eps_abs in the residuals, but far less in weakly
            # regularised directions (1e-9 of dual residual on a 1e-5 Hessian: 1e-4 in x):
            # rows within 1e-5 of a bound count as tight, the polish drops the wrong ones.
            eps = float(self._settings["eps_abs"])  # type: ignore[arg-type]
            slack = max(10.0 * eps, 1e-5)
            iterate = np.asarray(results.x)
            x = kkt.polish(p, iterate, slack=slack)
            if x is not None:
                self._rows = kkt.rows
                return x, QpStatus.SOLVED  # every KKT condition verified: the optimum
            if self.deterministic:
                x = kkt.settle(p, iterate, slack=slack, feasibility=max(eps, 1e-7))
                if x is None:
                    return None, status
                self._rows = kkt.rows
                return x, status if status in USABLE else QpStatus.INACCURATE
        if status not in USABLE:
            return None, status
        x = np.array(results.x)
        if kkt is not None:
            kkt.learn(p, x, results.z)
        return x, status

    def _status_of(self, results: object) -> tuple[QpStatus, int, int]:
        info = results.info  # type: ignore[attr-defined]
        status = self._status.get(info.status, QpStatus.FAILED)
        if status in USABLE:
            x = results.x  # type: ignore[attr-defined]
            if not math.isfinite(float(x @ x)):
                status = QpStatus.FAILED
        return status, int(info.iter), int(info.iter_ext)


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
                return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start, guess.rows)
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
            guess.learn(p, x, result.y[p.n_eq :])
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
