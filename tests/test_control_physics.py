"""Physical facts about the whole-body controller's answers, checked against sources other than
the controller's own model: MuJoCo's mass matrix, bias forces and Jacobians, the friction cone
written out by hand in the world frame, the torque limits, finite differences of the tasks."""

from __future__ import annotations

import time
from dataclasses import replace

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from test_wbc_mujoco_dynamics import mujoco_residual

from giwbc.control import (
    AngularMomentumTask,
    ComTask,
    ContactForceRegularization,
    CornerContact,
    FrameOrientationTask,
    FramePoseTask,
    Kinodynamics,
    PostureTask,
    QpStatus,
    SurfaceContact,
    WbcStatus,
    WbcTask,
    WholeBodyController,
    foot_contacts,
)
from giwbc.control.contacts import corner_forces_from_wrench, corner_wrench_map, rectangle_corners, sole_frame
from giwbc.control.qp import QpProblem
from giwbc.locomotion.support import signed_distance
from giwbc.testing import DoublePendulum, SimplePendulum
from giwbc.testing.pinocchio_models import build_pinocchio_model
from giwbc.robot import MujocoRobot, RobotDescription

SOLVERS = ["proxsuite", "osqp"]
ACCURATE = {"proxsuite": {"eps_abs": 1e-9, "max_iter": 100, "max_iter_in": 100}, "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 20000}}
MU = 0.6


@pytest.fixture(scope="module")
def g1_model(g1: RobotDescription) -> pin.Model:
    return g1.build_pinocchio()


@pytest.fixture(scope="module")
def mj(g1: RobotDescription):
    robot = MujocoRobot(g1)
    return robot.model, mujoco.MjData(robot.model)


def standing_controller(g1: RobotDescription, model: pin.Model, solver: str, contact_model: str, limits: np.ndarray) -> WholeBodyController:
    wbc = WholeBodyController(model, solver=solver, solver_settings=ACCURATE[solver], torque_limits=limits, dt=g1.timestep)
    for contact in foot_contacts(g1, contact_model, mu=MU):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    return wbc


def disturbed_state(g1: RobotDescription, model: pin.Model, rng: np.random.Generator, scale: float, speed: float):
    q = pin.integrate(model, g1.default_configuration(), rng.uniform(-scale, scale, model.nv))
    return q, rng.uniform(-speed, speed, model.nv)


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
@pytest.mark.parametrize("solver", SOLVERS)
def test_tight_torque_limits_bind_and_the_answer_still_obeys_mujocos_dynamics_and_friction(
    g1: RobotDescription, g1_model: pin.Model, mj, rng: np.random.Generator, solver: str, contact_model: str
) -> None:
    """With torque limits at a third of the motors' (so that some bind on a disturbed state):
    every |τ| within its limit, at least one joint on it, the contact forces inside the friction
    pyramid and the CoP inside each foot, all in the world frame, and ``M q̈ + h = Sᵀτ + Jᵀf``
    with MuJoCo's M, h and J — which an output clamp acting on τ would break."""
    mj_model, scratch = mj
    limits = g1.effort_limits / 3.0
    bound = 0
    steepest = 0.0  # largest |f_t| / f_n seen
    for _ in range(3):
        q, v = disturbed_state(g1, g1_model, rng, scale=0.15, speed=1.0)
        wbc = standing_controller(g1, g1_model, solver, contact_model, limits)
        result = wbc.update(q, v)
        assert result.ok, result.message
        assert np.all(np.abs(result.tau) <= limits)  # exactly: the output never exceeds a limit
        bound += int(np.sum(np.abs(result.tau) >= limits * (1 - 1e-4)))
        residual = mujoco_residual(mj_model, scratch, g1.base_link, q, v, result, wbc)
        assert np.max(np.abs(residual)) < 1e-6 * g1.total_mass * 9.81, np.max(np.abs(residual))
        for contact in wbc.contacts:
            placement = contact.placement_in_world(wbc.kin)
            normal = placement.rotation[:, 2]
            wrench = wbc.contact_wrench_world(contact.name, result)
            force, torque = wrench[:3], wrench[3:]
            fn = force @ normal
            assert fn >= -1e-6
            # The linearised cone (the pyramid along the sole's axes): |f_x|, |f_y| ≤ μ f_n.
            tangential = placement.rotation[:, :2].T @ force
            assert np.all(np.abs(tangential) <= MU * fn * (1 + 1e-6) + 1e-6)
            if fn > 1.0:
                steepest = max(steepest, float(np.max(np.abs(tangential))) / fn)
            if fn > 1.0:  # the centre of pressure inside the sole's support polygon
                cop = np.cross(normal, torque) / fn  # about the contact origin, world axes
                local = placement.rotation.T @ cop
                polygon = contact.support_polygon()  # counter-clockwise, contact frame
                assert signed_distance(local[:2], polygon) <= 1e-6 * np.abs(polygon).max() + 1e-9, (local, polygon)
    assert bound >= 1  # the limits did bind: the bound above was tested, not idle
    assert steepest > 0.05  # friction was used: the cone check was not idle either


def world_twist(model: pin.Model, data: pin.Data, contact, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The contact frame's twist (origin velocity, angular velocity), world axes, by Pinocchio's
    forward kinematics alone."""
    pin.forwardKinematics(model, data, q, v)
    return pin.getFrameVelocity(model, data, contact.joint_id, contact.placement, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).vector


@pytest.mark.parametrize("kp, kd", [(30.0, 4.0), (0.5, 0.5), (0.0, 0.0)])
@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_contact_jacobian_drift_and_motion_target_against_finite_differences(
    g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator, contact_model: str, kp: float, kd: float
) -> None:
    """A foot contact's ``J v`` is the time derivative of its placement, its drift ``J̇ v`` the
    derivative of its twist along ``q̈ = 0`` (classical acceleration: of the origin's world
    velocity, in contact axes), and its motion target ``−J̇ v − Kd J v − Kp log(ref⁻¹ X)``; the
    controller's hot path (``assemble``) gives the same rows, ``−JᵀΦ`` as the force columns."""
    kin = Kinodynamics(g1_model)
    contact = foot_contacts(g1, contact_model, mu=MU, kp=kp, kd=kd)[0]
    contact.bind(kin)
    q, v = disturbed_state(g1, g1_model, rng, scale=0.2, speed=1.0)
    kin.update(q, v)
    contact.update(kin)
    J, drift = contact.jacobian.copy(), contact.drift.copy()
    placement = contact.placement_in_world(kin)
    data = g1_model.createData()
    h = 1e-6
    ahead = pin.integrate(g1_model, q, v * h)
    behind = pin.integrate(g1_model, q, -v * h)
    pin.forwardKinematics(g1_model, data, ahead)
    later = data.oMi[contact.joint_id] * contact.placement
    pin.forwardKinematics(g1_model, data, behind)
    earlier = data.oMi[contact.joint_id] * contact.placement
    np.testing.assert_allclose(pin.log6(earlier.actInv(later)).vector / (2 * h), J @ v, rtol=1e-5, atol=1e-6)
    # Drift: d/dt of the world twist along q(t) = q ⊕ v t (q̈ = 0), turned into contact axes.
    h = 1e-5
    rate = (world_twist(g1_model, data, contact, pin.integrate(g1_model, q, v * h), v)
            - world_twist(g1_model, data, contact, pin.integrate(g1_model, q, -v * h), v)) / (2 * h)  # fmt: skip
    rotation = placement.rotation
    np.testing.assert_allclose(drift, np.concatenate([rotation.T @ rate[:3], rotation.T @ rate[3:]]), rtol=1e-4, atol=1e-4)
    assert np.linalg.norm(drift) > 0.1  # a moving robot: the check is not a comparison of zeros

    target = np.zeros(6)
    contact.motion_target(kin, target)  # not made yet (no reference): no pose feedback
    np.testing.assert_allclose(target, -drift - kd * (J @ v), atol=1e-9)
    offset = pin.SE3(pin.exp3(np.array([0.02, -0.03, 0.01])), np.array([0.01, 0.0, -0.02]))
    contact.reference = placement * offset  # where the contact was made: a little off
    expected = -drift - kd * (J @ v) - kp * pin.log6(contact.reference.actInv(placement)).vector
    target = np.zeros(6)
    contact.motion_target(kin, target)
    np.testing.assert_allclose(target, expected, atol=1e-9)
    motion, rhs, columns = np.zeros((6, kin.nv)), np.zeros(6), np.zeros((kin.nv, contact.n_force))
    contact.assemble(kin, motion, rhs, columns)
    np.testing.assert_allclose(motion, J, atol=1e-12)
    np.testing.assert_allclose(rhs, expected, atol=1e-9)
    phi = np.eye(6) if contact.phi is None else contact.phi
    np.testing.assert_allclose(columns, -J.T @ phi, atol=1e-12)


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_contact_wrenches_in_world_axes_and_normal_force(g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator, contact_model: str) -> None:
    """The wrench of a contact's force variables, about its origin: rotated into world axes by
    the sole's orientation; for corner forces, the sum of the forces and of their moments."""
    kin = Kinodynamics(g1_model)
    contact = foot_contacts(g1, contact_model, mu=MU)[0]
    contact.bind(kin)
    q, v = disturbed_state(g1, g1_model, rng, scale=0.3, speed=0.0)
    kin.update(q, v)
    forces = rng.uniform(-5.0, 50.0, contact.n_force)
    if contact_model == "corners":
        corner = forces.reshape(4, 3)
        local = np.concatenate([corner.sum(axis=0), np.cross(contact.corners, corner).sum(axis=0)])
    else:
        local = forces
    rotation = contact.placement_in_world(kin).rotation
    assert not np.allclose(rotation, np.eye(3), atol=1e-2)  # a tilted sole: world ≠ contact axes
    np.testing.assert_allclose(contact.wrench_in_world(kin, forces), np.concatenate([rotation @ local[:3], rotation @ local[3:]]), atol=1e-9)
    assert contact.normal_force(forces) == pytest.approx(local[2], abs=1e-9)
    assert repr(contact) == f"{type(contact).__name__}({contact.name!r}, link={contact.link!r}, mu={MU})"


def test_removing_a_task_gives_the_answer_of_a_controller_without_it(g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator) -> None:
    q, v = disturbed_state(g1, g1_model, rng, scale=0.05, speed=0.3)
    full = standing_controller(g1, g1_model, "proxsuite", "surface", g1.effort_limits)
    names = [task.name for task in full.tasks]
    orientation = next(task for task in full.tasks if isinstance(task, FrameOrientationTask))
    assert full.task(orientation.name) is orientation
    with pytest.raises(KeyError, match=r"no task named 'nothing'; tasks: \[" + ", ".join(f"'{n}'" for n in names) + r"\]"):
        full.task("nothing")
    before = full.update(q, v).tau.copy()
    full.remove_task(orientation.name)
    assert [task.name for task in full.tasks] == [n for n in names if n != orientation.name]
    with pytest.raises(KeyError, match=r"^\"no task named 'nothing'\"$"):
        full.remove_task("nothing")
    reduced = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits, dt=g1.timestep)
    for contact in foot_contacts(g1, "surface", mu=MU):
        reduced.add_contact(contact)
    reduced.add_task(ComTask(weight=10.0, kp=100.0))
    reduced.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    regularization = full.force_regularization
    reduced.add_task(ContactForceRegularization(weight=1e-5))
    after = full.update(q, v).tau
    np.testing.assert_allclose(after, reduced.update(q, v).tau, atol=1e-6)
    assert np.max(np.abs(after - before)) > 1e-3  # the removed task mattered
    full.remove_task(regularization.name)  # the force regularisation is removed by name too
    assert full.force_regularization is None
    reduced.remove_task(reduced.force_regularization.name)
    built, expected = full.build(q, v).copy(), reduced.build(q, v)
    np.testing.assert_array_equal(built.H, expected.H)
    np.testing.assert_array_equal(built.g, expected.g)


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_an_impossible_sideways_acceleration_saturates_friction_at_exactly_mu(g1: RobotDescription, g1_model: pin.Model, contact_model: str) -> None:
    """Asked for a horizontal CoM acceleration of 4 m/s² on μ = 0.2 (about twice what friction can
    give), the controller pushes as hard as the friction pyramid allows, in each of ±x, ±y: the
    total horizontal force is μ times the total normal force — not less (a pyramid face too
    steep) and not more (a face too shallow) — and every force variable obeys its own cone."""
    mu = 0.2
    for direction in np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]]):
        wbc = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits * 100, dt=g1.timestep)
        for contact in foot_contacts(g1, contact_model, mu=mu):
            wbc.add_contact(contact)
        com = wbc.add_task(ComTask(weight=100.0, kp=0.0, kd=0.0))
        wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
        wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
        wbc.add_task(ContactForceRegularization(weight=1e-5))
        q, v = g1.default_configuration(), np.zeros(g1_model.nv)
        wbc.update(q, v)
        com.set_reference(wbc.kin.com, acceleration=4.0 * direction)
        result = wbc.update(q, v)
        assert result.ok, result.message
        total = sum(wbc.contact_wrench_world(contact.name, result)[:3] for contact in wbc.contacts)
        assert total[2] > 0.5 * g1.total_mass * 9.81
        assert total[:2] @ direction[:2] == pytest.approx(mu * total[2], rel=1e-6)
        for contact in wbc.contacts:
            variables = wbc.contact_forces(contact.name, result)
            points = variables.reshape(4, 3) if contact_model == "corners" else variables[None, :3]
            assert np.all(np.abs(points[:, :2]) <= mu * points[:, 2:] * (1 + 1e-7) + 1e-7)


