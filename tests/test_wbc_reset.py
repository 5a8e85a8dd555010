"""``reset`` forgets the past: a used controller after ``reset(q)`` gives the same torques, bit for
bit, as a new one (clock, last torque, failure counts, contact ramps, solver warm start and the
active set of the guess are all state that used to survive it)."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control import WbcStatus, make_balance_controller
from giwbc.robot import MujocoRobot


def run(g1, controller, ticks: int) -> np.ndarray:
    """A MuJoCo closed loop from the standing pose: CoM sway, a lateral push from tick 80."""
    robot = MujocoRobot(g1)
    q, _ = robot.generalized_state()
    controller.reset(q)
    torques = []
    for i in range(ticks):
        t = i * g1.timestep
        controller.set_com_offset([0.0, 0.02 * np.sin(2.0 * np.pi * 0.5 * t), 0.0])
        robot.set_external_wrench(g1.base_link, [0.0, 60.0 if 80 <= i < 120 else 0.0, 0.0])
        torques.append(controller.step(robot).tau.copy())
        robot.step()
    return np.array(torques)


def use(g1, controller) -> None:
    """Leave as much state behind as possible: ticks at other times, a failed tick, a broken
    and re-made contact, moved references, forced proxsuite solves."""
    robot = MujocoRobot(g1)
    q, v = robot.generalized_state()
    controller.update(q, v, 0.0)
    for i in range(1, 60):
        controller.set_com_offset([0.01, 0.03, -0.01], velocity=[0.0, 0.1, 0.0])
        controller.set_posture(g1.default_positions + 0.05)
        robot.set_external_wrench(g1.base_link, [30.0, -80.0, 0.0])
        controller.step(robot)
        robot.step()
    bad = robot.generalized_state()[0].copy()
    bad[9] = np.nan
    assert controller.update(bad, v, 1.0).status is WbcStatus.INVALID_STATE
    controller.wbc.remove_contact(controller.contacts[1].name, ramp_time=0.05)
    for i in range(10):
        controller.update(*robot.generalized_state(), 1.002 + 0.002 * i)
    controller.wbc.add_contact(controller.contacts[1], ramp_time=0.02)
    controller.update(*robot.generalized_state(), 1.5)
    assert controller.wbc.failures == 1 and controller.wbc.ticks > 60


@pytest.mark.slow
@pytest.mark.parametrize("settings", [{}, {"active_set_guess": False}], ids=["default", "forced-misses"])
def test_a_used_controller_after_reset_equals_a_new_one(g1, settings):
    fresh = make_balance_controller(g1, solver_settings=dict(settings))
    used = make_balance_controller(g1, solver_settings=dict(settings))
    use(g1, used)
    expected = run(g1, fresh, 250)
    actual = run(g1, used, 250)
    assert np.array_equal(actual, expected), np.abs(actual - expected).max()


def test_reset_restores_the_fresh_state(g1):
    controller = make_balance_controller(g1, contact_ramp_time=0.1)
    use(g1, controller)
    wbc = controller.wbc
    controller.reset()
    assert (wbc.ticks, wbc.failures, wbc.consecutive_failures, wbc._last_tau, wbc._time) == (0, 0, 0, None, 0.0)
    for contact in controller.contacts:
        assert wbc.contact_activation(contact.name) == 0.0 and contact.reference is None
        slot = wbc._slot(contact.name)
        assert slot.ramping and slot.ramp_time == 0.1 and slot.ramp_start is None
    solver = wbc.solver
    assert solver._qp is None and len(solver.guess.active) == 0
    np.testing.assert_array_equal(controller.com_task.position_ref, controller.nominal_com)
    assert controller.com_task.velocity_ref is controller.com_task._zeros
    np.testing.assert_array_equal(controller.posture_task.position_ref, g1.default_positions)
    # The fallback before any success is zero torque again (not the decayed last torque).
    q, v = g1.default_configuration(), np.zeros(35)
    bad = q.copy()
    bad[3] = np.inf
    assert np.all(controller.update(bad, v).tau == 0.0)
