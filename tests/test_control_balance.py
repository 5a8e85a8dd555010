"""The ready-made balance controller: what its configuration promises, checked on its answers —
minimum normal force per foot, the shrunk support rectangles, torque limits and impedance gains
from the description, references anchored by ``reset(q)``, and the loop on a robot or an estimate."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control import WbcStatus, make_balance_controller
from giwbc.control.balance import BalanceController, BalanceOnEstimate
from giwbc.control.contacts import sole_frame
from giwbc.locomotion.support import signed_distance
from giwbc.robot import MujocoRobot, RobotDescription

ACCURATE = {"eps_abs": 1e-9, "max_iter": 100, "max_iter_in": 100}


def contact_cop(controller: BalanceController, contact, result) -> np.ndarray:
    """The centre of pressure (contact frame, sole plane) of a contact's planned wrench."""
    wrench = result.contact_wrenches[contact.name]  # contact frame: (f, τ) about the contact origin
    return np.array([-wrench[4] / wrench[2], wrench[3] / wrench[2]])


def normals(controller: BalanceController, result) -> np.ndarray:
    return np.array([controller.wbc.contact_wrench_world(contact.name, result)[2] for contact in controller.contacts])


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_a_far_com_target_leaves_each_foot_its_minimum_load_and_the_cop_in_the_margin(g1: RobotDescription, contact_model: str) -> None:
    """The CoM target moved over (and past) the left foot: the regularisation puts the weight
    there, but the right foot keeps 6 % of the weight (a quarter of it per corner), and every
    foot's centre of pressure stays inside its sole shrunk to 85 %; no foot exceeds 3 × the weight."""
    controller = make_balance_controller(g1, contact_model=contact_model, solver_settings=ACCURATE, force_weight=1.0, com_weight=1e-3)
    weight = g1.total_mass * 9.81
    q, v = g1.default_configuration(), np.zeros(35)
    controller.update(q, v, 0.0)
    left = controller.wbc.contact(controller.contacts[0].name).placement_in_world(controller.wbc.kin).translation
    controller.set_com_target(left + np.array([0.0, 0.1, 0.0]))
    result = controller.update(q, v, 0.002)
    assert result.ok, result.message
    load = normals(controller, result)
    assert load[1] == pytest.approx(0.06 * weight, rel=1e-4)  # the minimum binds
    if contact_model == "corners":
        corners = controller.wbc.contact_forces(controller.contacts[1].name, result)[2::3]
        np.testing.assert_allclose(corners, 0.015 * weight, rtol=1e-4)
    assert np.all(load <= 3.0 * weight)
    for contact, rectangle in zip(controller.contacts, g1.contacts):
        # The support: the description's sole hull (about its centroid, the contact frame) shrunk to 85 %.
        _, hull = sole_frame(rectangle)
        support = contact.support_polygon()
        assert sorted(map(tuple, np.round(support, 9))) == sorted(map(tuple, np.round(0.85 * hull, 9)))
        wrench = controller.wbc.contact_wrench_world(contact.name, result)  # the CoP inside it
        cop = contact_cop(controller, contact, result)
        assert signed_distance(cop, support) <= 1e-6, (cop, support)
        assert contact.mu == 0.8 and contact.kd == 20.0 and contact.kp == 0.0
        assert wrench[2] > 0.0


def test_the_cop_margin_binds_under_a_forward_com_acceleration(g1: RobotDescription) -> None:
    """Asked for more forward CoM acceleration than the feet can give, the controller moves the
    centres of pressure to the front edge of the shrunk soles — not beyond it."""
    controller = make_balance_controller(g1, solver_settings=ACCURATE)
    q, v = g1.default_configuration(), np.zeros(35)
    controller.update(q, v, 0.0)
    controller.set_com_target(controller.nominal_com, acceleration=np.array([-30.0, 0.0, 0.0]))
    result = controller.update(q, v, 0.002)
    assert result.ok, result.message
    for contact in controller.contacts:
        front = float(contact.support_polygon()[:, 0].max())  # the shrunk sole's front edge (contact frame)
        cop = contact_cop(controller, contact, result)
        assert cop[0] <= front + 1e-6
        assert cop[0] > 0.999 * front  # ... reached, not passed