# --- failures, the clock and reset -----------------------------------------------------------------
def test_a_fixed_base_falls_back_to_its_gravity_torque_before_any_success() -> None:
    """A fixed-base double pendulum told to push 1000 N at its tip with a 1 N m shoulder: the QP
    is infeasible. Before any solved tick the fallback holds the arm against gravity — ``g(q)`` of
    the closed-form model, clipped to the torque limits — then decays it per failed tick; a
    non-finite state (no ``g(q)`` to compute) gives zero torque."""
    arm = DoublePendulum()
    model = build_pinocchio_model(arm)
    limits = np.array([1.0, 100.0])

    def controller() -> WholeBodyController:
        wbc = WholeBodyController(model, torque_limits=limits, fallback_decay=0.5)
        wbc.add_contact(SurfaceContact("tip", "tip", 0.01, 0.01, min_normal_force=1000.0, max_normal_force=2000.0))
        wbc.add_task(PostureTask(reference=np.zeros(2)))
        return wbc

    q = np.array([0.3, 0.5])
    gravity = arm.gravity(q)
    assert abs(gravity[0]) > limits[0] and abs(gravity[1]) < limits[1]  # one joint clipped, one not
    wbc = controller()
    first = wbc.update(q, np.zeros(2))
    assert first.status is WbcStatus.QP_FAILED and first.failures == 1
    np.testing.assert_allclose(first.tau, np.clip(gravity, -limits, limits), rtol=1e-9)
    second = wbc.update(q, np.zeros(2))
    np.testing.assert_allclose(second.tau, 0.5 * first.tau, rtol=1e-12)
    assert first.contact_wrenches == {} and np.all(np.isnan(first.forces))
    command = first.impedance  # the fallback's impedance: hold nothing, damp, feed the torque forward
    np.testing.assert_array_equal(command.q_ref, q)
    np.testing.assert_array_equal(command.kp, 0.0)
    np.testing.assert_array_equal(command.tau_ff, first.tau)
    hanging = np.array([-0.3, -0.5])  # the mirror image: gravity pushes the other way
    assert abs(arm.gravity(hanging)[0]) > limits[0] and arm.gravity(hanging)[0] < 0
    np.testing.assert_allclose(controller().update(hanging, np.zeros(2)).tau, np.clip(arm.gravity(hanging), -limits, limits), rtol=1e-9)
    fresh = controller()
    invalid = fresh.update(np.array([np.nan, 0.5]), np.zeros(2), t=0.5)
    assert invalid.status is WbcStatus.INVALID_STATE and np.all(invalid.tau == 0.0) and invalid.t == 0.5
    np.testing.assert_array_equal(invalid.impedance.q_ref, np.zeros(2))  # no finite position to hold


