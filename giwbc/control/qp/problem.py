"""The QP as plain, inspectable numpy data, what a backend returns, and the backend interface.

::

    minimise ½ xᵀ H x + gᵀ x   subject to   A x = b,   l ≤ C x ≤ u,   lb ≤ x ≤ ub (optional)

(``±inf`` marks a missing bound). :meth:`QpProblem.to_qpsolvers` hands any tick's problem to any
``qpsolvers`` backend in one line.
"""

from __future__ import annotations

import abc
import enum
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import qpsolvers

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

    ``fixed`` (optional): variables held at exactly zero, with no finite bounds, as ``(variables,
    equality rows)`` or ``(variables, equality rows, inequality rows)``: the equality rows are
    unit rows ``x_i = 0`` (``b_i = 0``) of some of them (e.g. a broken contact's pinned wrench);
    the inequality rows (indices into ``C``) involve fixed variables only and hold the others at
    zero — bounds with ``l ≤ 0 ≤ u`` whose only solution among those variables is zero, every
    direction of their dual cone generated (e.g. a contact's friction cone with its normal
    force capped at 0: the contact made, its force not yet ramped up). A KKT solver may
    eliminate the variables, their equality rows and those inequality rows
    (:class:`~giwbc.control.qp.ActiveSetGuess`: a smaller system, the same optimum); the tuple
    is replaced, not modified, whenever the set changes.
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
    fixed: tuple[np.ndarray, ...] | None = field(default=None, repr=False)

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
            None if self.fixed is None else tuple(part.copy() for part in self.fixed),  # type: ignore[arg-type]
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

    def to_qpsolvers(self, infinity: float = 1e20) -> "qpsolvers.Problem":
        """This problem as a ``qpsolvers.Problem``: ``l ≤ Cx ≤ u`` becomes ``G x ≤ h`` rows for the
        finite bounds, infinite variable bounds become ``±infinity``. Hand any tick's QP to any
        solver in one line: ``qpsolvers.solve_problem(problem.to_qpsolvers(), solver="clarabel")``."""
        from giwbc.control.qp.proxsuite_build import import_qpsolvers  # not needed on the real-time path

        qpsolvers = import_qpsolvers()

        upper, lower = np.isfinite(self.u), np.isfinite(self.l)
        G = np.vstack([self.C[upper], -self.C[lower]])
        h = np.concatenate([self.u[upper], -self.l[lower]])
        lb = None if self.lb is None else np.where(np.isfinite(self.lb), self.lb, -infinity)
        ub = None if self.ub is None else np.where(np.isfinite(self.ub), self.ub, infinity)
        return qpsolvers.Problem(
            self.H, self.g, G if len(h) else None, h if len(h) else None,
            self.A if self.n_eq else None, self.b if self.n_eq else None, lb, ub,
        )

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


