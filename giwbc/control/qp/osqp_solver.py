"""The OSQP backend: one persistent ``osqp.OSQP`` on the problem's fixed sparsity pattern."""

from __future__ import annotations

import time

import numpy as np

from giwbc.control.qp.active_set import ActiveSetGuess
from giwbc.control.qp.problem import USABLE, QpProblem, QpSolution, QpSolver, QpStatus


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
        try:  # (malformed input raises in the guess's KKT solve or in OSQP: a failed solve either way)
            if guess is not None and self._solver is not None and key == self._structure:
                x = guess.try_solve(p)
                if x is not None:
                    return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start, guess.rows)
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
