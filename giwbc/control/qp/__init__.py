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

Modules: :mod:`~giwbc.control.qp.problem` (the data and the backend interface),
:mod:`~giwbc.control.qp.active_set` (exact answers from a guessed active set),
:mod:`~giwbc.control.qp.proxsuite_solver`, :mod:`~giwbc.control.qp.osqp_solver`,
:mod:`~giwbc.control.qp.qpsolvers_solver` (one backend each) and
:mod:`~giwbc.control.qp.registry` (backends by name).
"""

from giwbc.control.qp.active_set import ActiveSetGuess
from giwbc.control.qp.osqp_solver import OsqpSolver
from giwbc.control.qp.problem import DEFAULT_SOLVER, USABLE, QpProblem, QpSolution, QpSolver, QpStatus
from giwbc.control.qp.proxsuite_solver import ProxsuiteSolver
from giwbc.control.qp.qpsolvers_solver import QpsolversSolver
from giwbc.control.qp.registry import available_solvers, make_solver

__all__ = [
    "DEFAULT_SOLVER",
    "USABLE",
    "ActiveSetGuess",
    "OsqpSolver",
    "ProxsuiteSolver",
    "QpProblem",
    "QpSolution",
    "QpSolver",
    "QpStatus",
    "QpsolversSolver",
    "available_solvers",
    "make_solver",
]