def test_limits_and_gains_come_from_the_description_and_the_config(g1: RobotDescription) -> None:
    model = g1.build_pinocchio()
    controller = make_balance_controller(g1, model=model, solver="osqp", torque_limit_scale=0.5, impedance_kp_scale=0.2, impedance_kd_scale=0.3, com_kp=64.0, contact_ramp_time=0.1)
    wbc = controller.wbc
    assert wbc.model is model and wbc.solver.name == "osqp"
    np.testing.assert_allclose(wbc.torque_limits, 0.5 * g1.effort_limits)
    np.testing.assert_allclose(wbc.impedance_kp, 0.2 * g1.kp)
    np.testing.assert_allclose(wbc.impedance_kd, 0.3 * g1.kd)
    np.testing.assert_allclose(wbc.fallback_kd, g1.kd)
    assert wbc.dt == g1.timestep
    np.testing.assert_allclose(controller.com_task.kp, 64.0)
    np.testing.assert_allclose(controller.com_task.kd, 16.0)  # critical damping 2 √64
    assert controller.momentum_task is None and controller.config.com_kp == 64.0
    q, v = g1.default_configuration(), np.zeros(35)
    controller.update(q, v, 0.0)
    controller.update(q, v, 0.05)
    assert all(wbc.contact_activation(c.name) == pytest.approx(0.5) for c in controller.contacts)  # the ramp of the config
    with_momentum = make_balance_controller(g1, angular_momentum_weight=0.5, angular_momentum_kd=7.0)
    task = with_momentum.momentum_task
    assert task is not None and task in with_momentum.wbc.tasks
    np.testing.assert_allclose(task.weight, 0.5)
    np.testing.assert_allclose(task.kd, 7.0)
    with pytest.raises(ValueError, match="has a fixed base"):
        BalanceController(_fixed(g1))


def _fixed(g1: RobotDescription) -> RobotDescription:
    return replace(g1, floating_base=False)


def test_reset_anchors_the_references_at_a_configuration(g1: RobotDescription, rng: np.random.Generator) -> None:
    """``reset(q)``: CoM target the CoM at ``q``, base reference upright with ``q``'s heading
    (yaw only, at the base position), posture the default pose, momentum reference zero."""
    controller = make_balance_controller(g1, angular_momentum_weight=0.1)
    with pytest.raises(RuntimeError, match=r"^the nominal CoM is set by reset\(\) or the first update\(\)$"):
        controller.set_com_offset([0.0, 0.01, 0.0])
    model = g1.build_pinocchio()
    q = g1.default_configuration()
    yaw = 0.7
    rotation = pin.rpy.rpyToMatrix(0.1, -0.15, yaw)  # Rz(yaw) Ry Rx: the x axis heads at yaw
    q[3:7] = pin.Quaternion(rotation).coeffs()
    q[7:] += rng.uniform(-0.1, 0.1, 29)
    controller.set_posture(g1.default_positions)
    controller.momentum_task.set_reference(np.ones(3))
    controller.reset(q)
    data = model.createData()
    np.testing.assert_allclose(controller.nominal_com, pin.centerOfMass(model, data, q), atol=1e-12)
    np.testing.assert_allclose(controller.com_task.position_ref, controller.nominal_com)
    np.testing.assert_allclose(controller.force_regularization.support_point, controller.nominal_com)
    reference = controller.base_task.reference
    np.testing.assert_allclose(reference.rotation, pin.rpy.rpyToMatrix(0.0, 0.0, yaw), atol=1e-12)
    np.testing.assert_allclose(reference.translation, q[:3])
    np.testing.assert_allclose(controller.posture_task.position_ref, g1.default_positions)
    np.testing.assert_allclose(controller.momentum_task.velocity_ref, 0.0)
    controller.set_com_offset([0.0, 0.02, -0.01], velocity=[0.0, 0.1, 0.0], acceleration=[0.5, 0.0, 0.0])
    np.testing.assert_allclose(controller.com_task.position_ref, controller.nominal_com + [0.0, 0.02, -0.01])
    np.testing.assert_allclose(controller.com_task.velocity_ref, [0.0, 0.1, 0.0])
    np.testing.assert_allclose(controller.com_task.acceleration_ref, [0.5, 0.0, 0.0])
    lower, upper = g1.position_limits
    controller.set_posture(upper + 1.0, velocities=np.full(29, 0.5))
    np.testing.assert_allclose(controller.posture_task.position_ref, upper)
    np.testing.assert_allclose(controller.posture_task.velocity_ref, 0.5)
    controller.set_posture(lower - 1.0)
    np.testing.assert_allclose(controller.posture_task.position_ref, lower)