def test_the_fallback_damps_with_its_own_gains_and_a_late_task_counts() -> None:
    """The fallback's impedance damps with ``fallback_kd`` when given (``impedance_kd`` otherwise);
    a task added after the first solved tick changes the next answer as a first-tick task would."""
    arm = DoublePendulum()
    model = build_pinocchio_model(arm)
    q, v = np.array([0.3, 0.5]), np.zeros(2)
    for fallback_kd, expected in ((None, [2.0, 3.0]), (np.array([7.0, 9.0]), [7.0, 9.0])):
        wbc = WholeBodyController(model, impedance_kd=np.array([2.0, 3.0]), fallback_kd=fallback_kd)
        wbc.add_task(PostureTask(reference=np.zeros(2)))
        failed = wbc.update(np.array([np.nan, 0.5]), v)
        assert not failed.ok
        np.testing.assert_array_equal(failed.impedance.kd, expected)
        np.testing.assert_array_equal(wbc.update(q, v).impedance.kd, [2.0, 3.0])  # solved: the impedance gains
    late = WholeBodyController(model)
    late.add_task(PostureTask(reference=np.zeros(2), kp=100.0))
    first = late.update(q, v)
    late.add_task(PostureTask("hold", reference=q, weight=1e4, kp=100.0))  # pulls toward where it is
    after = late.update(q, v)
    fresh = WholeBodyController(model)
    fresh.add_task(PostureTask(reference=np.zeros(2), kp=100.0))
    fresh.add_task(PostureTask("hold", reference=q, weight=1e4, kp=100.0))
    np.testing.assert_allclose(after.qdd, fresh.update(q, v).qdd, rtol=1e-9, atol=1e-9)
    assert np.linalg.norm(after.qdd) < 0.1 * np.linalg.norm(first.qdd)


def test_the_internal_clock_ticks_by_dt_from_zero(g1: RobotDescription, g1_model: pin.Model) -> None:
    """Without explicit times, the first tick is at t = 0 and each later one (built or updated)
    dt after the previous (``build`` alone does not count a tick): a contact ramp of 5 ticks
    reaches activation k/5 at tick k."""
    dt = 0.004
    wbc = WholeBodyController(g1_model, dt=dt, torque_limits=g1.effort_limits)
    for contact in foot_contacts(g1, "surface", mu=MU):
        wbc.add_contact(contact, ramp_time=5 * dt)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    name = wbc.contacts[0].name
    wbc.build(q, v)  # the first tick: t = 0, where the ramp starts
    assert wbc.contact_activation(name) == 0.0
    result = wbc.update(q, v)
    assert result.t == pytest.approx(dt) and wbc.contact_activation(name) == pytest.approx(0.2)
    wbc.build(q, v)
    assert wbc.contact_activation(name) == pytest.approx(0.4)
    result = wbc.update(q, v)
    assert result.t == pytest.approx(3 * dt) and wbc.contact_activation(name) == pytest.approx(0.6)
    assert wbc.update(q, v, t=1.0).t == 1.0 and wbc.update(q, v).t == pytest.approx(1.0 + dt)
    wbc.build(q, v, t=2.0)  # an explicit time is the tick's time
    assert wbc.update(q, v).t == pytest.approx(2.0 + dt)


def test_misuse_is_refused_with_a_clear_message(g1: RobotDescription, g1_model: pin.Model) -> None:
    wbc = standing_controller(g1, g1_model, "proxsuite", "surface", g1.effort_limits)
    with pytest.raises(RuntimeError, match=r"^call build\(q, v, t\) before solve\(\)$"):
        wbc.solve()
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    bad = q.copy()
    bad[3] = np.inf
    with pytest.raises(ValueError, match=r"^state \(q, v\) is not finite$"):
        wbc.build(bad, v)
    with pytest.raises(ValueError, match=r"^ramp_time must be >= 0$"):
        wbc.remove_contact(wbc.contacts[0].name, ramp_time=-0.1)
    with pytest.raises(ValueError, match=r"^ramp_time must be >= 0$"):
        wbc.add_contact(wbc.contacts[0], ramp_time=-0.1)
    names = [contact.name for contact in wbc.contacts]
    with pytest.raises(KeyError, match=r"no contact named 'hand'; contacts: \[" + ", ".join(f"'{n}'" for n in names) + r"\]"):
        wbc.contact("hand")
    wbc.build(q, v)
    assert wbc.solve().ok
    # solve() takes any problem: a 2-variable one, min ½‖x‖² − x₁ s.t. x₀ + x₁ = 1 → (0, 1).
    small = QpProblem(H=np.eye(2), g=np.array([0.0, -1.0]), A=np.ones((1, 2)), b=np.ones(1), C=np.zeros((0, 2)), l=np.zeros(0), u=np.zeros(0), structure=99)
    np.testing.assert_allclose(wbc.solve(small).x, [0.0, 1.0], atol=1e-6)


def test_a_used_controller_after_reset_ticks_exactly_like_a_new_one(g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator) -> None:
    """The same states at the internal clock's times give bit-identical torques from a fresh
    controller and from a used one after ``reset()``: contacts made with a ramp (the load ramps up
    from 0 over 10 ticks again), pose feedback re-anchored, clock, failures and warm start gone."""
    states = [disturbed_state(g1, g1_model, rng, scale=0.03, speed=0.3) for _ in range(14)]
    com = pin.centerOfMass(g1_model, g1_model.createData(), g1.default_configuration())

    def make() -> WholeBodyController:
        wbc = WholeBodyController(g1_model, dt=g1.timestep, torque_limits=g1.effort_limits, solver_settings=ACCURATE["proxsuite"])
        for contact in foot_contacts(g1, "surface", mu=MU, kp=20.0, kd=5.0):
            wbc.add_contact(contact, ramp_time=10 * g1.timestep)
        # Explicit references: a task's reference is configuration, kept by reset().
        wbc.add_task(ComTask(weight=10.0, kp=100.0)).set_reference(com)
        wbc.add_task(FrameOrientationTask("pelvis", kp=100.0)).set_reference(pin.SE3.Identity())
        wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
        wbc.add_task(ContactForceRegularization(weight=1e-5))
        return wbc

    def run(wbc: WholeBodyController) -> tuple[np.ndarray, list[float]]:
        results = [wbc.update(q, v) for q, v in states]
        assert all(result.ok for result in results), [(i, result.message) for i, result in enumerate(results) if not result.ok]
        return np.array([result.tau for result in results]), [result.t for result in results]

    fresh, used = make(), make()
    expected, times = run(fresh)
    for q, v in states[::-1]:
        used.update(q + 0.01, v)
    bad = states[0][0].copy()
    bad[8] = np.nan
    used.update(bad, states[0][1])
    used.remove_contact(used.contacts[1].name, ramp_time=0.01)
    for q, v in states[:6]:
        used.update(q, v)
    used.add_contact(used.contacts[1], ramp_time=10 * g1.timestep)
    used.update(*states[3])
    used.reset()
    used.reset()  # idempotent
    actual, used_times = run(used)
    assert used_times == times and times[0] == g1.timestep  # (the first update is one dt after t = 0)
    assert np.array_equal(actual, expected), np.abs(actual - expected).max()
    assert used.failures == 0 and used.ticks == len(states)
    # The ramp mattered: the first ticks carry less than the weight on the feet.
    assert np.max(np.abs(expected[0] - expected[-1])) > 1.0


# --- the task stack -----------------------------------------------------------------------------
def tilted_model(g1: RobotDescription) -> pin.Model:
    """The G1 model with one more frame on the pelvis, rotated and offset in it (no shipped
    frame is rotated relative to its joint)."""
    model = g1.build_pinocchio()
    placement = pin.SE3(pin.exp3(np.array([0.3, -0.2, 0.5])), np.array([0.05, 0.02, -0.03]))
    model.addFrame(pin.Frame("tilted", 1, model.getFrameId("pelvis"), placement, pin.FrameType.OP_FRAME))
    return model


