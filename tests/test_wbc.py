"""The inverse-dynamics QP: equation of motion, friction, statics, computed torque on closed-form
models, task Jacobians against finite differences, contact ramping, failures and fallbacks."""

from __future__ import annotations


import numpy as np
import pinocchio as pin
import pytest

from giwbc.control import (
    AngularMomentumTask,
    ComTask,
    ContactForceRegularization,
    CornerContact,
    FrameOrientationTask,
    FramePoseTask,
    FramePositionTask,
    PostureTask,
    QpStatus,
    SurfaceContact,
    WbcStatus,
    WholeBodyController,
    available_solvers,
    foot_contacts,
    make_balance_controller,
    make_solver,
)
from giwbc.control.contacts import (
    corner_forces_from_wrench,
    pyramid_generators,
    rectangle_corners,
    wrench_cone_matrix,
)
from giwbc.control.kinodynamics import Kinodynamics
from giwbc.testing import CartPole, DoublePendulum, PlanarFloatingArm, SimplePendulum
from giwbc.testing.checks import assert_computed_torque
from giwbc.testing.pinocchio_models import build_pinocchio_model, planar_floating_arm_model

SOLVERS = ["proxsuite", "osqp"]
ACCURATE = {"proxsuite": {"eps_abs": 1e-9, "max_iter": 100, "max_iter_in": 100}, "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 20000}}


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_pinocchio()


def g1_controller(g1, g1_model, solver: str, contact_model: str = "surface", accurate: bool = True) -> WholeBodyController:
    """Double support, CoM + pelvis orientation + posture + force regularisation, torque limits."""
    wbc = WholeBodyController(
        g1_model,
        solver=solver,
        solver_settings=ACCURATE[solver] if accurate else None,
        torque_limits=g1.effort_limits,
        impedance_kd=g1.kd * 0.1,
    )
    for contact in foot_contacts(g1, contact_model, mu=0.8):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    return wbc


def random_state(g1, model, rng, scale=0.05, speed=0.5):
    q = pin.integrate(model, g1.default_configuration(), rng.uniform(-scale, scale, model.nv))
    return q, rng.uniform(-speed, speed, model.nv)


def eom_residual(wbc: WholeBodyController, result) -> np.ndarray:
    """``M q̈ + h − Sᵀτ − Σ Jᵀ Φ f`` with the controller's current kinematics."""
    kin = wbc.kin
    tau_full = np.zeros(kin.nv)
    tau_full[kin.n_base :] = result.tau
    return kin.mass_matrix @ result.qdd + kin.nonlinear_effects - tau_full - wbc.generalized_contact_forces(result.forces)


# --- friction model ------------------------------------------------------------------------------
def test_wrench_cone_is_the_span_of_the_corner_pyramids(rng):
    """A wrench satisfies the 16 face inequalities iff 4 corner forces in their pyramids make it."""
    X, Y, mu = 0.085, 0.03, 0.8
    faces = wrench_cone_matrix(X, Y, mu)
    generators = pyramid_generators(rectangle_corners(X, Y), mu)
    assert np.max(faces @ generators) <= 1e-12  # every edge is inside
    agree = 0
    for _ in range(3000):
        wrench = rng.normal(size=6) * np.array([1.0, 1.0, 3.0, 0.1, 0.1, 0.05])
        wrench[2] = abs(wrench[2])
        inside = bool(np.all(faces @ wrench <= 1e-12))
        forces, residual = corner_forces_from_wrench(wrench, X, Y, mu)
        assert inside == (residual < 1e-9)
        if inside:
            agree += 1
            np.testing.assert_allclose(forces.sum(axis=0), wrench[:3], atol=1e-9)
            assert np.all(np.abs(forces[:, :2]) <= mu * forces[:, 2:] + 1e-9)
    assert agree > 100  # the sample did hit the cone


# --- equation of motion and friction on G1 ------------------------------------------------------
@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("contact_model", ["surface", "corners"])
def test_equation_of_motion_and_friction_in_double_support(g1, g1_model, rng, solver, contact_model):
    wbc = g1_controller(g1, g1_model, solver, contact_model)
    mu = 0.8
    for _ in range(8):
        q, v = random_state(g1, g1_model, rng)
        result = wbc.update(q, v)
        assert result.ok, result.message
        residual = eom_residual(wbc, result)
        assert np.max(np.abs(residual)) < 1e-5 * g1.total_mass * 9.81, residual
        assert np.all(np.abs(result.tau) <= g1.effort_limits + 1e-9)
        for name, wrench in result.contact_wrenches.items():
            contact = wbc.contact(name)
            corners = contact.corner_forces(wbc.contact_forces(name, result))
            # Every corner force inside its pyramid (hence the CoP inside the foot) and unilateral.
            assert np.all(corners[:, 2] >= -1e-5)
            assert np.all(np.abs(corners[:, :2]) <= mu * corners[:, 2:] + 1e-5), corners
            np.testing.assert_allclose(corners.sum(axis=0), wrench[:3], atol=1e-5)
            if wrench[2] > 1.0:  # centre of pressure inside the (contact-frame) rectangle
                cop = np.array([-wrench[4], wrench[3]]) / wrench[2]
                assert abs(cop[0]) <= contact.half_length + 1e-6 and abs(cop[1]) <= contact.half_width + 1e-6


@pytest.mark.parametrize("solver", SOLVERS)
def test_standing_still_carries_exactly_the_weight(g1, g1_model, solver):
    wbc = g1_controller(g1, g1_model, solver)
    result = wbc.update(g1.default_configuration(), np.zeros(g1_model.nv))
    assert result.ok
    total = sum(wbc.contact_wrench_world(name, result)[:3] for name in result.contact_wrenches)
    weight = wbc.kin.mass * 9.81
    assert abs(total[2] - weight) <= 1e-3 * weight
    assert np.all(np.abs(total[:2]) <= 1e-3 * weight)
    # The description's mass (URDF) and the model's agree.
    assert wbc.kin.mass == pytest.approx(g1.total_mass, rel=1e-9)
    # Nothing moves: the base does not accelerate.
    assert np.max(np.abs(result.qdd)) < 1e-3


def test_the_contact_force_regularisation_is_on_by_default_and_its_absence_is_named(g1, g1_model, rng):
    """Without a force regularisation the two feet's forces are not unique (a singular Hessian)
    and proxsuite finds no KKT point on the G1: the controller therefore has one from
    construction — no ``add_task`` needed — and every tick solves with the weight shared by the
    feet; removed, every tick fails and the message names the missing regularisation."""
    wbc = WholeBodyController(g1_model, torque_limits=g1.effort_limits)
    for contact in foot_contacts(g1, mu=0.8):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    weight = wbc.kin.mass * 9.81
    for tick in range(4):
        q, v = random_state(g1, g1_model, rng, scale=0.02, speed=0.1) if tick else (g1.default_configuration(), np.zeros(g1_model.nv))
        result = wbc.update(q, v)
        assert result.ok, result.failure()
        assert np.max(np.abs(eom_residual(wbc, result))) < 1e-5 * weight
    standing = wbc.update(g1.default_configuration(), np.zeros(g1_model.nv))
    normals = [wbc.contact_wrench_world(name, standing)[2] for name in ("left_foot", "right_foot")]
    assert normals[0] == pytest.approx(weight / 2, rel=0.05) and normals[1] == pytest.approx(weight / 2, rel=0.05)
    wbc.remove_task("contact_forces")
    wbc.reset()
    for _ in range(2):
        failed = wbc.update(g1.default_configuration(), np.zeros(g1_model.nv))
        assert not failed.ok and "no contact-force regularisation" in failed.message
        assert failed.message.endswith("add a ContactForceRegularization)")  # names the class to add
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    assert wbc.update(g1.default_configuration(), np.zeros(g1_model.nv)).ok


# --- computed torque on closed-form fixed-base models -------------------------------------------
@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("params", [SimplePendulum.uniform_rod(), DoublePendulum(), CartPole()], ids=lambda p: type(p).__name__)
def test_posture_acceleration_task_is_computed_torque(params, solver, rng):
    """With only a joint-acceleration task, the WBC is τ = M q̈* + C q̇ + g of the analytic model."""
    model = build_pinocchio_model(params)
    wbc = WholeBodyController(model, solver=solver, solver_settings=ACCURATE[solver], acceleration_regularization=0.0)
    task = wbc.add_task(PostureTask(dim=model.nv, kp=0.0, kd=0.0))
    assert wbc.n_base == 0

    def controller(q, qd, qdd):
        task.set_reference(q, qd, qdd)  # zero error: the target is the feed-forward acceleration
        result = wbc.update(q, qd)
        assert result.ok, result.message
        return result.tau

    assert_computed_torque(controller, params, rng, n_states=15, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("solver", SOLVERS)
def test_torque_limits_bind_on_a_fixed_base(solver, rng):
    model = build_pinocchio_model(DoublePendulum())
    wbc = WholeBodyController(model, solver=solver, torque_limits=np.array([5.0, 2.0]))
    task = wbc.add_task(PostureTask(dim=2))
    task.set_reference(np.zeros(2), np.zeros(2), np.array([50.0, -50.0]))
    result = wbc.update(np.array([0.3, -0.2]), np.zeros(2))
    assert result.ok
    np.testing.assert_allclose(np.abs(result.tau), [5.0, 2.0], atol=1e-4)


@pytest.mark.parametrize("solver", SOLVERS)
def test_underactuated_planar_base_without_contacts(solver, rng):
    """A floating (planar) base with no contact: the base rows force free-fall dynamics."""
    params = PlanarFloatingArm()
    model = planar_floating_arm_model(params)
    wbc = WholeBodyController(model, solver=solver, solver_settings=ACCURATE[solver], n_base=3)
    wbc.add_task(FramePositionTask("tip", kp=10.0))
    for _ in range(5):
        q, v = rng.uniform(-1, 1, 4), rng.uniform(-1, 1, 4)
        result = wbc.update(q, v)
        assert result.ok
        tau = np.concatenate([np.zeros(3), result.tau])
        expected_qdd = params.forward_dynamics(q, v, tau)
        np.testing.assert_allclose(result.qdd, expected_qdd, atol=1e-6)


# --- task Jacobians against finite differences on the manifold ----------------------------------
def _task_cases(g1):
    return [
        ComTask(),
        FramePoseTask("left_wrist_yaw_link"),
        FramePositionTask("torso_link"),
        FrameOrientationTask("pelvis"),
        FramePoseTask("right_ankle_roll_link", mask=[1, 0, 1, 0, 1, 0]),
        PostureTask(reference=g1.default_positions),
    ]


def _task_value(task, kin):
    """The quantity a task's Jacobian differentiates: position, rotation, joint angles."""
    if isinstance(task, ComTask):
        return np.array(kin.com)
    if isinstance(task, PostureTask):
        return np.array(kin.q[kin.joint_q])
    placement = kin.frame_placement(task.frame_id)
    return pin.SE3(placement)


def _difference(task, plus, minus):
    if isinstance(plus, pin.SE3):
        linear = plus.translation - minus.translation
        angular = pin.log3(plus.rotation @ minus.rotation.T)
        return np.concatenate([linear, angular])[task.rows]
    return plus - minus


@pytest.mark.parametrize("index", range(6))
def test_task_jacobians_and_drifts_against_finite_differences(g1, g1_model, rng, index):
    task = _task_cases(g1)[index]
    kin = Kinodynamics(g1_model)
    task.bind(kin)
    q, v = random_state(g1, g1_model, rng, scale=0.3, speed=1.0)
    a = rng.uniform(-1, 1, g1_model.nv)
    kin.update(q, v)
    task.compute(kin)
    jacobian, drift = task.jacobian.copy(), task.drift.copy()
    eps = 1e-6
    numeric = np.zeros_like(jacobian)
    probe = Kinodynamics(g1_model)
    for i in range(g1_model.nv):
        dq = np.zeros(g1_model.nv)
        dq[i] = eps
        probe.update(pin.integrate(g1_model, q, dq), v)
        plus = _task_value(task, probe)
        probe.update(pin.integrate(g1_model, q, -dq), v)
        minus = _task_value(task, probe)
        numeric[:, i] = _difference(task, plus, minus) / (2 * eps)
    np.testing.assert_allclose(jacobian, numeric, atol=1e-6)
    # Drift: d/dt (J v) − J a along q ⊕ v t, v + a t.
    h = 1e-6
    rates = []
    for sign in (1.0, -1.0):
        probe.update(pin.integrate(g1_model, q, sign * v * h), v + sign * a * h)
        task.compute(probe)
        rates.append(task.jacobian @ probe.v)
    np.testing.assert_allclose(jacobian @ a + drift, (rates[0] - rates[1]) / (2 * h), atol=2e-5)
    # The task's error is reference minus value, and its rate is v_ref − J v.
    kin.update(q, v)
    task.compute(kin)
    np.testing.assert_allclose(task.error_velocity, task.velocity_ref - jacobian @ v, atol=1e-12)


@pytest.mark.parametrize("mask", [None, [0, 0, 0, 1, 0, 1]], ids=["all", "roll-yaw"])
def test_orientation_error_is_the_rotation_vector_to_the_reference(g1, g1_model, rng, mask):
    """Each row of the error is its own component of ``log3(R_ref Rᵀ)`` — on the floating base
    (rows written from the base rotation, no Pinocchio call) and on another link. (The committed
    version repeated the first component in every row.)"""
    for frame in ("pelvis", "torso_link"):
        task = FrameOrientationTask(frame) if mask is None else FramePoseTask(frame, mask=mask)
        kin = Kinodynamics(g1_model)
        task.bind(kin)
        assert task._root == (frame == "pelvis")
        q, v = random_state(g1, g1_model, rng, scale=0.3, speed=1.0)
        kin.update(q, v)
        reference = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.zeros(3))
        task.set_reference(reference)
        task.compute(kin)
        rotation = kin.frame_placement(task.frame_id).rotation
        np.testing.assert_allclose(task.error, pin.log3(reference.rotation @ rotation.T)[task.rows - 3], atol=1e-12)
        expected = kin.frame_jacobian(task.frame_id)[task.rows]
        np.testing.assert_allclose(task.jacobian, expected, atol=1e-12)


def test_base_orientation_weights_per_row_regroup_the_task_stack(g1):
    """The base orientation's Hessian is the constant ``w I`` only for one weight on all rows:
    per-row weights move it back among the state-dependent tasks, with the same problem as a
    controller built that way."""
    q, v = g1.default_configuration(), np.zeros(35)
    changed = make_balance_controller(g1)
    changed.update(q, v, 0.0)
    changed.base_task.set_weight([1.0, 1.0, 2.0])
    changed.update(q, v, 0.002)
    built = make_balance_controller(g1)
    built.base_task.set_weight([1.0, 1.0, 2.0])
    built.update(q, v, 0.0)
    built.update(q, v, 0.002)
    np.testing.assert_array_equal(changed.wbc.problem.H, built.wbc.problem.H)
    np.testing.assert_array_equal(changed.wbc.problem.g, built.wbc.problem.g)
    assert changed.wbc._stack.groups == [0, 0, 2]


def test_angular_momentum_task_jacobian_and_drift(g1, g1_model, rng):
    """L̇ = A q̈ + Ȧ v: finite differences of L(q(t), v(t))."""
    task = AngularMomentumTask()
    kin = Kinodynamics(g1_model)
    task.bind(kin)
    q, v = random_state(g1, g1_model, rng, scale=0.3, speed=1.0)
    a = rng.uniform(-1, 1, g1_model.nv)
    kin.update(q, v)
    task.compute(kin)
    h = 1e-6
    momentum = []
    for sign in (1.0, -1.0):
        kin.update(pin.integrate(g1_model, q, sign * v * h), v + sign * a * h)
        momentum.append(np.array(kin.centroidal_momentum[3:]))
    np.testing.assert_allclose(task.jacobian @ a + task.drift, (momentum[0] - momentum[1]) / (2 * h), atol=2e-5)
    np.testing.assert_allclose(task.error_velocity, -(task.jacobian @ v), atol=1e-10)


def test_task_settings_are_validated():
    with pytest.raises(ValueError):
        ComTask(weight=-1.0)
    with pytest.raises(ValueError):
        ComTask(kp=[1.0, 2.0])
    task = ComTask(kp=100.0)
    np.testing.assert_allclose(task.kd, 20.0)  # critical damping by default
    version, ref_version = task.version, task.ref_version
    task.set_reference([0.0, 0.0, 0.7], velocity=[0.1, 0.0, 0.0])
    assert task.ref_version > ref_version and task.version == version
    ref_version = task.ref_version
    task.set_reference([0.0, 0.0, 0.7])  # the rates go back to zero: a change
    assert task.ref_version > ref_version
    ref_version = task.ref_version
    task.set_reference([0.0, 0.0, 0.71])  # still no rates: nothing for the controller to gather
    assert task.ref_version == ref_version and task.position_ref[2] == 0.71
    task.set_weight(2.0)
    assert task.version > version
    with pytest.raises(ValueError):
        task.set_reference([0.0, np.nan, 0.7])
    with pytest.raises(ValueError):
        FramePoseTask("pelvis", mask=[0] * 6)
    with pytest.raises(TypeError):
        FramePoseTask("pelvis").set_reference(np.eye(4))


# --- the problem, its structure and the solvers --------------------------------------------------
def test_build_returns_an_inspectable_problem(g1, g1_model, rng):
    wbc = g1_controller(g1, g1_model, "proxsuite")
    q, v = random_state(g1, g1_model, rng)
    problem = wbc.build(q, v, 0.0)
    problem.validate()
    # 35 accelerations + 2 × 6 wrench variables; 6 base rows + 2 × 6 contact rows;
    # 29 torque rows + 2 × 17 wrench-cone rows.
    assert (problem.n, problem.n_eq, problem.n_in) == (47, 18, 63)
    np.testing.assert_allclose(problem.H, problem.H.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(problem.H) > 0)
    solution = wbc.solve()
    assert solution.ok and problem.violation(solution.x) < 1e-6
    kept = problem.copy()
    # Any tick's QP goes to another solver in one line, with the same optimum.
    from giwbc.control.qp.proxsuite_build import import_qpsolvers

    other = import_qpsolvers().solve_problem(problem.to_qpsolvers(), solver="osqp", eps_abs=1e-9, eps_rel=1e-9, polish=True)
    assert other.found
    np.testing.assert_allclose(other.x, solution.x, atol=1e-4)
    assert problem.violation(other.x) < 1e-6
    wbc.build(*random_state(g1, g1_model, rng))
    assert not np.array_equal(kept.H, wbc.problem.H)  # the controller's buffers moved on, the copy did not


def test_sparsity_patterns_cover_every_nonzero(g1, g1_model, rng):
    """The structural masks OSQP is set up with must contain every entry that is ever non-zero."""
    for contact_model in ("surface", "corners"):
        wbc = g1_controller(g1, g1_model, "proxsuite", contact_model)
        for _ in range(5):
            p = wbc.build(*random_state(g1, g1_model, rng, scale=0.5, speed=2.0))
            assert not np.any((p.H != 0) & ~p.H_pattern)
            ac = np.vstack([p.A, p.C])
            assert not np.any((ac != 0) & ~p.AC_pattern)


def test_solver_backends_agree(g1, g1_model, rng):
    q, v = random_state(g1, g1_model, rng)
    results = {}
    for solver in ["proxsuite", "osqp", "qpsolvers:proxqp"]:
        wbc = g1_controller(g1, g1_model, solver, accurate=solver != "qpsolvers:proxqp")
        results[solver] = wbc.update(q, v)
        assert results[solver].ok
    np.testing.assert_allclose(results["proxsuite"].tau, results["osqp"].tau, atol=1e-3)
    np.testing.assert_allclose(results["proxsuite"].tau, results["qpsolvers:proxqp"].tau, atol=1e-3)
    assert "proxsuite" in available_solvers() and "osqp" in available_solvers()
    with pytest.raises(ValueError, match="unknown QP solver"):
        make_solver("no-such-solver")


# --- contacts at run time ------------------------------------------------------------------------
@pytest.mark.parametrize("solver", SOLVERS)
def test_contact_removal_ramps_the_force_down_and_keeps_torques_continuous(g1, g1_model, solver):
    wbc = g1_controller(g1, g1_model, solver, accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    dt = 0.002
    result = wbc.update(q, v, 0.0)
    structure = wbc.problem.structure
    wbc.remove_contact("right_foot", ramp_time=0.1)
    previous = result.tau
    normal = []
    jumps = []
    for i in range(1, 80):
        result = wbc.update(q, v, i * dt)
        assert result.ok, result.message
        normal.append(result.contact_wrenches.get("right_foot", np.zeros(6))[2])
        jumps.append(np.max(np.abs(result.tau - previous)))
        previous = result.tau
        # The cap falls linearly from the load at removal to zero, from the first tick after the call.
        bound = 163.6 * max(0.0, 1.0 - (i - 1) * dt / 0.1)
        assert normal[-1] <= bound + 0.5
    assert normal[-1] == 0.0 and "right_foot" not in wbc.active_contacts
    assert wbc.contact_activation("right_foot") == 0.0
    assert wbc.problem.structure == structure  # the slot stays: no re-initialisation
    # Torques are continuous during the ramp: removing the contact at once jumps by the load of a
    # whole foot; the ramp spreads that over 50 ticks.
    abrupt = g1_controller(g1, g1_model, solver, accurate=False)
    before = abrupt.update(q, v, 0.0).tau
    abrupt.remove_contact("right_foot")
    step = np.max(np.abs(abrupt.update(q, v, dt).tau - before))
    assert max(jumps) < 0.1 * step, (max(jumps), step)
    # Re-adding the same contact ramps it back up and reuses its slot.
    wbc.add_contact(wbc.contact("right_foot"), ramp_time=0.05)
    for i in range(80, 120):
        result = wbc.update(q, v, i * dt)
    assert result.ok and wbc.contact_activation("right_foot") == 1.0
    assert wbc.problem.structure == structure
    assert result.contact_wrenches["right_foot"][2] > 100.0


def test_a_re_made_contact_carries_no_force_before_its_ramp_allows_it(g1, g1_model):
    """A foot lifted off (ramped to zero) and put down again with a ramp: at the tick it is made
    again its activation is 0, so it carries no force (the whole weight on the other foot), and
    on the following ticks its normal force follows the cap activation × weight."""
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    dt = 0.002
    wbc.update(q, v, 0.0)
    wbc.remove_contact("right_foot", ramp_time=0.02)
    for i in range(1, 20):
        assert wbc.update(q, v, i * dt).ok
    assert wbc.contact_activation("right_foot") == 0.0 and "right_foot" not in wbc.active_contacts
    weight = g1.total_mass * 9.81
    wbc.add_contact(wbc.contact("right_foot"), ramp_time=0.1)
    for i in range(20, 26):
        result = wbc.update(q, v, i * dt)
        assert result.ok, result.failure()
        activation = wbc.contact_activation("right_foot")
        assert activation == pytest.approx((i - 20) * dt / 0.1)
        right = wbc.contact_forces("right_foot", result)  # the force variables, reported or not
        assert right[2] <= activation * weight + 1e-6
        np.testing.assert_allclose(right, 0.0, atol=1e-6 + activation * weight)
        # Statics at rest: the two feet together still carry the weight.
        total = wbc.contact_wrench_world("left_foot", result)[2] + wbc.contact_wrench_world("right_foot", result)[2]
        assert total == pytest.approx(weight, rel=0.05)


def test_a_broken_foot_carries_no_force_with_a_sparse_solver(g1, g1_model):
    """OSQP (fixed sparsity pattern): once a foot's force has ramped to zero, its six force
    variables stay zero (a broken 6D contact's ``f = 0`` rows are in the pattern) and the other
    foot carries the whole weight."""
    wbc = g1_controller(g1, g1_model, "osqp")
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    wbc.update(q, v, 0.0)
    wbc.remove_contact("right_foot", ramp_time=0.01)
    for i in range(1, 12):
        result = wbc.update(q, v, i * 0.002)
        assert result.ok, result.failure()
    assert "right_foot" not in wbc.active_contacts
    np.testing.assert_allclose(wbc.contact_forces("right_foot", result), 0.0, atol=1e-6)
    assert wbc.contact_wrench_world("left_foot", result)[2] == pytest.approx(g1.total_mass * 9.81, rel=0.02)


def test_a_foot_put_down_again_anchors_anew_and_lifts_off_from_its_load(g1, g1_model):
    """A foot lifted off and put down again takes its new ground position (the lever rule with a
    support point on it puts the weight there), and lifted again mid-ramp its force falls from the
    load it carries then (no jump down)."""
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    dt, t = 0.002, 0.0
    wbc.update(q, v, t)
    wbc.remove_contact("right_foot", ramp_time=0.01)
    for _ in range(8):
        t += dt
        wbc.update(q, v, t)
    assert "right_foot" not in wbc.active_contacts
    wbc.add_contact(wbc.contact("right_foot"), ramp_time=0.01)
    for _ in range(8):
        t += dt
        result = wbc.update(q, v, t)
    assert wbc.contact_activation("right_foot") == 1.0
    right = wbc.contact("right_foot").placement_in_world(wbc.kin).translation
    wbc.force_regularization.set_support_point(right)
    t += dt
    result = wbc.update(q, v, t)
    assert result.ok, result.failure()
    weight = g1.total_mass * 9.81
    assert wbc.contact_wrench_world("right_foot", result)[2] > 0.6 * weight  # more than its even share
    # Lifted again while its force ramps back up: the cap starts from the load at that moment.
    wbc.force_regularization.set_support_point(None)
    wbc.remove_contact("right_foot", ramp_time=0.01)
    for _ in range(8):
        t += dt
        wbc.update(q, v, t)
    wbc.add_contact(wbc.contact("right_foot"), ramp_time=0.1)
    for _ in range(26):
        t += dt
        result = wbc.update(q, v, t)
    activation = wbc.contact_activation("right_foot")
    load = wbc.contact_wrench_world("right_foot", result)[2]
    assert 0.3 < activation < 0.7 and load > 0.1 * weight
    wbc.remove_contact("right_foot", ramp_time=0.1)
    for _ in range(5):
        t += dt
        result = wbc.update(q, v, t)
        assert result.ok, result.failure()
        cap = load * wbc.contact_activation("right_foot") / activation
        assert 0.9 * cap < wbc.contact_wrench_world("right_foot", result)[2] <= cap + 1e-6
    assert wbc.contact_activation("right_foot") < activation


def test_a_contact_not_made_yet_is_placed_where_its_sole_is_now(g1, g1_model):
    """Before a contact takes its reference pose (after a reset), its ground position is the
    sole's current position: forward kinematics of the sole frame, with the base moved off the
    origin so that x and y differ."""
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    q[:2] += (0.7, -0.3)
    assert wbc.update(q, v, 0.0).ok
    wbc.reset()
    data = g1_model.createData()
    pin.framesForwardKinematics(g1_model, data, q)
    for contact in wbc.contacts:
        assert contact.reference is None
        sole = data.oMf[g1_model.getFrameId(contact.link)] * contact.offset
        xy = wbc.contact_set.contact_xy(wbc.contact_set.slot(contact.name))
        np.testing.assert_allclose(xy, sole.translation[:2], atol=1e-9)
    assert abs(xy[0] - xy[1]) > 0.1


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_contact_swapped_for_one_of_the_same_size_solves_as_a_fresh_controller(g1, g1_model, solver):
    """The right foot forgotten and a hand contact of the same size added: the problem keeps its
    dimensions but not its sparsity pattern, and the next tick must solve as a controller built
    with those contacts from the start (same torques, a hand force that supports the robot)."""
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    swapped = g1_controller(g1, g1_model, solver)
    assert swapped.update(q, v, 0.0).ok
    n = swapped.problem.n
    swapped.forget_contact("right_foot")
    swapped.add_contact(SurfaceContact("right_hand", "right_wrist_yaw_link", 0.02, 0.02, mu=0.8))
    fresh = g1_controller(g1, g1_model, solver)
    fresh.forget_contact("right_foot")
    fresh.add_contact(SurfaceContact("right_hand", "right_wrist_yaw_link", 0.02, 0.02, mu=0.8))
    assert fresh.update(q, v, 0.0).ok
    a, b = swapped.update(q, v, 0.002), fresh.update(q, v, 0.002)
    assert a.ok and b.ok, (a.message, b.message)
    assert swapped.problem.n == n
    weight = g1.total_mass * 9.81
    np.testing.assert_allclose(a.tau, b.tau, atol=1e-3 * weight)
    np.testing.assert_allclose(a.qdd, b.qdd, atol=1e-3)


def test_the_answer_at_a_state_does_not_depend_on_the_states_before(g1, g1_model, rng):
    """A controller that ran at another base orientation with another pelvis-orientation weight,
    then had that weight changed and ran there once more, answers at a new state as a fresh
    controller built with the new weight: the same torques and accelerations (the base-orientation
    rows follow the base, and a weight change reaches the Hessian)."""
    q1, v1 = random_state(g1, g1_model, rng, scale=0.1, speed=0.5)
    q2, v2 = random_state(g1, g1_model, rng, scale=0.1, speed=0.5)

    def controller():  # the same references, whatever the first tick's state
        wbc = g1_controller(g1, g1_model, "proxsuite")
        wbc.task("com").set_reference(np.array([0.0, 0.0, 0.6]))
        wbc.task("pelvis_orientation").set_reference(pin.SE3(pin.rpy.rpyToMatrix(0.05, -0.1, 0.2), np.zeros(3)))
        return wbc

    used = controller()
    for i in range(3):
        assert used.update(q1, v1, i * 0.002).ok
    used.task("pelvis_orientation").set_weight(30.0)
    assert used.update(q1, v1, 0.006).ok
    fresh = controller()
    fresh.task("pelvis_orientation").set_weight(30.0)
    a, b = used.update(q2, v2, 0.008), fresh.update(q2, v2, 0.008)
    assert a.ok and b.ok, (a.message, b.message)
    np.testing.assert_allclose(a.qdd, b.qdd, atol=1e-5)
    np.testing.assert_allclose(a.tau, b.tau, atol=1e-4)
    unweighted = controller().update(q2, v2, 0.008)
    assert np.max(np.abs(unweighted.qdd - b.qdd)) > 1e-2  # the weight matters at this state


def test_a_new_contact_grows_the_problem(g1, g1_model):
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    wbc.update(q, v, 0.0)
    n = wbc.problem.n
    wbc.add_contact(SurfaceContact("left_hand", "left_wrist_yaw_link", 0.02, 0.02), ramp_time=0.1)
    wbc.remove_contact("left_hand")
    result = wbc.update(q, v, 0.002)
    assert result.ok and wbc.problem.n == n + 6
    wbc.forget_contact("left_hand")
    assert wbc.update(q, v, 0.004).ok and wbc.problem.n == n
    with pytest.raises(KeyError):
        wbc.remove_contact("nowhere")


# --- failures never raise inside the loop --------------------------------------------------------
def test_a_fallback_before_any_qp_says_so(g1, g1_model):
    """A non-finite state falls back before any QP is built: the failure names no QP status."""
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    assert wbc.update(q, v, 0.0).failure() is None
    q[10] = np.nan
    result = wbc.update(q, v, 0.002)
    assert result.qp_status is None
    assert result.failure() == "whole-body controller invalid_state (no QP): state (q, v) is not finite"


@pytest.mark.parametrize("solver", SOLVERS)
def test_non_finite_state_returns_a_fallback(g1, g1_model, solver):
    wbc = g1_controller(g1, g1_model, solver, accurate=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    good = wbc.update(q, v, 0.0)
    bad_q = q.copy()
    bad_q[10] = np.nan
    result = wbc.update(bad_q, v, 0.002)
    assert result.status is WbcStatus.INVALID_STATE and not result.ok
    np.testing.assert_allclose(result.tau, good.tau * wbc.fallback_decay)
    assert result.failures == 1 and wbc.failures == 1 and wbc.consecutive_failures == 1
    assert np.all(np.isfinite(result.impedance.tau_ff)) and np.all(result.impedance.kp == 0)
    result = wbc.update(q, np.full(g1_model.nv, np.inf), 0.004)
    assert result.status is WbcStatus.INVALID_STATE and wbc.consecutive_failures == 2
    np.testing.assert_allclose(result.tau, good.tau * wbc.fallback_decay**2)
    assert wbc.update(q, v, 0.006).ok and wbc.consecutive_failures == 0
    with pytest.raises(ValueError, match="shape"):
        wbc.update(q[:-1], v)


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_problem_returns_a_fallback(g1, g1_model, solver):
    """Limp joints (1 mN m) cannot push the feet down with twice the weight each: the QP is
    infeasible, the tick is not."""
    wbc = WholeBodyController(g1_model, solver=solver, torque_limits=np.full(29, 1e-3), solver_settings={"max_iter": 200})
    weight = g1.total_mass * 9.81
    for contact in foot_contacts(g1, min_normal_force=2 * weight, max_normal_force=3 * weight):
        wbc.add_contact(contact)
    wbc.add_task(ComTask())
    result = wbc.update(g1.default_configuration(), np.zeros(35), 0.0)
    assert result.status is WbcStatus.QP_FAILED
    assert result.qp_status in (QpStatus.PRIMAL_INFEASIBLE, QpStatus.MAX_ITER, QpStatus.FAILED, QpStatus.DUAL_INFEASIBLE)
    assert np.all(result.tau == 0.0) and np.all(np.isnan(result.qdd))  # no previous torque: zero on a floating base
    assert wbc.failures == 1 and result.message


def test_a_failed_qp_tick_keeps_its_time_and_blames_no_missing_regularisation(g1, g1_model):
    """The infeasible stance above, regularised as by default: the failed tick reports the time it
    was asked for, and its message does not blame a missing force regularisation."""
    wbc = WholeBodyController(g1_model, torque_limits=np.full(29, 1e-3), solver_settings={"max_iter": 200})
    weight = g1.total_mass * 9.81
    for contact in foot_contacts(g1, min_normal_force=2 * weight, max_normal_force=3 * weight):
        wbc.add_contact(contact)
    wbc.add_task(ComTask())
    assert wbc.force_regularization is not None and wbc.force_regularization.weight > 0
    result = wbc.update(g1.default_configuration(), np.zeros(35), 0.5)
    assert result.status is WbcStatus.QP_FAILED and result.t == 0.5
    assert result.message and "regularisation" not in result.message


def test_bad_settings_are_refused_with_their_names(g1_model):
    for bad in (np.inf, np.nan, -1.0):
        with pytest.raises(ValueError, match=r"^acceleration_regularization must be finite and >= 0$"):
            WholeBodyController(g1_model, acceleration_regularization=bad)
    with pytest.raises(ValueError, match=r"^joint_limit_horizon must be > 0$"):
        WholeBodyController(g1_model, joint_limit_horizon=0.0)
    with pytest.raises(ValueError, match=r"^torque_limits must have 29 entries, got shape \(28,\)$"):
        WholeBodyController(g1_model, torque_limits=np.ones(28))


def test_states_in_other_dtypes_give_the_same_answer(g1, g1_model, rng):
    """A state given as float32 arrays (as a sensor driver may deliver it) or as integer
    velocities is read as float64: the same answer as the float64 state it rounds to."""
    q, v = random_state(g1, g1_model, rng)
    q32, v32 = q.astype(np.float32), v.astype(np.float32)
    a = g1_controller(g1, g1_model, "proxsuite").update(q32, v32, 0.0)
    b = g1_controller(g1, g1_model, "proxsuite").update(q32.astype(float), v32.astype(float), 0.0)
    assert a.ok and b.ok
    np.testing.assert_array_equal(a.tau, b.tau)
    still = np.zeros(g1_model.nv, dtype=int)
    c = g1_controller(g1, g1_model, "proxsuite").update(g1.default_configuration(), still, 0.0)
    d = g1_controller(g1, g1_model, "proxsuite").update(g1.default_configuration(), np.zeros(g1_model.nv), 0.0)
    assert c.ok and d.ok
    np.testing.assert_array_equal(c.tau, d.tau)


def test_a_robot_with_some_joints_unlimited_stands_as_with_loose_limits(g1, g1_model):
    """Torque limits on the legs only (the waist and arms unlimited), standing on both feet: the
    same torques as with huge finite limits on every joint, the legs within their limits and the
    feet carrying the weight."""
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    limits = np.array(g1.effort_limits, dtype=float)
    partial, loose = limits.copy(), limits.copy()
    partial[12:], loose[12:] = np.inf, 1e6
    results = []
    for torque_limits in (partial, loose):
        wbc = WholeBodyController(g1_model, solver="proxsuite", solver_settings=ACCURATE["proxsuite"], torque_limits=torque_limits)
        for contact in foot_contacts(g1, mu=0.8):
            wbc.add_contact(contact)
        wbc.add_task(ComTask(weight=10.0, kp=100.0))
        wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
        result = wbc.update(q, v, 0.0)
        assert result.ok, result.message
        normals = sum(wbc.contact_wrench_world(c.name, result)[2] for c in wbc.contacts)
        assert normals == pytest.approx(g1.total_mass * 9.81, rel=1e-3)
        results.append(result)
    np.testing.assert_allclose(results[0].tau, results[1].tau, atol=1e-4)
    assert np.all(np.abs(results[0].tau[:12]) <= limits[:12] + 1e-6)


# --- the output for a Robot ------------------------------------------------------------------------
def test_impedance_command_reproduces_the_torque_at_the_measured_state(g1, g1_model, rng):
    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    wbc.impedance_kp = np.full(29, 5.0)
    q, v = random_state(g1, g1_model, rng)
    result = wbc.update(q, v)
    command = result.impedance
    command.validate(29)
    np.testing.assert_allclose(command.torque(q[7:], v[6:]), result.tau, atol=1e-12)
    np.testing.assert_allclose(command.kd, g1.kd * 0.1)
    # With a look-ahead h the references are the state integrated h ahead with q̈.
    wbc.impedance_lookahead = 0.01
    result = wbc.update(q, v)
    command = result.impedance
    np.testing.assert_allclose(command.q_ref, q[7:] + 0.01 * v[6:] + 0.5e-4 * result.qdd[6:])
    np.testing.assert_allclose(command.v_ref, v[6:] + 0.01 * result.qdd[6:])


def test_balance_controller_factory(g1):
    controller = make_balance_controller(g1, solver="osqp", com_kp=80.0)
    assert controller.config.solver == "osqp" and controller.com_task.kp[0] == 80.0
    q = g1.default_configuration()
    result = controller.update(q, np.zeros(35), 0.0)
    assert result.ok
    np.testing.assert_allclose(controller.nominal_com, controller.wbc.kin.com)
    controller.set_com_offset([0.0, 0.02, 0.0])
    np.testing.assert_allclose(controller.com_task.position_ref, controller.nominal_com + [0.0, 0.02, 0.0])
    with pytest.raises(TypeError):
        make_balance_controller(g1, no_such_option=1.0)
    corners = make_balance_controller(g1, contact_model="corners")
    assert all(isinstance(c, CornerContact) for c in corners.contacts)
    assert corners.update(q, np.zeros(35), 0.0).ok


def test_joint_limit_bounds_stop_a_joint_at_its_limit(g1, g1_model):
    wbc = WholeBodyController(g1_model, torque_limits=g1.effort_limits, joint_limits=True, joint_limit_horizon=0.05)
    wbc.add_task(PostureTask(reference=g1.default_positions))
    q, v = g1.default_configuration(), np.zeros(35)
    lower, upper = g1.position_limits
    knee = 3
    q[7 + knee] = upper[knee] - 0.01
    v[6 + knee] = 1.0  # heading into the limit
    problem = wbc.build(q, v, 0.0)
    bound = problem.ub[6 + knee]
    assert bound == pytest.approx(2.0 * (0.01 - 0.05) / 0.05**2)
    assert problem.lb[6 + knee] <= bound
    assert np.all(problem.lb <= problem.ub)
    assert np.all(np.isinf(problem.lb[:6])) and np.all(np.isinf(problem.lb[35:]))


def test_joint_limit_margin_stops_a_joint_that_far_inside_its_limit(g1, g1_model):
    """With ``joint_limit_margin`` the bounds stop a joint at its limit moved inward (a safety
    layer's soft limit): the same knee 0.01 rad from its limit is already 0.02 rad beyond the
    margin's limit, so its bound brakes harder, by exactly the margin's share."""
    q, v = g1.default_configuration(), np.zeros(35)
    lower, upper = g1.position_limits
    knee = 3
    q[7 + knee] = upper[knee] - 0.01
    v[6 + knee] = 1.0
    bounds = []
    for margin in (0.0, 0.03):
        wbc = WholeBodyController(g1_model, torque_limits=g1.effort_limits, joint_limits=True, joint_limit_horizon=0.05, joint_limit_margin=margin)
        wbc.add_task(PostureTask(reference=g1.default_positions))
        problem = wbc.build(q, v, 0.0)
        bounds.append(problem.ub[6 + knee])
        assert np.all(problem.lb <= problem.ub)
    assert bounds[0] == pytest.approx(2.0 * (0.01 - 0.05) / 0.05**2)
    assert bounds[1] == pytest.approx(2.0 * (0.01 - 0.03 - 0.05) / 0.05**2)
    with pytest.raises(ValueError, match="joint_limit_margin"):
        WholeBodyController(g1_model, joint_limits=True, joint_limit_margin=-0.01)


# --- the active-set guess in front of proxsuite ----------------------------------------------------
def test_active_set_guess_returns_the_qp_optimum(g1, g1_model, rng):
    """Along a smooth trajectory of states the guess (one KKT solve) answers most ticks, and every
    answer equals proxsuite's own optimum."""
    from giwbc.control import ProxsuiteSolver

    wbc = g1_controller(g1, g1_model, "proxsuite", accurate=False)
    reference = ProxsuiteSolver(eps_abs=1e-9, max_iter=1000, max_iter_in=1500, active_set_guess=False, polish=False)
    q0, v0 = random_state(g1, g1_model, rng, scale=0.05, speed=0.2)
    direction = rng.uniform(-1, 1, g1_model.nv)
    compared = 0
    for i in range(60):
        q = pin.integrate(g1_model, q0, 0.02 * np.sin(0.05 * i) * direction)
        problem = wbc.build(q, v0, i * 0.002)
        solution = wbc.solve()
        assert solution.ok
        if solution.message == "active-set guess":
            expected = reference.solve(problem.copy())
            # proxsuite stops at residuals of 1e-9: the weakly regularised (1e-5) tangential
            # forces are only determined to ~1e-4 by it; the exact answer is at least as good.
            np.testing.assert_allclose(solution.x[:35], expected.x[:35], rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(solution.x[35:], expected.x[35:], rtol=1e-5, atol=1e-4)
            assert problem.violation(solution.x) < 1e-7
            assert problem.objective(solution.x) <= problem.objective(expected.x) + 1e-7  # (it may violate by 1e-9)
            compared += 1
    guess = wbc.solver.guess
    assert guess.hits == compared and compared > 40, (guess.hits, guess.tries)


def test_active_set_guess_handles_active_constraints(g1, g1_model):
    """A lateral CoM offset saturates the feet's centres of pressure (the regularisation keeps the
    weight split): active rows in the guess, and its answers are still the QP optimum."""
    from giwbc.control import ProxsuiteSolver

    controller = make_balance_controller(g1)
    wbc = controller.wbc
    reference = ProxsuiteSolver(eps_abs=1e-9, max_iter=1000, max_iter_in=1500, active_set_guess=False, polish=False)
    q, v = g1.default_configuration(), np.zeros(g1_model.nv)
    controller.update(q, v, 0.0)
    hits = 0
    for i in range(1, 8):
        controller.set_com_offset([0.0, 0.002 * i, 0.0])
        problem = wbc.build(q, v, i * 0.002)
        solution = wbc.solve()
        assert solution.ok
        if solution.message == "active-set guess":
            hits += 1
            np.testing.assert_allclose(solution.x, reference.solve(problem.copy()).x, rtol=1e-5, atol=1e-5)
    guess = wbc.solver.guess
    assert len(guess.active) > 0 and hits >= 4, (guess.active, hits)
    # Variable bounds (joint limits) are identity rows after those of C: a knee driven into its
    # limit makes its bound active, and the guess still answers with the optimum.
    knee = 3
    target = g1.default_positions.copy()
    target[knee] = g1.position_limits[1][knee] + 0.5  # beyond the limit: the posture pulls into it
    limited = WholeBodyController(g1_model, joint_limits=True)
    limited.add_task(PostureTask(reference=target, kp=50.0))
    q[7 + knee] = g1.position_limits[1][knee] - 0.01
    v[6 + knee] = 1.0
    for i in range(3):
        result = limited.update(q, v, i * 0.002)
        assert result.ok
        expected = reference.solve(limited.problem.copy())
        np.testing.assert_allclose(np.concatenate([result.qdd, result.forces]), expected.x, rtol=1e-6, atol=1e-6)
    assert limited.solver.guess.hits == 2 and len(limited.solver.guess.active) > 0
    assert limited.problem.ub[6 + knee] == pytest.approx(result.qdd[6 + knee])


# --- QP backends on problems with a known answer -------------------------------------------------
def small_qp(structure: int = 1):
    """min ½‖x − (1, 2)‖²  s.t.  x0 + x1 = 1,  x0 − x1 ≤ 0.5,  −10 ≤ x ≤ 10: the answer is (0, 1)
    without the inequality binding (x0 − x1 = −1); the multiplier of the equality is 1."""
    from giwbc.control.qp import QpProblem

    return QpProblem(
        H=np.eye(2), g=-np.array([1.0, 2.0]), A=np.ones((1, 2)), b=np.ones(1), C=np.array([[1.0, -1.0]]),
        l=np.array([-np.inf]), u=np.array([0.5]), lb=np.full(2, -10.0), ub=np.full(2, 10.0), structure=structure,
    )  # fmt: skip


def larger_qp(structure: int = 2):
    """min ½‖x‖² − x2  s.t.  x0 + x1 + x2 = 2,  x0 ≥ 0.9: the answer is (0.9, 0.05, 1.05)."""
    from giwbc.control.qp import QpProblem

    return QpProblem(
        H=np.eye(3), g=np.array([0.0, 0.0, -1.0]), A=np.ones((1, 3)), b=np.array([2.0]), C=np.array([[1.0, 0.0, 0.0]]),
        l=np.array([0.9]), u=np.array([np.inf]), structure=structure,
    )  # fmt: skip


@pytest.mark.parametrize("solver", SOLVERS)
def test_backends_solve_known_problems_and_report_what_they_did(solver):
    import time

    backend = make_solver(solver, **ACCURATE[solver])
    for problem, expected in [(small_qp(), [0.0, 1.0]), (larger_qp(), [0.9, 0.05, 1.05]), (small_qp(), [0.0, 1.0])]:
        before = time.perf_counter()
        solution = backend.solve(problem)
        elapsed = time.perf_counter() - before
        assert solution.status is QpStatus.SOLVED and solution.ok
        np.testing.assert_allclose(solution.x, expected, atol=1e-5)
        assert solution.solver == backend.name == solver
        assert type(solution.iterations) is int and solution.iterations >= 0
        assert 0.0 <= solution.solve_time <= elapsed  # measured inside this call
        if solution.rows is not None:  # [A; C; bounds] x, computed on the way
            rows = np.concatenate([problem.A @ solution.x, problem.C @ solution.x])
            np.testing.assert_allclose(solution.rows[: len(rows)], rows, atol=1e-9)
            if len(solution.rows) > len(rows):
                np.testing.assert_allclose(solution.rows[len(rows) :], solution.x, atol=1e-9)
        assert solution.message in ("", "active-set guess")


@pytest.mark.parametrize("solver", SOLVERS)
def test_backends_report_an_infeasible_problem(solver):
    from giwbc.control.qp import QpProblem

    backend = make_solver(solver)
    infeasible = QpProblem(H=np.eye(1), g=np.zeros(1), A=np.ones((1, 1)), b=np.array([1.0]), C=np.ones((1, 1)),
                           l=np.array([2.0]), u=np.array([3.0]), structure=7)  # fmt: skip
    solution = backend.solve(infeasible)
    assert not solution.ok and solution.status is not QpStatus.SOLVED
    assert solution.x.shape == (1,) and np.all(np.isnan(solution.x))
    assert solution.solver == solver
    np.testing.assert_allclose(backend.solve(small_qp(structure=8)).x, [0.0, 1.0], atol=1e-5)  # and recovers


def test_qp_problem_violation_copy_and_validation():
    p = small_qp()
    assert p.violation(np.array([0.0, 1.0])) == 0.0
    assert p.violation(np.array([1.0, 1.0])) == pytest.approx(1.0)  # equality off by 1
    assert p.violation(np.array([1.5, -0.5])) == pytest.approx(1.5)  # x0 − x1 = 2 > 0.5
    assert p.violation(np.array([11.0, -10.0])) == pytest.approx(20.5)  # the inequality dominates the bound (1)
    q = larger_qp()
    assert q.violation(np.array([0.5, 0.5, 1.0])) == pytest.approx(0.4)  # x0 below its lower limit
    assert q.objective(np.array([0.9, 0.05, 1.05])) == pytest.approx(0.5 * (0.81 + 0.0025 + 1.1025) - 1.05)
    copy = p.copy()
    copy.H[0, 0] = 5.0
    copy.lb[0] = 0.0
    assert p.H[0, 0] == 1.0 and p.lb[0] == -10.0 and copy.structure == p.structure
    assert larger_qp().copy().lb is None
    p.validate()
    bad = small_qp()
    bad.g = np.zeros(3)
    with pytest.raises(ValueError, match=r"^QP g has shape \(3,\), expected \(2,\)$"):
        bad.validate()
    bad = small_qp()
    bad.A = np.full((1, 2), np.nan)
    with pytest.raises(ValueError, match=r"^QP A is not finite$"):
        bad.validate()
    bad = small_qp()
    bad.ub = None
    with pytest.raises(ValueError, match=r"^QP ub has shape None, expected \(2,\)$"):
        bad.validate()


def test_constructor_defaults_pass_through_and_clear_errors():
    """The internal clock advances by the default 2 ms per tick; the impedance gains default
    to zero and are passed through when given; ``fallback_decay`` accepts both ends of [0, 1];
    bad settings name themselves; a failed tick still reports its phase timings."""
    model = build_pinocchio_model(DoublePendulum())
    q, v = np.array([0.3, -0.2]), np.zeros(2)
    plain = WholeBodyController(model)
    first, second = plain.update(q, v), plain.update(q, v)
    assert first.ok and first.t == pytest.approx(0.002) and second.t == pytest.approx(0.004)
    command = first.impedance
    assert np.all(command.kp == 0.0) and np.all(command.kd == 0.0)
    given = WholeBodyController(model, impedance_kp=3.0, impedance_kd=np.array([0.5, 0.25])).update(q, v).impedance
    np.testing.assert_array_equal(given.kp, [3.0, 3.0])
    np.testing.assert_array_equal(given.kd, [0.5, 0.25])
    for decay in (0.0, 1.0):
        assert WholeBodyController(model, fallback_decay=decay).fallback_decay == decay
    with pytest.raises(ValueError, match=r"^torque limits must be >= 0$"):
        WholeBodyController(model, torque_limits=np.array([-1.0, 1.0]))
    with pytest.raises(ValueError, match=r"^fallback_kd must be finite and >= 0"):
        WholeBodyController(model, fallback_kd=-1.0)
    with pytest.raises(TypeError, match=r"^expected a WbcTask, got str$"):
        plain.add_task("posture")
    infeasible = WholeBodyController(model, torque_limits=np.array([1e-3, 1e-3]))
    infeasible.add_contact(SurfaceContact("tip", "tip", 0.01, 0.01, min_normal_force=1000.0, max_normal_force=2000.0))
    failed = infeasible.update(q, v)
    assert not failed.ok and failed.timings.solve > 0.0 and failed.timings.build > 0.0 and failed.timings.pinocchio > 0.0
