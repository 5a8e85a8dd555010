"""Kinodynamics: one Pinocchio pass gives M, h, Jacobians, drifts and centroidal terms that agree
with Pinocchio's reference algorithms and with finite differences on the configuration manifold."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control.kinodynamics import LOCAL, LWA, Kinodynamics, unactuated_dofs
from giwbc.testing import CartPole, PlanarFloatingArm
from giwbc.testing.pinocchio_models import cart_pole_model, planar_floating_arm_model


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_pinocchio()


def random_state(model: pin.Model, description, rng: np.random.Generator, scale: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    q0 = description.default_configuration()
    q = pin.integrate(model, q0, rng.uniform(-scale, scale, model.nv))
    v = rng.uniform(-1.0, 1.0, model.nv)
    return q, v


def test_detects_the_floating_base(g1_model):
    kin = Kinodynamics(g1_model)
    assert (kin.n_base, kin.n_joints, kin.free_flyer) == (6, 29, True)
    assert kin.joint_q == slice(7, 36) and kin.joint_v == slice(6, 35)
    fixed = Kinodynamics(cart_pole_model(CartPole()))
    assert (fixed.n_base, fixed.n_joints, fixed.free_flyer) == (0, 2, False)
    planar = Kinodynamics(planar_floating_arm_model(PlanarFloatingArm()), n_base=3)
    assert (planar.n_base, planar.n_joints) == (3, 1)
    assert unactuated_dofs(g1_model) == 6


def test_rejects_bad_input(g1_model):
    kin = Kinodynamics(g1_model)
    with pytest.raises(ValueError, match="q has shape"):
        kin.update(np.zeros(35), np.zeros(35))
    with pytest.raises(ValueError, match="v has shape"):
        kin.update(pin.neutral(g1_model), np.zeros(36))
    with pytest.raises(ValueError, match="n_base"):
        Kinodynamics(g1_model, n_base=40)
    with pytest.raises(TypeError):
        Kinodynamics("g1")  # type: ignore[arg-type]
    assert not Kinodynamics.is_finite(np.array([0.0, np.nan]), np.zeros(2))
    assert Kinodynamics.is_finite(np.zeros(3), np.ones(2))


def test_matches_pinocchio_reference_algorithms(g1, g1_model, rng):
    kin = Kinodynamics(g1_model)
    data = g1_model.createData()
    for _ in range(5):
        q, v = random_state(g1_model, g1, rng)
        kin.update(q, v)
        mass = pin.crba(g1_model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        np.testing.assert_allclose(kin.mass_matrix, mass, atol=1e-10)
        np.testing.assert_allclose(kin.nonlinear_effects, pin.rnea(g1_model, data, q, v, np.zeros(35)), atol=1e-9)
        np.testing.assert_allclose(kin.generalized_gravity, pin.computeGeneralizedGravity(g1_model, data, q), atol=1e-10)
        pin.centerOfMass(g1_model, data, q, v, np.zeros(35))
        np.testing.assert_allclose(kin.com, data.com[0], atol=1e-12)
        np.testing.assert_allclose(kin.com_velocity, data.vcom[0], atol=1e-12)
        np.testing.assert_allclose(kin.com_drift, data.acom[0], atol=1e-10)
        np.testing.assert_allclose(kin.com_jacobian, pin.jacobianCenterOfMass(g1_model, data, q), atol=1e-12)
        pin.computeCentroidalMomentumTimeVariation(g1_model, data, q, v, np.zeros(35))
        np.testing.assert_allclose(kin.centroidal_momentum, data.hg.vector, atol=1e-10)
        np.testing.assert_allclose(kin.centroidal_drift, data.dhg.vector, atol=1e-9)
        np.testing.assert_allclose(kin.centroidal_map @ v, data.hg.vector, atol=1e-10)


def test_generic_centroidal_drift_on_a_fixed_base(rng):
    model = cart_pole_model(CartPole())
    kin = Kinodynamics(model)
    data = model.createData()
    q, v = rng.uniform(-1, 1, 2), rng.uniform(-1, 1, 2)
    kin.update(q, v)
    pin.computeCentroidalMomentumTimeVariation(model, data, q, v, np.zeros(2))
    np.testing.assert_allclose(kin.centroidal_drift, data.dhg.vector, atol=1e-12)


def _frame_pose(model, data, q, frame_id):
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[frame_id].copy()


@pytest.mark.parametrize("link", ["pelvis", "left_ankle_roll_link", "right_wrist_yaw_link", "torso_link"])
def test_frame_jacobian_and_drift_against_finite_differences(g1, g1_model, rng, link):
    """LWA Jacobian = d(position, rotation)/dq along pin.integrate; drift = d(J v)/dt − J a."""
    kin = Kinodynamics(g1_model)
    data = g1_model.createData()
    frame = kin.frame_id(link)
    q, v = random_state(g1_model, g1, rng)
    a = rng.uniform(-1, 1, g1_model.nv)
    kin.update(q, v)
    jacobian = kin.frame_jacobian(frame, LWA).copy()
    drift = kin.frame_drift(frame, LWA).copy()
    eps = 1e-6
    pose = _frame_pose(g1_model, data, q, frame)
    numeric = np.zeros((6, g1_model.nv))
    for i in range(g1_model.nv):
        dq = np.zeros(g1_model.nv)
        dq[i] = eps
        plus = _frame_pose(g1_model, data, pin.integrate(g1_model, q, dq), frame)
        minus = _frame_pose(g1_model, data, pin.integrate(g1_model, q, -dq), frame)
        numeric[:3, i] = (plus.translation - minus.translation) / (2 * eps)
        numeric[3:, i] = (pin.log3(plus.rotation @ pose.rotation.T) - pin.log3(minus.rotation @ pose.rotation.T)) / (2 * eps)
    np.testing.assert_allclose(jacobian, numeric, atol=1e-6)

    # d/dt (J v) along q(t) = q ⊕ v t, v(t) = v + a t equals J a + J̇ v (classical acceleration).
    h = 1e-6
    kin_plus = Kinodynamics(g1_model)
    kin_plus.update(pin.integrate(g1_model, q, v * h), v + a * h)
    kin_minus = Kinodynamics(g1_model)
    kin_minus.update(pin.integrate(g1_model, q, -v * h), v - a * h)
    twist_rate = (kin_plus.frame_jacobian(frame, LWA) @ kin_plus.v - kin_minus.frame_jacobian(frame, LWA) @ kin_minus.v) / (2 * h)
    np.testing.assert_allclose(jacobian @ a + drift, twist_rate, atol=2e-5)


def _sole_point_at_random_state(g1, g1_model, rng, contact_index, reference):
    """A sole's centre as a placement on its joint, at a random state with a random acceleration
    ``a``: the model, the frame, the placement, ``q, v, a``, and the point's Jacobian and drift in
    ``reference`` (copies)."""
    kin = Kinodynamics(g1_model)
    contact = g1.contacts[contact_index]
    frame = g1_model.frames[kin.frame_id(contact.link)]
    placement = frame.placement * pin.SE3(np.eye(3), np.asarray(contact.center))
    q, v = random_state(g1_model, g1, rng)
    a = rng.uniform(-1, 1, g1_model.nv)
    kin.update(q, v)
    jacobian = kin.point_jacobian(frame.parentJoint, placement, reference).copy()
    drift = kin.point_drift(frame.parentJoint, placement, reference).copy()
    return kin, frame, placement, q, v, a, jacobian, drift


def test_local_point_jacobian_and_drift(g1, g1_model, rng):
    """The contact-frame (LOCAL) Jacobian of a point given by its joint placement, and its drift."""
    kin, frame, placement, q, v, a, jacobian, drift = _sole_point_at_random_state(g1, g1_model, rng, 0, LOCAL)

    def local_twist(qq, vv):
        other = Kinodynamics(g1_model)
        other.update(qq, vv)
        return other.point_jacobian(frame.parentJoint, placement, LOCAL) @ vv, other.joint_placement(frame.parentJoint) * placement

    h = 1e-6
    (tw_p, pose_p), (tw_m, pose_m) = local_twist(pin.integrate(g1_model, q, v * h), v + a * h), local_twist(pin.integrate(g1_model, q, -v * h), v - a * h)
    # Classical acceleration in the (moving) local frame: d/dt of the world-frame velocity, rotated
    # back into the current frame; angular part likewise.
    world_rate = (pose_p.rotation @ tw_p[:3] - pose_m.rotation @ tw_m[:3]) / (2 * h)
    angular_rate = (pose_p.rotation @ tw_p[3:] - pose_m.rotation @ tw_m[3:]) / (2 * h)
    pose = kin.joint_placement(frame.parentJoint) * placement
    expected = np.concatenate([pose.rotation.T @ world_rate, pose.rotation.T @ angular_rate])
    np.testing.assert_allclose(jacobian @ a + drift, expected, atol=2e-5)


def test_world_aligned_point_jacobian_and_drift(g1, g1_model, rng):
    """With world-aligned axes, ``J a + J̇ v`` of a sole point is the time derivative of its world
    velocity (linear: the point's, angular: the foot's), by central finite differences along (v, a)."""
    kin, frame, placement, q, v, a, jacobian, drift = _sole_point_at_random_state(g1, g1_model, rng, 1, LWA)

    def world_twist(qq, vv):
        other = Kinodynamics(g1_model)
        other.update(qq, vv)
        local = other.point_jacobian(frame.parentJoint, placement, LOCAL) @ vv
        rotation = (other.joint_placement(frame.parentJoint) * placement).rotation
        return np.concatenate([rotation @ local[:3], rotation @ local[3:]])

    h = 1e-6
    expected = (world_twist(pin.integrate(g1_model, q, v * h), v + a * h) - world_twist(pin.integrate(g1_model, q, -v * h), v - a * h)) / (2 * h)
    np.testing.assert_allclose(jacobian @ a + drift, expected, atol=2e-5)
    assert np.max(np.abs(drift)) > 1e-2  # the drift matters at this state


def test_a_light_free_flyer_has_the_com_acceleration_of_pinocchio(rng):
    """A free-flying body of 0.4 kg with a 0.3 kg arm (0.7 kg in all, under 1 kg): the CoM
    acceleration at ``q̈ = 0`` from the base rows of ``h`` equals Pinocchio's ``centerOfMass``."""
    model = pin.Model()
    base = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(base, pin.Inertia(0.4, np.array([0.0, 0.0, 0.05]), np.diag([1e-3, 2e-3, 3e-3])), pin.SE3.Identity())
    arm = model.addJoint(base, pin.JointModelRY(), pin.SE3(np.eye(3), np.array([0.1, 0.0, 0.0])), "arm")
    model.appendBodyToJoint(arm, pin.Inertia(0.3, np.array([0.2, 0.0, 0.0]), np.diag([1e-4, 4e-3, 4e-3])), pin.SE3.Identity())
    kin = Kinodynamics(model)
    assert kin.free_flyer and kin.n_base == 6 and kin.mass == pytest.approx(0.7)
    data = model.createData()
    for _ in range(3):
        quaternion = rng.normal(size=4)
        q = np.concatenate([rng.uniform(-1.0, 1.0, 3), quaternion / np.linalg.norm(quaternion), rng.uniform(-1.0, 1.0, 1)])
        v = rng.uniform(-2.0, 2.0, model.nv)
        kin.update(q, v)
        pin.centerOfMass(model, data, q, v, np.zeros(model.nv))
        np.testing.assert_allclose(kin.com_drift, data.acom[0], atol=1e-10)
        out = np.zeros(3)
        kin.com_drift_into(out)
        np.testing.assert_allclose(out, data.acom[0], atol=1e-10)