def weighted_least_squares_answer(wbc: WholeBodyController, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The q̈ minimising ``Σ_tasks ‖√W (J q̈ + J̇ v − ẍ*)‖² + ε ‖q̈‖²`` subject to the unactuated
    base rows of ``M q̈ + h = Sᵀτ`` (no contacts), with ``ẍ* = ẍ_ref + Kp e + Kd (v_ref − J v)``
    from each task's own measurement and M, h from a fresh Pinocchio pass — one KKT solve in
    numpy, nothing from the controller's assembly."""
    model = wbc.model
    data = model.createData()
    mass = pin.crba(model, data, q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    bias = pin.nonLinearEffects(model, data, q, v)
    rows, targets = [], []
    for task in wbc.tasks:
        task.compute(wbc.kin)
        root = np.sqrt(task.weight)
        desired = task.acceleration_ref + task.kp * task.error + task.kd * (task.velocity_ref - task.jacobian @ v)
        rows.append(root[:, None] * task.jacobian)
        targets.append(root * (desired - task.drift))
    J, b = np.vstack(rows), np.concatenate(targets)
    nv = model.nv
    kkt = np.zeros((nv + 6, nv + 6))
    kkt[:nv, :nv] = J.T @ J + wbc.acceleration_regularization * np.eye(nv)
    kkt[:nv, nv:] = mass[:6].T
    kkt[nv:, :nv] = mass[:6]
    return np.linalg.solve(kkt, np.concatenate([J.T @ b, -bias[:6]]))[:nv]


class JointSumTask(WbcTask):
    """The sum of two joint angles (one row, a constant Jacobian coupling two joints): its Gram
    matrix is not diagonal, unlike the posture task's."""

    constant_jacobian = True

    def __init__(self, first: int, second: int, target: float, **gains: float) -> None:
        super().__init__("joint_sum", 1, **gains)
        self.first, self.second, self.target = first, second, target

    def compute_error(self, kin: Kinodynamics) -> np.ndarray:
        q = kin.q[kin.joint_q]
        return np.array([self.target - q[self.first] - q[self.second]])

    def compute_jacobian(self, kin: Kinodynamics) -> np.ndarray:
        row = np.zeros((1, kin.nv))
        row[0, kin.n_base + self.first] = row[0, kin.n_base + self.second] = 1.0
        return row


def test_the_task_stack_minimises_the_weighted_task_residuals(g1: RobotDescription, rng: np.random.Generator) -> None:
    """A falling robot (no contacts) with every kind of task, per-row weights and gains, velocity
    and acceleration references: the controller's q̈ is the weighted least-squares answer built
    from the definitions — and stays so after weights, gains and references change."""
    model = tilted_model(g1)
    wbc = WholeBodyController(model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=np.full(29, np.inf), dt=g1.timestep)
    com = wbc.add_task(ComTask(weight=np.array([5.0, 8.0, 2.0]), kp=np.array([40.0, 60.0, 30.0])))
    pelvis = wbc.add_task(FrameOrientationTask("pelvis", weight=3.0, kp=80.0, kd=5.0))
    tilted = wbc.add_task(FramePoseTask("tilted", mask=[1, 0, 1, 0, 1, 1], weight=np.array([1.0, 2.0, 3.0, 4.0]), kp=50.0))
    hand = wbc.add_task(FramePoseTask("left_wrist_yaw_link", weight=0.5, kp=np.array([10.0, 20.0, 30.0, 5.0, 6.0, 7.0])))
    momentum = wbc.add_task(AngularMomentumTask(weight=0.2, kd=4.0))
    posture = wbc.add_task(PostureTask(reference=g1.default_positions, weight=np.linspace(0.01, 0.1, 29), kp=np.linspace(20.0, 60.0, 29), kd=3.0))
    coupled = wbc.add_task(JointSumTask(3, 9, 0.4, weight=2.0, kp=30.0))  # a non-diagonal constant Hessian part
    for _ in range(3):
        q, v = disturbed_state(g1, model, rng, scale=0.2, speed=1.0)
        result = wbc.update(q, v)
        assert result.ok, result.message
        np.testing.assert_allclose(result.qdd, weighted_least_squares_answer(wbc, q, v), rtol=1e-5, atol=1e-5)
        com.set_reference(wbc.kin.com + rng.normal(0, 0.05, 3), velocity=rng.normal(0, 0.2, 3), acceleration=rng.normal(0, 1.0, 3))
        pelvis.set_reference(pin.SE3(pin.exp3(rng.normal(0, 0.2, 3)), np.zeros(3)), velocity=rng.normal(0, 0.5, 6), acceleration=rng.normal(0, 1.0, 6))
        tilted.set_weight(rng.uniform(0.5, 3.0, 4))
        tilted.set_gains(rng.uniform(10.0, 50.0, 4), rng.uniform(1.0, 9.0, 4))
        hand.set_reference(pin.SE3(pin.exp3(rng.normal(0, 0.3, 3)), rng.normal(0, 0.3, 3)), velocity=rng.normal(0, 0.3, 6))
        momentum.set_reference(rng.normal(0, 1.0, 3), rate=rng.normal(0, 1.0, 3))
        posture.set_reference(g1.default_positions + rng.normal(0, 0.1, 29), velocity=rng.normal(0, 0.2, 29), acceleration=rng.normal(0, 0.5, 29))
        coupled.set_weight(rng.uniform(1.0, 3.0))
        pelvis.set_weight(rng.uniform(1.0, 4.0))  # one weight: still a constant Gram matrix, of another size
    pelvis.set_weight(np.array([1.0, 2.0, 3.0]))  # per-row weights: no longer a constant Gram matrix
    q, v = disturbed_state(g1, model, rng, scale=0.2, speed=1.0)
    result = wbc.update(q, v)
    np.testing.assert_allclose(result.qdd, weighted_least_squares_answer(wbc, q, v), rtol=1e-5, atol=1e-5)
    wbc.remove_task(hand.name)
    q, v = disturbed_state(g1, model, rng, scale=0.2, speed=1.0)
    result = wbc.update(q, v)
    np.testing.assert_allclose(result.qdd, weighted_least_squares_answer(wbc, q, v), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("mask", [None, [0, 0, 0, 1, 0, 1]], ids=["all", "roll-yaw"])
def test_orientation_of_a_frame_rotated_on_the_base_against_finite_differences(g1: RobotDescription, rng: np.random.Generator, mask) -> None:
    """The base-orientation shortcut (rows from the base rotation, no Pinocchio call) for a frame
    rotated in the pelvis: its error is the rotation vector from the frame to the reference and
    its rows the derivative of the frame's world rotation, by finite differences."""
    model = tilted_model(g1)
    task = FrameOrientationTask("tilted") if mask is None else FramePoseTask("tilted", mask=mask)
    kin = Kinodynamics(model)
    task.bind(kin)
    q, v = disturbed_state(g1, model, rng, scale=0.3, speed=1.0)
    reference = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.zeros(3))
    task.set_reference(reference)
    kin.update(q, v)
    task.compute(kin)
    data = model.createData()
    frame = model.getFrameId("tilted")

    def rotation(config: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(model, data, config)
        return np.array(data.oMf[frame].rotation)

    rows = np.flatnonzero(np.asarray(task.rows) >= 3)
    angular = np.asarray(task.rows)[rows] - 3
    np.testing.assert_allclose(task.error, pin.log3(reference.rotation @ rotation(q).T)[angular], atol=1e-12)
    eps = 1e-6
    numeric = np.zeros((3, model.nv))
    for i in range(model.nv):
        dq = np.zeros(model.nv)
        dq[i] = eps
        numeric[:, i] = pin.log3(rotation(pin.integrate(model, q, dq)) @ rotation(pin.integrate(model, q, -dq)).T) / (2 * eps)
    np.testing.assert_allclose(task.jacobian, numeric[angular], atol=1e-6)
    np.testing.assert_allclose(task.drift, 0.0, atol=1e-12)  # the base's angular rows: constant in its velocity


# --- contacts in the controller: weight sharing, motion rows, ramps, breaking -----------------------
def regularized_controller(g1: RobotDescription, model: pin.Model, contact_model: str, **contact_options) -> tuple[WholeBodyController, ContactForceRegularization]:
    """Standing on both feet with a dominant force regularisation and a weak posture task: the
    contact forces follow the regularisation's reference."""
    wbc = WholeBodyController(model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits, dt=g1.timestep)
    for contact in foot_contacts(g1, contact_model, mu=0.8, **contact_options):
        wbc.add_contact(contact)
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=1e-3, kp=10.0))
    regularization = wbc.add_task(ContactForceRegularization(weight=1.0))
    return wbc, regularization


def normal_shares(wbc: WholeBodyController, result) -> np.ndarray:
    normal = np.array([wbc.contact_wrench_world(contact.name, result)[2] for contact in wbc.contacts])
    return normal / normal.sum()


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_the_weight_is_shared_by_activation_or_by_the_lever_rule_about_the_support_point(g1: RobotDescription, g1_model: pin.Model, contact_model: str) -> None:
    """``ContactForceRegularization``'s reference: the weight split evenly between two made feet;
    by the lever rule about a support point (its projection on the line between the feet, clamped
    to the segment); in proportion to the activations while one foot ramps out — and, with a
    support point, by the lever rule weighted by the activations. Corner forces share a foot's
    load evenly."""
    wbc, regularization = regularized_controller(g1, g1_model, contact_model)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    result = wbc.update(q, v)
    np.testing.assert_allclose(normal_shares(wbc, result), [0.5, 0.5], atol=1e-4)
    left, right = (wbc.contact(contact.name).placement_in_world(wbc.kin).translation for contact in wbc.contacts)
    across = np.array([-(left - right)[1], (left - right)[0], 0.0])  # off the line between the feet
    for point, expected in [(0.3 * left + 0.7 * right + 0.2 * across, 0.3), (left + 0.5 * (left - right), 1.0), (right, 0.0), (0.8 * left + 0.2 * right, 0.8)]:
        regularization.set_support_point(point)
        result = wbc.update(q, v)
        np.testing.assert_allclose(normal_shares(wbc, result), [expected, 1.0 - expected], atol=1e-3)
        if contact_model == "corners":
            for contact in wbc.contacts:
                corners = wbc.contact_forces(contact.name, result)[2::3]
                np.testing.assert_allclose(corners, corners.mean(), rtol=1e-3, atol=0.05)
    # The ramp caps a foot at its load when the ramp started times its activation: start it with
    # the right foot carrying everything, so that the cap stays above the shares tested here.
    regularization.set_support_point(right)
    wbc.update(q, v)
    regularization.set_support_point(None)
    right_name = wbc.contacts[1].name
    wbc.remove_contact(right_name, ramp_time=10 * g1.timestep)
    wbc.update(q, v)  # the ramp starts at this tick
    for _ in range(2):
        result = wbc.update(q, v)
        activation = wbc.contact_activation(right_name)
        assert 0.0 < activation < 1.0
        np.testing.assert_allclose(normal_shares(wbc, result), np.array([1.0, activation]) / (1.0 + activation), atol=1e-3)
    regularization.set_support_point(0.3 * left + 0.7 * right)
    result = wbc.update(q, v)
    activation = wbc.contact_activation(right_name)
    share = 0.3 / (0.3 + 0.7 * activation)
    np.testing.assert_allclose(normal_shares(wbc, result), [share, 1.0 - share], atol=1e-3)


def test_a_surface_foot_and_a_corner_foot_share_the_weight_by_the_lever_rule(g1: RobotDescription, g1_model: pin.Model) -> None:
    """One foot a 6D surface contact, the other four corner forces: as the support point moves
    from tick to tick, the feet's normal forces still follow the lever rule, the corner foot's
    load spread evenly over its corners."""
    wbc = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits, dt=g1.timestep)
    wbc.add_contact(foot_contacts(g1, "surface", mu=0.8)[0])
    wbc.add_contact(foot_contacts(g1, "corners", mu=0.8)[1])
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=1e-3, kp=10.0))
    regularization = wbc.add_task(ContactForceRegularization(weight=1.0))
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    wbc.update(q, v)
    left, right = (wbc.contact(contact.name).placement_in_world(wbc.kin).translation for contact in wbc.contacts)
    for expected in (0.5, 0.3, 0.8, 0.6):
        regularization.set_support_point(expected * left + (1.0 - expected) * right)
        result = wbc.update(q, v)
        assert result.ok, result.message
        np.testing.assert_allclose(normal_shares(wbc, result), [expected, 1.0 - expected], atol=1e-3)
        corners = wbc.contact_forces(wbc.contacts[1].name, result)[2::3]
        np.testing.assert_allclose(corners, corners.mean(), rtol=1e-3, atol=0.05)


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_each_foot_accelerates_as_its_motion_rows_ask(g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator, contact_model: str) -> None:
    """A made foot's spatial acceleration (from the returned q̈ by Pinocchio's forward
    kinematics, contact frame) is ``−Kd J v − Kp log(ref⁻¹ X)``: damping of its twist, and pose
    feedback towards where it was made — the batched path (surface feet, damping only) and the
    per-contact one (corner feet, pose feedback)."""
    kp = 0.0 if contact_model == "surface" else 25.0
    wbc = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits * 10, dt=g1.timestep)
    for contact in foot_contacts(g1, contact_model, mu=0.8, kd=6.0, kp=kp):
        wbc.add_contact(contact)
    if contact_model == "surface":  # a third contact (a hand on a rail): the batch handles any number
        wbc.add_contact(SurfaceContact("hand", "left_wrist_yaw_link", 0.02, 0.02, mu=0.8, kd=6.0))
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    q0 = g1.default_configuration()
    data = g1_model.createData()
    pin.framesForwardKinematics(g1_model, data, q0)
    made = {}
    for contact in wbc.contacts:
        made[contact.name] = data.oMi[contact.joint_id] * contact.placement
    assert wbc.update(q0, np.zeros(g1_model.nv)).ok  # the feet are made here
    q, v = disturbed_state(g1, g1_model, rng, scale=0.02, speed=0.5)
    result = wbc.update(q, v)
    assert result.ok, result.message
    pin.forwardKinematics(g1_model, data, q, v, result.qdd)
    for contact in wbc.contacts:
        twist = pin.getFrameVelocity(g1_model, data, contact.joint_id, contact.placement, pin.ReferenceFrame.LOCAL).vector
        acceleration = pin.getFrameClassicalAcceleration(g1_model, data, contact.joint_id, contact.placement, pin.ReferenceFrame.LOCAL).vector
        placement = data.oMi[contact.joint_id] * contact.placement
        expected = -6.0 * twist - kp * pin.log6(made[contact.name].actInv(placement)).vector
        assert np.linalg.norm(twist) > 0.05  # the foot moves: damping is exercised
        np.testing.assert_allclose(acceleration, expected, atol=1e-6)


