"""A tick has a hard bound: proxsuite 0.8 counts *inner* (semi-smooth Newton) iterations in
``info.iter`` and runs up to ``max_iter_in`` (default 1500) of them per *outer* iteration, so
``max_iter`` alone bounded nothing (4734 iterations, 0.8 s, on a falling robot's QP under
``max_iter=300``; 13 million, 270 s, on an infeasible one under proxsuite's defaults). The backend
now bounds both, and the whole tick (cold retry included) shares one outer budget."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control import ComTask, ProxsuiteSolver, QpStatus, WbcStatus, WholeBodyController, foot_contacts, make_balance_controller
from giwbc.robot import MujocoRobot


def infeasible_controller(g1, g1_model, **settings) -> WholeBodyController:
    """Limp joints (1 mN m) cannot push the feet down with twice the weight each."""
    wbc = WholeBodyController(g1_model, torque_limits=np.full(29, 1e-3), solver_settings=settings)
    weight = g1.total_mass * 9.81
    for contact in foot_contacts(g1, min_normal_force=2 * weight, max_normal_force=3 * weight):
        wbc.add_contact(contact)
    wbc.add_task(ComTask())
    return wbc


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_pinocchio()


def test_an_infeasible_problem_fails_within_its_iteration_budget(g1, g1_model):
    """Counted, not timed: the failing tick (warm start, then the cold retry) stops within
    ``max_iter * (max_iter_in + 1)`` inner iterations, 110 by default (~2-5 ms at ~20-40 µs each),
    where proxsuite's own defaults ran 13 million."""
    solver = ProxsuiteSolver()
    bound = solver.max_iter * (solver.max_iter_in + 1)
    assert bound <= 200
    q, v = g1.default_configuration(), np.zeros(35)
    for attempt in range(3):
        wbc = infeasible_controller(g1, g1_model)
        wbc.update(q, v, 0.0)  # cold: init + solve
        result = wbc.update(q, v, 0.002)  # warm start, then the cold retry with the rest of the budget
        assert result.status is WbcStatus.QP_FAILED and result.qp_status is not QpStatus.SOLVED
        assert 0 < result.iterations <= bound, (result.iterations, bound)
        assert np.all(np.isfinite(result.tau))
        assert wbc.failures == 2 and wbc.consecutive_failures == 2


def test_the_budget_is_shared_by_the_cold_retry(g1, g1_model):
    q, v = g1.default_configuration(), np.zeros(35)
    for max_iter, max_iter_in in [(4, 5), (10, 10)]:
        wbc = infeasible_controller(g1, g1_model, max_iter=max_iter, max_iter_in=max_iter_in)
        for i in range(3):
            result = wbc.update(q, v, 0.002 * i)
            assert not result.ok and result.iterations <= max_iter * (max_iter_in + 1)
    with pytest.raises(ValueError):
        ProxsuiteSolver(max_iter_in=0)


@pytest.mark.slow
def test_every_tick_of_a_fall_is_bounded(g1):
    """A 400 N push topples the robot: its QPs turn degenerate and infeasible; every tick stays
    within the iteration budget and returns a finite torque."""
    robot = MujocoRobot(g1)
    controller = make_balance_controller(g1)
    solver = controller.wbc.solver
    bound = solver.max_iter * (solver.max_iter_in + 1)
    iterations, failed, lowest = [], 0, np.inf
    for i in range(600):
        robot.set_external_wrench(g1.base_link, [0.0, 400.0 if 50 <= i < 150 else 0.0, 0.0])
        result = controller.step(robot)
        robot.step()
        lowest = min(lowest, robot.base_state().position[2])
        iterations.append(result.iterations)
        failed += not result.ok
        assert np.all(np.isfinite(result.tau))
    assert lowest < 0.4  # it did fall (pelvis from 0.78 m to the floor; on the ground it flails, so not judged at the end)
    assert max(iterations) <= bound and max(iterations) > 0  # 844 ms for one tick before the bound
    assert failed > 0  # the budget was reached: the bound, not an easy problem, ended those ticks
