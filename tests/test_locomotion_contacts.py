"""The WBC's contact switching as walking uses it: a broken foot contact (ramped out) keeps its
slot with its wrench pinned at zero — equality rows of full rank, so the active-set guess answers
single-support ticks with one regular KKT solve — and the same foot made again carries load."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control import ComTask, ContactForceRegularization, FrameOrientationTask, PostureTask, WholeBodyController, foot_contacts


def controller(g1, solver: str) -> WholeBodyController:
    wbc = WholeBodyController(g1.build_pinocchio(), solver=solver, torque_limits=g1.effort_limits)
    for contact in foot_contacts(g1, "surface", mu=0.8):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    return wbc


@pytest.mark.parametrize("solver", ["proxsuite", "osqp"])
def test_a_broken_contact_is_pinned_at_zero_force_with_full_rank_equalities(g1, solver):
    wbc = controller(g1, solver)
    q, v = g1.default_configuration(), np.zeros(wbc.nv)
    dt = 0.002
    wbc.update(q, v, 0.0)
    structure = wbc.problem.structure
    wbc.remove_contact("right_foot", ramp_time=0.02)
    for i in range(1, 30):
        result = wbc.update(q, v, i * dt)
        assert result.ok, result.message
    assert "right_foot" not in wbc.active_contacts and wbc.problem.structure == structure
    A = wbc.problem.A
    assert np.linalg.matrix_rank(A) == A.shape[0]  # no zero rows left behind by the broken contact
    forces = wbc.contact_forces("right_foot", result)
    assert np.all(forces == 0.0)
    # Equation of motion with the remaining foot only: M q̈ + h = Sᵀτ + J_leftᵀ f_left.
    kin = wbc.kin
    left = wbc.contact("left_foot")
    tau = np.concatenate([np.zeros(6), result.tau])
    residual = kin.mass_matrix @ result.qdd + kin.nonlinear_effects - tau - left.jacobian.T @ wbc.contact_forces("left_foot", result)
    assert np.abs(residual).max() < 1e-6
    # Made again: the same slot, its load ramps back in.
    wbc.add_contact(wbc.contact("right_foot"), ramp_time=0.02)
    for i in range(30, 60):
        result = wbc.update(q, v, i * dt)
        assert result.ok, result.message
    assert wbc.problem.structure == structure and wbc.contact_activation("right_foot") == 1.0
    assert result.contact_wrenches["right_foot"][2] > 100.0


def test_single_support_ticks_are_answered_by_one_regular_kkt_solve(g1):
    """With the broken contact pinned, repeated single-support ticks hit the active-set guess."""
    wbc = controller(g1, "proxsuite")
    q, v = g1.default_configuration(), np.zeros(wbc.nv)
    wbc.update(q, v, 0.0)
    wbc.remove_contact("right_foot", ramp_time=0.0)
    for i in range(1, 5):
        wbc.update(q, v, i * 0.002)
    guess = wbc.solver.guess
    factorisations = []
    gesv = guess._gesv

    def counting(*args, **kwargs):  # a spy on the LAPACK solve of the KKT system
        out = gesv(*args, **kwargs)
        factorisations.append(out[-1])
        return out

    guess._gesv = counting
    for i in range(5, 25):
        assert wbc.update(q, v, i * 0.002).message == "active-set guess"
    assert len(factorisations) == 20 and all(info == 0 for info in factorisations)  # one regular solve a tick