def test_corner_forces_ramp_out_with_the_cap_shared_by_the_corners(g1: RobotDescription, g1_model: pin.Model) -> None:
    """A corner-model foot ramping out carries at most ``activation · F`` (F: its load when the
    ramp started), a quarter at each corner; the cap binds, since the regularisation asks for more."""
    wbc, _ = regularized_controller(g1, g1_model, "corners")
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    result = wbc.update(q, v)
    name = wbc.contacts[1].name
    start = float(np.sum(wbc.contact_forces(name, result)[2::3]))
    wbc.remove_contact(name, ramp_time=10 * g1.timestep)
    wbc.update(q, v)  # the ramp starts at this tick (activation 1: the bounds are not rewritten)
    for _ in range(6):
        result = wbc.update(q, v)
        cap = wbc.contact_activation(name) * start
        corners = wbc.contact_forces(name, result)[2::3]
        assert np.all(corners <= cap / 4 * (1 + 1e-7) + 1e-7)
        # The regularisation asks a/(1+a) of the weight, the cap allows a/2 of it: it binds.
        np.testing.assert_allclose(corners, cap / 4, rtol=1e-4)


@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_a_broken_foot_carries_nothing_moves_freely_and_can_be_made_again(g1: RobotDescription, g1_model: pin.Model, mj, rng: np.random.Generator, contact_model: str) -> None:
    """After ``remove_contact`` (no ramp) a foot's force variables are zero, its acceleration is
    no longer constrained, and MuJoCo's equation of motion holds with the other foot's wrench
    alone; made again, it carries load and is held still again."""
    mj_model, scratch = mj
    wbc = standing_controller(g1, g1_model, "proxsuite", contact_model, g1.effort_limits)
    wbc.contacts[0].kd = 0.0
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    assert wbc.update(q, v).ok
    name = wbc.contacts[1].name
    wbc.remove_contact(name)
    data = g1_model.createData()
    for _ in range(2):
        q, v = disturbed_state(g1, g1_model, rng, scale=0.02, speed=0.3)
        result = wbc.update(q, v)
        assert result.ok, result.message
        assert name not in result.contact_wrenches and name not in wbc.active_contacts
        np.testing.assert_array_equal(wbc.contact_forces(name, result), 0.0)
        np.testing.assert_array_equal(wbc.contact_wrench_world(name, result), np.zeros(6))
        residual = mujoco_residual(mj_model, scratch, g1.base_link, q, v, result, wbc)
        assert np.max(np.abs(residual)) < 1e-6 * g1.total_mass * 9.81
        pin.forwardKinematics(g1_model, data, q, v, result.qdd)
        broken = wbc.contact(name)
        free = pin.getFrameClassicalAcceleration(g1_model, data, broken.joint_id, broken.placement, pin.ReferenceFrame.LOCAL).vector
        assert np.linalg.norm(free) > 1e-2  # the broken foot is not held
    left = wbc.contact(wbc.contacts[0].name).placement_in_world(wbc.kin).translation
    wbc.force_regularization.set_support_point(left)  # the lever rule reads where the feet were made
    wbc.add_contact(wbc.contact(name), ramp_time=4 * g1.timestep)
    result = wbc.update(q, v)  # made again: its ramp starts here, at zero load
    assert result.ok and name in wbc.active_contacts
    assert result.contact_wrenches.get(name, np.zeros(6))[2] <= 1e-6
    wbc.force_regularization.set_support_point(None)
    for _ in range(4):
        result = wbc.update(q, v)
        # (a contact made again ramps its cap up to the model's weight)
        normal = result.contact_wrenches[name][2]  # the cap is on the normal of the sole (contact frame)
        assert wbc.contact_activation(name) == 1.0 or normal <= wbc.contact_activation(name) * wbc.kin.mass * np.linalg.norm(wbc.kin.gravity) * (1 + 1e-7) + 1e-6
    result = wbc.update(q, v)
    assert result.ok and wbc.contact_activation(name) == 1.0
    assert wbc.contact_wrench_world(name, result)[2] > 0.2 * g1.total_mass * 9.81
    pin.forwardKinematics(g1_model, data, q, v, result.qdd)
    made = wbc.contact(name)
    held = pin.getFrameClassicalAcceleration(g1_model, data, made.joint_id, made.placement, pin.ReferenceFrame.LOCAL).vector
    np.testing.assert_allclose(held, 0.0, atol=1e-6)