def test_reset_makes_the_contacts_of_construction_again(g1: RobotDescription) -> None:
    controller = make_balance_controller(g1)
    q, v = g1.default_configuration(), np.zeros(35)
    controller.update(q, v, 0.0)
    controller.wbc.forget_contact(controller.contacts[1].name)
    assert len(controller.wbc.contacts) == 1
    controller.reset()
    assert [c.name for c in controller.wbc.contacts] == [c.name for c in controller.contacts]
    result = controller.update(q, v, 0.0)
    assert result.ok and all(normals(controller, result) > 0.3 * g1.total_mass * 9.81)


def test_step_closes_the_loop_on_a_robot_and_on_an_estimate(g1: RobotDescription) -> None:
    """``step(robot)`` reads the robot's state and clock and commands the returned torques;
    ``BalanceOnEstimate`` does the same from an estimate's (q, v) and counts failures."""
    robot = MujocoRobot(g1)
    controller = make_balance_controller(g1)
    for _ in range(3):
        robot.step()
    q, v = robot.generalized_state()
    result = controller.step(robot)
    assert result.ok and result.t == robot.time() > 0.0
    np.testing.assert_allclose(robot.data.ctrl, result.tau)
    np.testing.assert_allclose(controller.nominal_com, pin.centerOfMass(g1.build_pinocchio(), g1.build_pinocchio().createData(), q), atol=1e-9)

    @dataclass
    class Estimate:
        q: np.ndarray
        v: np.ndarray

    ramped = BalanceOnEstimate(g1, contact_ramp_time=0.1)  # its clock is the robot's: a ramp shows it
    ramped(robot, Estimate(q, v))
    for _ in range(5):
        robot.step()
    ramped(robot, Estimate(q, v))
    name = ramped.controller.contacts[0].name
    assert ramped.controller.wbc.contact_activation(name) == pytest.approx(5 * g1.timestep / 0.1)
    closing = BalanceOnEstimate(g1, com_kp=90.0)
    assert closing.controller.config.com_kp == 90.0
    closing(robot, Estimate(q, v))
    expected = make_balance_controller(g1, com_kp=90.0).update(q, v, robot.time())
    np.testing.assert_array_equal(robot.data.ctrl, expected.tau)
    assert closing.failures == 0
    bad = q.copy()
    bad[0] = np.nan
    closing(robot, Estimate(bad, v))
    assert closing.failures == 1 and closing.controller.wbc.failures == 1
    assert closing.controller.update(bad, v).status is WbcStatus.INVALID_STATE


def test_every_configured_option_reaches_the_controller(g1: RobotDescription) -> None:
    weight = g1.total_mass * 9.81
    controller = make_balance_controller(
        g1, solver_settings={"max_iter": 7}, joint_limits=True, acceleration_regularization=1e-4, impedance_lookahead=0.01,
        mu=0.5, min_normal_force=12.0, max_normal_force=900.0, contact_kp=3.0, contact_kd=4.0,
        com_weight=7.0, com_kp=49.0, com_kd=3.0, base_weight=2.0, base_kp=36.0, base_kd=5.0,
        posture_weight=0.2, posture_kp=25.0, posture_kd=1.0,
    )  # fmt: skip
    wbc = controller.wbc
    assert wbc.solver.max_iter == 7 and wbc.joint_limits and wbc.acceleration_regularization == 1e-4 and wbc.impedance_lookahead == 0.01
    for contact in controller.contacts:
        assert (contact.mu, contact.min_normal_force, contact.max_normal_force, contact.kp, contact.kd) == (0.5, 12.0, 900.0, 3.0, 4.0)
    for task, (w, kp, kd) in ((controller.com_task, (7.0, 49.0, 3.0)), (controller.base_task, (2.0, 36.0, 5.0)), (controller.posture_task, (0.2, 25.0, 1.0))):
        np.testing.assert_allclose(task.weight, w)
        np.testing.assert_allclose(task.kp, kp)
        np.testing.assert_allclose(task.kd, kd)
    default = make_balance_controller(g1)
    assert all(c.max_normal_force == pytest.approx(3.0 * weight) and c.min_normal_force == pytest.approx(0.06 * weight) for c in default.contacts)
    assert BalanceOnEstimate(g1).failures == 0
    with pytest.raises(ValueError, match=r"^robot 'g1' has no foot contacts; a balance controller needs some$"):
        BalanceController(replace(g1, contacts=()))
