"""Whole-body control: a torque-level inverse-dynamics QP on a Pinocchio model.

* :mod:`giwbc.control.kinodynamics` — one Pinocchio pass per tick (M, h, Jacobians, CoM, momentum).
* :mod:`giwbc.control.tasks` — weighted acceleration tasks (CoM, frame pose, posture, momentum)
  and the contact-force regularisation.
* :mod:`giwbc.control.contacts` — flat-foot contacts (wrench cone or corner pyramids), ramping.
* :mod:`giwbc.control.contact_set` — the QP's contact slots, force ramps, activations and weight
  shares (the lever rule).
* :mod:`giwbc.control.qp` — the inspectable QP and its persistent solver backends.
* :mod:`giwbc.control.wbc` — :class:`WholeBodyController` and its :class:`WbcResult`.
* :mod:`giwbc.control.balance` — a ready-made standing/balance controller for any description
  with foot contacts.
"""

from giwbc.control.balance import BalanceConfig, BalanceController, make_balance_controller
from giwbc.control.contacts import Contact, CornerContact, RectangleContact, SurfaceContact, foot_contacts
from giwbc.control.kinodynamics import Kinodynamics
from giwbc.control.qp import (
    ActiveSetGuess,
    OsqpSolver,
    ProxsuiteSolver,
    QpProblem,
    QpSolution,
    QpSolver,
    QpStatus,
    QpsolversSolver,
    available_solvers,
    make_solver,
)
from giwbc.control.tasks import (
    AngularMomentumTask,
    ComTask,
    ContactForceRegularization,
    FrameOrientationTask,
    FramePoseTask,
    FramePositionTask,
    PostureTask,
    WbcTask,
)
from giwbc.control.wbc import WbcResult, WbcStatus, WbcTimings, WholeBodyController

__all__ = [
    "ActiveSetGuess",
    "AngularMomentumTask",
    "BalanceConfig",
    "BalanceController",
    "ComTask",
    "Contact",
    "ContactForceRegularization",
    "CornerContact",
    "FrameOrientationTask",
    "FramePoseTask",
    "FramePositionTask",
    "Kinodynamics",
    "OsqpSolver",
    "PostureTask",
    "ProxsuiteSolver",
    "QpProblem",
    "QpSolution",
    "QpSolver",
    "QpStatus",
    "QpsolversSolver",
    "RectangleContact",
    "SurfaceContact",
    "WbcTask",
    "WbcResult",
    "WbcStatus",
    "WbcTimings",
    "WholeBodyController",
    "available_solvers",
    "foot_contacts",
    "make_balance_controller",
    "make_solver",
]