def test_a_failed_tick_reports_what_happened(g1: RobotDescription, g1_model: pin.Model) -> None:
    """The invalid-state result names the problem and its tick time, keeps consistent timings;
    on a fixed base whose kinematics were computed at an earlier state, a non-finite state still
    gets zero torque (not the gravity torque of that stale state); a wrong velocity shape raises."""
    arm = DoublePendulum()
    model = build_pinocchio_model(arm)
    wbc = WholeBodyController(model, torque_limits=np.array([100.0, 100.0]), dt=0.01)
    wbc.add_task(PostureTask(reference=np.zeros(2)))
    wbc.build(np.array([0.3, 0.5]), np.zeros(2))  # kinematics at a valid state, no torque yet
    before = time.perf_counter()
    result = wbc.update(np.array([0.3, np.inf]), np.zeros(2))
    elapsed = time.perf_counter() - before
    assert result.status is WbcStatus.INVALID_STATE and result.message == "state (q, v) is not finite"
    assert result.t == pytest.approx(0.01) and result.qp_status is None and result.iterations == 0
    np.testing.assert_array_equal(result.tau, 0.0)
    timings = result.timings
    assert 0.0 <= timings.total <= elapsed
    listed = wbc.update([0, 1], [0, 0])  # Python integers: taken as floats
    np.testing.assert_allclose(listed.tau, wbc.update(np.array([0.0, 1.0]), np.zeros(2)).tau)
    assert listed.ok
    with pytest.raises(ValueError, match=r"^v has shape \(1,\), expected \(2,\)"):
        wbc.update(np.array([0.3, 0.5]), np.zeros(1))
    # A QP failure: the timings of each phase, inside the call.
    infeasible = WholeBodyController(model, torque_limits=np.array([1.0, 100.0]))
    infeasible.add_contact(SurfaceContact("tip", "tip", 0.01, 0.01, min_normal_force=1000.0, max_normal_force=2000.0))
    infeasible.add_task(PostureTask(reference=np.zeros(2)))
    before = time.perf_counter()
    failed = infeasible.update(np.array([0.3, 0.5]), np.zeros(2))
    elapsed = time.perf_counter() - before
    assert failed.status is WbcStatus.QP_FAILED and failed.qp_status is not None and failed.message
    t = failed.timings
    assert min(t.pinocchio, t.build, t.solve) >= 0.0 and t.pinocchio + t.build + t.solve <= t.total <= elapsed
    assert failed.forces.shape == (6,) and np.all(np.isnan(failed.forces)) and np.all(np.isnan(failed.qdd))


def test_joint_limit_bounds_hold_a_joint_from_both_sides_and_never_cross(g1: RobotDescription, g1_model: pin.Model) -> None:
    """Acceleration bounds from the position limit (``q + v T + ½ q̈ T² ≥ q_min``) and from the
    velocity limit (``v + q̈ T ≥ −v_max``), whichever is tighter, stop a joint that a posture task
    drives into its lower limit; for a joint already past its upper limit and still moving out,
    the bounds conflict and the upper one wins (the box stays non-empty)."""
    T = 0.01
    wbc = WholeBodyController(g1_model, torque_limits=np.full(29, np.inf), joint_limits=True, joint_limit_horizon=T)
    lower, upper = g1.position_limits
    velocity_limit = g1_model.velocityLimit[6:]
    wbc.add_task(PostureTask(reference=lower - 1.0, weight=1.0, kp=1000.0, kd=0.0))  # every joint pulled below its limit
    q, v = g1.default_configuration(), np.zeros(35)
    knee, hip = 3, 0
    q[7 + knee], v[6 + knee] = lower[knee] + 0.005, -0.2  # the position bound is the tighter one
    q[7 + hip], v[6 + hip] = lower[hip] + 1.0, -velocity_limit[hip]  # at the velocity limit, far from the stop
    problem = wbc.build(q, v, 0.0)
    position_bound = 2.0 * (lower[knee] - q[7 + knee] - v[6 + knee] * T) / T**2
    assert problem.lb[6 + knee] == pytest.approx(position_bound)
    assert problem.lb[6 + hip] == pytest.approx((-velocity_limit[hip] - v[6 + hip]) / T)
    result = wbc.update(q, v, 0.002)
    assert result.ok, result.message
    assert result.qdd[6 + knee] == pytest.approx(position_bound, rel=1e-4)
    assert result.qdd[6 + hip] == pytest.approx(0.0, abs=1e-4)
    q[7 + knee], v[6 + knee] = upper[knee] + 0.1, 2.0  # outside, moving further out
    problem = wbc.build(q, v, 0.004)
    assert problem.lb[6 + knee] == problem.ub[6 + knee] < 0.0
    assert np.all(problem.lb <= problem.ub)


def test_joint_velocity_limits_hold_a_joint_driven_upwards(g1: RobotDescription, g1_model: pin.Model) -> None:
    """A posture task pulls every joint above its upper limit: a joint already at its velocity limit
    (far from the stop) may not speed up (q̈ = 0), and one at half of it speeds up only to the limit
    within the horizon (``v + q̈ T = v_max``)."""
    T = 0.01
    wbc = WholeBodyController(g1_model, torque_limits=np.full(29, np.inf), joint_limits=True, joint_limit_horizon=T)
    lower, upper = g1.position_limits
    velocity_limit = g1_model.velocityLimit[6:]
    wbc.add_task(PostureTask(reference=upper + 1.0, weight=1.0, kp=1000.0, kd=0.0))
    q, v = g1.default_configuration(), np.zeros(35)
    hip, knee = 0, 3
    q[7 + hip], v[6 + hip] = upper[hip] - 1.0, velocity_limit[hip]
    q[7 + knee], v[6 + knee] = 0.5 * (lower[knee] + upper[knee]), 0.5 * velocity_limit[knee]
    assert upper[knee] - q[7 + knee] > velocity_limit[knee] * T  # far enough: the velocity bound is the tighter one
    result = wbc.update(q, v, 0.0)
    assert result.ok, result.message
    assert result.qdd[6 + hip] == pytest.approx(0.0, abs=1e-4)
    assert v[6 + knee] + result.qdd[6 + knee] * T == pytest.approx(velocity_limit[knee], rel=1e-4)


def test_a_corner_cap_below_one_newton_holds(g1: RobotDescription, g1_model: pin.Model) -> None:
    """A foot that carried almost nothing when its removal started (the lever rule put the load on
    the other foot) may carry no more than that times its activation — even far below 1 N."""
    for contact_model in ("surface", "corners"):
        wbc, regularization = regularized_controller(g1, g1_model, contact_model)
        q, v = g1.default_configuration(), np.zeros(g1_model.nv)
        wbc.update(q, v)
        left = wbc.contact(wbc.contacts[0].name).placement_in_world(wbc.kin).translation
        regularization.set_support_point(left)
        result = wbc.update(q, v)
        name = wbc.contacts[1].name
        start = wbc.contact_wrench_world(name, result)[2]
        assert 0.0 <= start < 0.2
        wbc.remove_contact(name, ramp_time=10 * g1.timestep)
        regularization.set_support_point(None)  # now the regularisation asks for half the weight
        wbc.update(q, v)
        for _ in range(3):
            result = wbc.update(q, v)
            assert wbc.contact_wrench_world(name, result)[2] <= wbc.contact_activation(name) * start + 1e-6


