"""Backends by name: :func:`make_solver` and :func:`available_solvers`."""

from __future__ import annotations

from giwbc.control.qp.osqp_solver import OsqpSolver
from giwbc.control.qp.problem import DEFAULT_SOLVER, QpSolver
from giwbc.control.qp.proxsuite_solver import ProxsuiteSolver
from giwbc.control.qp.proxsuite_build import import_qpsolvers
from giwbc.control.qp.qpsolvers_solver import QpsolversSolver


def available_solvers() -> list[str]:
    """Names :func:`make_solver` accepts on this machine."""
    qpsolvers = import_qpsolvers()

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
    qpsolvers = import_qpsolvers()

    if key in qpsolvers.available_solvers:
        return QpsolversSolver(key, **settings)
    raise ValueError(f"unknown QP solver {name!r}; available: {available_solvers()}")
