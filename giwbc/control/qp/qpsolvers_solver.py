"""Any ``qpsolvers`` backend through its one-shot ``solve_problem`` (tests and comparisons, not real time)."""

from __future__ import annotations

import time

import numpy as np

from giwbc.control.qp.problem import QpProblem, QpSolution, QpSolver, QpStatus
from giwbc.control.qp.proxsuite_build import import_qpsolvers


class QpsolversSolver(QpSolver):
    """Any backend of ``qpsolvers`` through its one-shot ``solve_problem`` (not for real time).

    The problem goes through :meth:`QpProblem.to_qpsolvers`; the previous solution is passed as
    ``initvals``.
    """

    def __init__(self, solver: str, **settings: object) -> None:
        qpsolvers = import_qpsolvers()

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
        qp = p.to_qpsolvers()
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