def test_corner_forces_recovered_from_a_wrench_and_the_residual_outside_the_cone() -> None:
    """Inside the wrench cone: four corner forces in their pyramids that add up to the wrench.
    Outside it (more tangential force than μ allows): the residual is the size of the part of the
    wrench they cannot produce, in newtons."""
    X, Y, mu = 0.1, 0.05, 0.5
    wrench_of = corner_wrench_map(rectangle_corners(X, Y))
    inside = np.array([20.0, -10.0, 300.0, 3.0, -5.0, 1.0])
    forces, residual = corner_forces_from_wrench(inside, X, Y, mu)
    assert forces.shape == (4, 3) and residual < 1e-6
    np.testing.assert_allclose(wrench_of @ forces.reshape(-1), inside, atol=1e-6)
    assert np.all(np.abs(forces[:, :2]) <= mu * forces[:, 2:] + 1e-9)
    outside = np.array([400.0, 0.0, 300.0, 0.0, 0.0, 0.0])  # needs μ ≥ 4/3
    forces, residual = corner_forces_from_wrench(outside, X, Y, mu)
    missing = np.linalg.norm(wrench_of @ forces.reshape(-1) - outside)
    assert residual == pytest.approx(missing, rel=1e-6) and residual > 100.0


def test_the_lever_rule_uses_where_the_feet_were_made_on_a_turned_robot_with_ramping_feet(g1: RobotDescription, g1_model: pin.Model) -> None:
    """The robot turned 0.6 rad (the line between its feet crosses both world axes), both feet
    made with ramps of 10 and 20 ticks and the support point midway: each foot's share is its
    activation's share (the lever weights a half each); the total carried is the weight. Then the
    whole robot slides 5 cm: the shares still refer to where the feet were made."""
    wbc, regularization = regularized_controller(g1, g1_model, "surface")
    for contact, ticks in zip(wbc.contacts, (10, 20)):
        wbc.add_contact(contact, ramp_time=ticks * g1.timestep)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, 0.0, 0.6)).coeffs()
    kin = Kinodynamics(g1_model)
    kin.update(q, v)
    left, right = (c.placement_in_world(kin).translation for c in wbc.contacts)  # (bound to this model)
    assert abs(left[0] - right[0]) > 0.05 and abs(left[1] - right[1]) > 0.05
    regularization.set_support_point(0.5 * (left + right) + np.array([0.0, 0.0, 0.7]))
    weight = g1.total_mass * 9.81
    for tick in range(10):
        result = wbc.update(q, v)
    activations = np.array([wbc.contact_activation(c.name) for c in wbc.contacts])
    assert activations[0] == pytest.approx(0.9) and activations[1] == pytest.approx(0.45)
    np.testing.assert_allclose(normal_shares(wbc, result), activations / activations.sum(), atol=2e-3)
    result = wbc.update(q, v)  # the left foot fully made: the lever fast path
    load = np.array([wbc.contact_wrench_world(c.name, result)[2] for c in wbc.contacts])
    assert load.sum() == pytest.approx(weight, rel=0.01)
    regularization.set_support_point(0.3 * left + 0.7 * right)
    for _ in range(12):
        result = wbc.update(q, v)
    np.testing.assert_allclose(normal_shares(wbc, result), [0.3, 0.7], atol=2e-3)
    slid = q.copy()
    slid[:2] += [0.05, 0.03]
    result = wbc.update(slid, v)
    np.testing.assert_allclose(normal_shares(wbc, result), [0.3, 0.7], atol=2e-3)
    regularization.set_support_point(0.6 * left + 0.4 * right)  # a moved point: the lever's fast path
    result = wbc.update(slid, v)
    np.testing.assert_allclose(normal_shares(wbc, result), [0.6, 0.4], atol=2e-3)
    regularization.set_weight(0.9)  # a new weight: the general path, from where the feet were made
    result = wbc.update(slid, v)
    np.testing.assert_allclose(normal_shares(wbc, result), [0.6, 0.4], atol=2e-3)
    regularization.set_support_point(left + 0.5 * (left - right))  # beyond the left foot: all on it, no more
    result = wbc.update(q, v)
    load = np.array([wbc.contact_wrench_world(c.name, result)[2] for c in wbc.contacts])
    np.testing.assert_allclose(load / load.sum(), [1.0, 0.0], atol=2e-3)
    assert load.sum() == pytest.approx(weight, rel=0.01)


def test_a_solved_tick_reports_its_solver_status_counts_and_timings(g1: RobotDescription, g1_model: pin.Model) -> None:
    """Solver status, iterations, message, the failures so far (a failed tick counts on), and
    timings of each phase that add up within the call."""
    wbc = standing_controller(g1, g1_model, "proxsuite", "surface", g1.effort_limits)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    bad = q.copy()
    bad[0] = np.nan
    for state, failures in ((q, 0), (q, 0), (bad, 1), (q, 1)):
        before = time.perf_counter()
        result = wbc.update(state, v)
        elapsed = time.perf_counter() - before
        assert result.failures == failures
        if state is bad:
            continue
        assert result.ok and result.qp_status is QpStatus.SOLVED and isinstance(result.message, str)
        assert type(result.iterations) is int and result.iterations >= 0
        t = result.timings
        assert min(t.pinocchio, t.build, t.solve) >= 0.0 and t.pinocchio + t.build + t.solve <= t.total <= elapsed
    with pytest.raises(TypeError, match=r"^expected a Contact, got str$"):
        wbc.add_contact("left_foot")  # type: ignore[arg-type]


def test_a_contact_replaced_under_its_name_brings_its_own_friction_and_keeps_its_load(g1: RobotDescription, g1_model: pin.Model) -> None:
    """Made feet replaced by new contacts of the same names: with μ = 0.2 (same model), an
    impossible sideways acceleration saturates friction at the new μ; with the other foot model
    (a new size), the foot keeps carrying its load through the swap (its activation is kept)."""
    wbc = standing_controller(g1, g1_model, "proxsuite", "surface", g1.effort_limits * 100)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    assert wbc.update(q, v).ok
    for contact in foot_contacts(g1, "surface", mu=0.2):
        wbc.add_contact(contact)
    com = next(task for task in wbc.tasks if isinstance(task, ComTask))
    com.set_reference(wbc.kin.com, acceleration=np.array([0.0, 4.0, 0.0]))
    result = wbc.update(q, v)
    assert result.ok, result.message
    total = sum(wbc.contact_wrench_world(contact.name, result)[:3] for contact in wbc.contacts)
    assert total[1] == pytest.approx(0.2 * total[2], rel=1e-6)
    com.set_reference(wbc.kin.com)
    assert wbc.update(q, v).ok
    weight = wbc.kin.mass * 9.81
    for contact in foot_contacts(g1, "surface", mu=0.8, max_normal_force=0.45 * weight):  # new bounds too
        wbc.add_contact(contact)
    result = wbc.update(q, v)
    load = np.array([result.contact_wrenches[c.name][2] for c in wbc.contacts])
    np.testing.assert_allclose(load, 0.45 * weight, rtol=1e-6)  # both at the new cap (the robot sinks)
    for contact in foot_contacts(g1, "surface", mu=0.8):
        wbc.add_contact(contact)
    assert wbc.update(q, v).ok
    swapped = foot_contacts(g1, "corners", mu=0.8)[1]
    wbc.add_contact(swapped, ramp_time=0.1)
    result = wbc.update(q, v)
    assert result.ok and wbc.contact(swapped.name) is swapped
    assert wbc.contact_activation(swapped.name) == 1.0
    assert result.contact_wrenches[swapped.name][2] > 0.3 * g1.total_mass * 9.81  # no drop to zero


def test_a_made_foot_can_carry_more_than_the_weight(g1: RobotDescription, g1_model: pin.Model) -> None:
    """Once its ramp is over a contact has no cap: asked to accelerate the CoM up hard, the feet
    push ``m (g + c̈_z)`` together (Newton), more than the weight each."""
    wbc = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=g1.effort_limits * 100, dt=g1.timestep)
    for contact in foot_contacts(g1, "surface", mu=0.8):
        wbc.add_contact(contact, ramp_time=2 * g1.timestep)
    com = wbc.add_task(ComTask(weight=100.0, kp=0.0, kd=0.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    for _ in range(4):
        wbc.update(q, v)
    com.set_reference(wbc.kin.com, acceleration=np.array([0.0, 0.0, 40.0]))
    result = wbc.update(q, v)
    assert result.ok, result.message
    load = np.array([result.contact_wrenches[c.name][2] for c in wbc.contacts])
    weight = wbc.kin.mass * 9.81
    rise = (wbc.kin.com_jacobian @ result.qdd + wbc.kin.com_drift)[2]  # the CoM's vertical acceleration
    assert load.sum() == pytest.approx(wbc.kin.mass * (9.81 + rise), rel=1e-6)  # Newton: Σ f = m (c̈ − g)
    assert np.all(load > weight)


def test_changing_the_regularisation_weight_with_a_support_point_gives_the_problem_of_that_weight(g1: RobotDescription, g1_model: pin.Model) -> None:
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    changed, reg = regularized_controller(g1, g1_model, "surface")
    built, reg_built = regularized_controller(g1, g1_model, "surface")
    reg_built.set_weight(0.5)
    for wbc, regularization in ((changed, reg), (built, reg_built)):
        wbc.update(q, v)
        left = wbc.contact(wbc.contacts[0].name).placement_in_world(wbc.kin).translation
        regularization.set_support_point(left - [0.0, 0.05, 0.0])
        wbc.update(q, v)
        wbc.update(q, v)
    reg.set_weight(0.5)
    a, b = changed.build(q, v).copy(), built.build(q, v)
    np.testing.assert_allclose(a.H, b.H, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.g, b.g, rtol=1e-12, atol=1e-12)


def test_contact_settings_are_checked_and_feet_are_built_from_the_description(g1: RobotDescription) -> None:
    with pytest.raises(ValueError, match=r"^contact 'foot': friction coefficient mu must be > 0, got 0.0$"):
        SurfaceContact("foot", "pelvis", 0.1, 0.05, mu=0.0)
    with pytest.raises(ValueError, match=r"^contact 'foot': friction coefficient mu must be > 0, got inf$"):
        SurfaceContact("foot", "pelvis", 0.1, 0.05, mu=np.inf)
    with pytest.raises(ValueError, match=r"^contact 'foot': need 0 <= min_normal_force <= max_normal_force, got 20.0, 10.0$"):
        SurfaceContact("foot", "pelvis", 0.1, 0.05, min_normal_force=20.0, max_normal_force=10.0)
    pinned = SurfaceContact("foot", "pelvis", 0.1, 0.05, min_normal_force=10.0, max_normal_force=10.0)  # equal bounds: allowed
    assert pinned.min_normal_force == pinned.max_normal_force == 10.0
    with pytest.raises(ValueError, match=r"^contact 'foot': gains must be >= 0$"):
        SurfaceContact("foot", "pelvis", 0.1, 0.05, kd=-1.0)
    with pytest.raises(ValueError, match=r"^contact 'foot': half_length and half_width must be > 0$"):
        SurfaceContact("foot", "pelvis", 0.0, 0.05)
    for half_length, half_width in ((0.1, 0.0), (0.1, -0.05), (-0.1, 0.05)):  # a zero-width sole has no cone
        with pytest.raises(ValueError, match=r"^contact 'foot': half_length and half_width must be > 0$"):
            CornerContact("foot", "pelvis", half_length, half_width)
    shifted = SurfaceContact("foot", "pelvis", 0.1, 0.05, offset=[0.01, -0.02, 0.03])
    np.testing.assert_array_equal(shifted.offset.translation, [0.01, -0.02, 0.03])
    np.testing.assert_array_equal(shifted.offset.rotation, np.eye(3))
    with pytest.raises(ValueError, match=r"^unknown contact model 'points'; choose from \['corners', 'surface'\]$"):
        foot_contacts(g1, "points")
    for scale in (0.0, 1.5):
        with pytest.raises(ValueError, match=rf"^scale must be in \(0, 1\], got {scale}$"):
            foot_contacts(g1, scale=scale)
    box = replace(g1, contacts=tuple(replace(rectangle, sole=()) for rectangle in g1.contacts))  # rectangular soles
    for contact, rectangle in zip(foot_contacts(box, "corners", scale=0.5, mu=0.3), box.contacts):
        assert (contact.name, contact.link, contact.mu) == (rectangle.name, rectangle.link, 0.3)
        assert contact.half_length == 0.5 * rectangle.half_length and contact.half_width == 0.5 * rectangle.half_width
        np.testing.assert_array_equal(contact.offset.translation, rectangle.center)
    heel = ((0.08, 0.03), (0.08, -0.03), (-0.075, 0.012), (-0.075, -0.012))  # a narrower heel than toe
    trapezoid = replace(g1, contacts=tuple(replace(rectangle, sole=heel) for rectangle in g1.contacts))
    for contact, rectangle in zip(foot_contacts(trapezoid, "corners", scale=0.5, mu=0.3), trapezoid.contacts):
        offset, hull = sole_frame(rectangle)
        assert (contact.name, contact.link, contact.mu) == (rectangle.name, rectangle.link, 0.3)
        np.testing.assert_allclose(contact.corners[:, :2], 0.5 * hull, atol=1e-12)  # shrunk about its centroid ...
        np.testing.assert_allclose(contact.offset.translation, offset.translation)  # ... the contact frame's origin
        assert offset.translation[0] > rectangle.center[0]  # the heel narrower than the toe: the frame ahead of the centre


def test_the_first_joint_rotation_of_a_one_joint_model(rng: np.random.Generator) -> None:
    """``base_rotation`` is the world rotation of the model's first joint — also when that is its
    only joint (a pendulum), and it follows every update."""
    model = build_pinocchio_model(SimplePendulum.uniform_rod())
    kin = Kinodynamics(model)
    data = model.createData()
    for angle in rng.uniform(-2.0, 2.0, 3):
        q = np.array([angle])
        kin.update(q, np.zeros(1))
        pin.forwardKinematics(model, data, q)
        np.testing.assert_allclose(kin.base_rotation, data.oMi[1].rotation, atol=1e-15)
        assert not np.allclose(kin.base_rotation, np.eye(3))


def test_a_zero_force_reference_regularises_towards_no_force(g1: RobotDescription, g1_model: pin.Model) -> None:
    """``reference="zero"``: the regularisation's gradient on the force variables is zero — with
    or without a support point — where the default reference asks for the weight."""
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    gradients = {}
    for reference in ("weight", "zero"):
        wbc = WholeBodyController(g1_model, torque_limits=g1.effort_limits)
        for contact in foot_contacts(g1, "surface"):
            wbc.add_contact(contact)
        wbc.add_task(ComTask())
        regularization = wbc.add_task(ContactForceRegularization(weight=1e-3, reference=reference))
        wbc.update(q, v)
        regularization.set_support_point(wbc.kin.com)
        wbc.update(q, v)
        gradients[reference] = wbc.build(q, v).g[g1_model.nv :].copy()
    np.testing.assert_array_equal(gradients["zero"], 0.0)
    assert np.all(gradients["weight"][[2, 8]] < 0.0)  # towards a positive normal force on each foot


def test_kinodynamics_of_fixed_base_models_and_its_checks(g1: RobotDescription, g1_model: pin.Model, rng: np.random.Generator) -> None:
    """On a fixed-base arm the CoM drift written in place equals Pinocchio's CoM acceleration at
    q̈ = 0, joint rotations follow every update, and bad models or names are refused by name."""
    model = build_pinocchio_model(DoublePendulum())
    kin = Kinodynamics(model)
    data = model.createData()
    out = np.zeros(3)
    for _ in range(2):
        q, v = rng.uniform(-2.0, 2.0, 2), rng.uniform(-3.0, 3.0, 2)
        kin.update(q, v)
        kin.com_drift_into(out)
        pin.centerOfMass(model, data, q, v, np.zeros(2))
        np.testing.assert_allclose(out, data.acom[0], atol=1e-12)
        assert np.linalg.norm(out) > 0.1
        pin.forwardKinematics(model, data, q)
        for joint in (1, 2):
            np.testing.assert_allclose(kin.joint_rotation(joint), data.oMi[joint].rotation, atol=1e-15)
    all_base = Kinodynamics(model, n_base=2)  # every coordinate unactuated: allowed
    assert (all_base.n_base, all_base.n_joints) == (2, 0)
    with pytest.raises(ValueError, match=r"^n_base must be in \[0, 2\], got 3$"):
        Kinodynamics(model, n_base=3)
    with pytest.raises(TypeError, match=r"^expected a pinocchio.Model, got str$"):
        Kinodynamics("g1")  # type: ignore[arg-type]
    with pytest.raises(KeyError, match=r"model '.*' has no frame 'wing'"):
        Kinodynamics(g1_model).frame_id("wing")
    spherical = pin.Model()
    spherical.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    with pytest.raises(ValueError, match=r"^the joints after the base must all be single-DoF \(nq == nv\); got nq=4, nv=3, n_base=0$"):
        Kinodynamics(spherical)
