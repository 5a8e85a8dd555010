"""Closed-form models in ``giwbc.testing`` against Pinocchio, against physics, and the checks' own failures."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from giwbc.testing.analytic import (
    AnalyticModel,
    CartPole,
    DoublePendulum,
    PlanarFloatingArm,
    PlanarFloatingBody,
    SimplePendulum,
)
from giwbc.testing.checks import (
    PinocchioDynamics,
    assert_computed_torque,
    assert_dynamics_match,
    assert_energy_conserved,
    assert_lagrangian_consistency,
    assert_mass_matrix_spd,
    assert_skew_symmetry,
    random_states,
)
from giwbc.testing.pinocchio_models import build_pinocchio_model

CARTPOLE_URDF = Path(__file__).resolve().parents[1] / "robots" / "cartpole" / "cartpole.urdf"

# Deliberately unequal, non-round parameters (and CoM offsets) so no term can hide behind a symmetry.
MODELS: dict[str, AnalyticModel] = {
    "pendulum": SimplePendulum(mass=1.3, com_distance=0.7, inertia=0.04),
    "point_pendulum": SimplePendulum.point_mass(mass=0.9, length=1.1),
    "double_pendulum": DoublePendulum(
        mass1=1.2, length1=0.9, com1=0.35, inertia1=0.05, mass2=0.7, length2=0.6, com2=0.27, inertia2=0.02
    ),
    "cartpole": CartPole(cart_mass=1.4, pole_mass=0.3, pole_com=0.4, pole_inertia=0.011, pivot_height=0.2),
    "floating_body": PlanarFloatingBody(mass=2.5, inertia=0.07, com_x=0.06, com_z=-0.04),
    "floating_arm": PlanarFloatingArm(
        base_mass=3.1, base_inertia=0.08, base_com_x=0.03, base_com_z=0.05,
        joint_x=0.07, joint_z=-0.12, link_mass=0.9, link_com=0.22, link_inertia=0.013, link_length=0.45,
    ),
}
MODEL_IDS = list(MODELS)

# Parameter samplers for randomized twin checks (every draw from the test's seeded Generator).
SAMPLERS: dict[str, Callable[[np.random.Generator], AnalyticModel]] = {
    "pendulum": lambda r: SimplePendulum(mass=r.uniform(0.2, 3), com_distance=r.uniform(-1, 1), inertia=r.uniform(0, 0.2)),
    "double_pendulum": lambda r: DoublePendulum(
        *(r.uniform(0.2, 2), r.uniform(0.2, 1.5), r.uniform(-0.5, 1), r.uniform(0, 0.1)),
        *(r.uniform(0.2, 2), r.uniform(0.2, 1.5), r.uniform(-0.5, 1), r.uniform(0.001, 0.1)),
        gravity_acc=r.uniform(1, 20),
    ),
    "cartpole": lambda r: CartPole(r.uniform(0.2, 3), r.uniform(0.05, 1), r.uniform(-0.5, 0.8), r.uniform(0, 0.05), r.uniform(1, 20), r.uniform(-1, 1), r.uniform(-0.1, 0.1)),
    "floating_body": lambda r: PlanarFloatingBody(r.uniform(0.5, 5), r.uniform(0.01, 0.2), r.uniform(-0.2, 0.2), r.uniform(-0.2, 0.2)),
    "floating_arm": lambda r: PlanarFloatingArm(
        *(r.uniform(0.5, 5), r.uniform(0.01, 0.2), *r.uniform(-0.2, 0.2, 4)),
        *(r.uniform(0.1, 2), r.uniform(-0.1, 0.5), r.uniform(0, 0.05), r.uniform(0.1, 0.6)),
    ),
}


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


def twin(model: AnalyticModel) -> PinocchioDynamics:
    return PinocchioDynamics(build_pinocchio_model(model))


# -- (a) analytic vs Pinocchio twin ------------------------------------------------------------
@pytest.mark.parametrize("name", MODEL_IDS)
def test_matches_pinocchio_twin(name: str, rng: np.random.Generator) -> None:
    """M, C q̇, g, rnea, aba and total energy agree with a Pinocchio model of the same parameters."""
    model = MODELS[name]
    assert_dynamics_match(model, twin(model), rng, n_states=20, rtol=1e-10, atol=1e-10, check_energy=True)


@pytest.mark.parametrize("name", list(SAMPLERS))
def test_random_parameters_match_pinocchio_twin(name: str, rng: np.random.Generator) -> None:
    for _ in range(4):
        model = SAMPLERS[name](rng)
        assert_dynamics_match(model, twin(model), rng, n_states=5, rtol=1e-9, atol=1e-9, check_energy=True)


def test_floating_arm_tip_jacobian_matches_pinocchio_frame(rng: np.random.Generator) -> None:
    model = MODELS["floating_arm"]
    pin_model = build_pinocchio_model(model)
    data = pin_model.createData()
    tip = pin_model.getFrameId("tip")
    for q in random_states(model, rng, 10).q:
        pin.computeJointJacobians(pin_model, data, q)
        pin.updateFramePlacements(pin_model, data)
        jac = pin.getFrameJacobian(pin_model, data, tip, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(model.tip_jacobian(q), jac[[0, 2]], atol=1e-12)
        np.testing.assert_allclose(model.tip_position(q), data.oMf[tip].translation[[0, 2]], atol=1e-12)


def test_double_pendulum_tip_matches_pinocchio_frame(rng: np.random.Generator) -> None:
    model = MODELS["double_pendulum"]
    pin_model = build_pinocchio_model(model)
    data = pin_model.createData()
    for q in random_states(model, rng, 10).q:
        pin.framesForwardKinematics(pin_model, data, q)
        np.testing.assert_allclose(model.tip_position(q), data.oMf[pin_model.getFrameId("tip")].translation[[0, 2]], atol=1e-12)


# -- (b) physics of the hand derivations, no Pinocchio -----------------------------------------
@pytest.mark.parametrize("name", MODEL_IDS)
def test_mass_matrix_symmetric_positive_definite(name: str, rng: np.random.Generator) -> None:
    assert_mass_matrix_spd(MODELS[name], rng, n_states=50)


@pytest.mark.parametrize("name", MODEL_IDS)
def test_coriolis_and_gravity_follow_from_lagrangian(name: str, rng: np.random.Generator) -> None:
    """C q̇ = Ṁ q̇ − ½ ∂(q̇ᵀMq̇)/∂q and g = ∂V/∂q, by finite differences of M and V alone."""
    assert_lagrangian_consistency(MODELS[name], rng, n_states=10)


@pytest.mark.parametrize("name", MODEL_IDS)
def test_mdot_minus_2c_skew_symmetric(name: str, rng: np.random.Generator) -> None:
    assert_skew_symmetry(MODELS[name], rng, n_states=10)


@pytest.mark.parametrize("name", MODEL_IDS)
def test_unforced_simulation_conserves_energy(name: str, rng: np.random.Generator) -> None:
    model = MODELS[name]
    state = random_states(model, rng, 1, q_scale=1.5, qd_scale=1.5)
    drift = assert_energy_conserved(model, state.q[0], state.qd[0], duration=2.0, dt=1e-3, rtol=1e-6)
    assert drift < 1e-6


@pytest.mark.parametrize("name", MODEL_IDS)
def test_forward_inverts_inverse_dynamics(name: str, rng: np.random.Generator) -> None:
    model = MODELS[name]
    for q, qd, qdd in zip(*random_states(model, rng, 10)):
        tau = model.inverse_dynamics(q, qd, qdd)
        np.testing.assert_allclose(model.forward_dynamics(q, qd, tau), qdd, rtol=1e-10, atol=1e-10)


def test_floating_arm_tip_jacobian_is_derivative_of_tip_position(rng: np.random.Generator) -> None:
    model, h = MODELS["floating_arm"], 1e-6
    for q in random_states(model, rng, 5).q:
        numeric = np.column_stack([(model.tip_position(q + h * e) - model.tip_position(q - h * e)) / (2 * h) for e in np.eye(4)])
        np.testing.assert_allclose(model.tip_jacobian(q), numeric, atol=1e-8)


def test_floating_arm_reduces_to_double_pendulum_with_base_pinned(rng: np.random.Generator) -> None:
    """With (x, z) frozen, the θ–φ block of the floating arm is a double pendulum hung at the origin."""
    dp = MODELS["double_pendulum"]
    arm = PlanarFloatingArm(
        base_mass=dp.mass1, base_inertia=dp.inertia1, base_com_x=0.0, base_com_z=-dp.com1,
        joint_x=0.0, joint_z=-dp.length1, link_mass=dp.mass2, link_com=dp.com2, link_inertia=dp.inertia2,
        gravity_acc=dp.gravity_acc,
    )
    for q2, qd2, _ in zip(*random_states(dp, rng, 10)):
        q = np.array([0.0, 0.0, *q2])
        qd = np.array([0.0, 0.0, *qd2])
        np.testing.assert_allclose(arm.mass_matrix(q)[2:, 2:], dp.mass_matrix(q2), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(arm.coriolis(q, qd)[2:], dp.coriolis(q2, qd2), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(arm.gravity(q)[2:], dp.gravity(q2), rtol=1e-12, atol=1e-14)


def test_planar_floating_body_with_com_at_origin_is_decoupled() -> None:
    body = PlanarFloatingBody(mass=2.0, inertia=0.3)
    q, qd = np.array([0.4, -1.0, 2.2]), np.array([0.3, 0.1, -4.0])
    np.testing.assert_allclose(body.mass_matrix(q), np.diag([2.0, 2.0, 0.3]))
    np.testing.assert_allclose(body.coriolis(q, qd), np.zeros(3))
    np.testing.assert_allclose(body.gravity(q), [0.0, 2.0 * body.gravity_acc, 0.0])
    np.testing.assert_allclose(body.forward_dynamics(q, qd, np.zeros(3)), [0.0, -body.gravity_acc, 0.0])


# -- (c) the project's cart-pole URDF ------------------------------------------------------------
@pytest.fixture(scope="module")
def urdf_cartpole() -> PinocchioDynamics:
    return PinocchioDynamics(pin.buildModelFromUrdf(str(CARTPOLE_URDF)))


def test_cartpole_urdf_matches_analytic(urdf_cartpole: PinocchioDynamics, rng: np.random.Generator) -> None:
    assert [urdf_cartpole.model.names[i] for i in (1, 2)] == ["linear", "pivot"]
    analytic = CartPole.from_urdf_parameters()
    assert_dynamics_match(analytic, urdf_cartpole, rng, n_states=30, rtol=1e-10, atol=1e-10, check_energy=True)
    for q, qd, _ in zip(*random_states(analytic, rng, 10)):
        tau = rng.uniform(-10.0, 10.0, 2)
        np.testing.assert_allclose(analytic.forward_dynamics(q, qd, tau), pin.aba(urdf_cartpole.model, urdf_cartpole.data, q, qd, tau), rtol=1e-10, atol=1e-10)


def test_cartpole_urdf_parameters_are_the_files(urdf_cartpole: PinocchioDynamics) -> None:
    """The constants in ``CartPole.from_urdf_parameters`` are read off the URDF itself."""
    root = ET.parse(CARTPOLE_URDF).getroot()
    links = {link.get("name"): link.find("inertial") for link in root.iter("link")}
    params = CartPole.from_urdf_parameters()
    assert float(links["cart"].find("mass").get("value")) == params.cart_mass
    assert float(links["pole"].find("mass").get("value")) == params.pole_mass
    assert links["pole"].find("origin").get("xyz").split() == ["0", "0", str(params.pole_com)]
    assert float(links["pole"].find("inertia").get("iyy")) == params.pole_inertia
    joints = {j.get("name"): j for j in root.iter("joint")}
    assert joints["linear"].find("axis").get("xyz").split() == ["1", "0", "0"]
    assert joints["pivot"].find("axis").get("xyz").split() == ["0", "1", "0"]
    assert np.isclose(urdf_cartpole.model.gravity.linear[2], -params.gravity_acc)


def test_cartpole_sign_convention(urdf_cartpole: PinocchioDynamics) -> None:
    """θ > 0 tips the pole's top towards +x, and gravity then pushes it further over."""
    params = CartPole.from_urdf_parameters()
    model, data = urdf_cartpole.model, urdf_cartpole.data
    theta = 0.3
    q = np.array([0.0, theta])
    pin.forwardKinematics(model, data, q)
    pole_com_world = data.oMi[model.getJointId("pivot")].act(model.inertias[model.getJointId("pivot")].lever)
    np.testing.assert_allclose(pole_com_world[[0, 2]], params.pole_com_position(q), atol=1e-12)
    assert pole_com_world[0] > 0.0
    assert params.gravity(q)[1] < 0.0  # g sits on the left: it accelerates θ further positive
    assert params.forward_dynamics(q, np.zeros(2), np.zeros(2))[1] > 0.0
    # Accelerating the cart to +x makes the pole fall back (θ̈ < 0) at upright.
    qdd = params.forward_dynamics(np.zeros(2), np.zeros(2), np.array([5.0, 0.0]))
    assert qdd[0] > 0.0 and qdd[1] < 0.0


# -- (d) the checks themselves fail when they should -------------------------------------------
def _computed_torque(model: AnalyticModel, *, coriolis: bool = True, gravity: float = 1.0) -> Callable[..., np.ndarray]:
    def controller(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        tau = model.mass_matrix(q) @ qdd + gravity * model.gravity(q)
        return tau + model.coriolis(q, qd) if coriolis else tau

    return controller


@pytest.mark.parametrize("name", ["double_pendulum", "cartpole", "floating_arm"])
def test_computed_torque_accepts_correct_controller(name: str, rng: np.random.Generator) -> None:
    model = MODELS[name]
    pin_twin = twin(model)
    assert_computed_torque(pin_twin.inverse_dynamics, model, rng, rtol=1e-10, atol=1e-10)
    assert_computed_torque(_computed_torque(model), model, rng)


@pytest.mark.parametrize("name", ["double_pendulum", "cartpole", "floating_arm"])
def test_computed_torque_catches_missing_coriolis(name: str, rng: np.random.Generator) -> None:
    model = MODELS[name]
    with pytest.raises(AssertionError, match=r"(?s)worst entry.*q = .*omits the C\(q, qd\) qd term"):
        assert_computed_torque(_computed_torque(model, coriolis=False), model, rng)


def test_computed_torque_catches_gravity_sign_and_shape(rng: np.random.Generator) -> None:
    model = MODELS["floating_arm"]
    with pytest.raises(AssertionError, match="flips the sign of the g"):
        assert_computed_torque(_computed_torque(model, gravity=-1.0), model, rng)
    with pytest.raises(AssertionError, match="shape mismatch"):
        assert_computed_torque(lambda q, qd, qdd: model.inverse_dynamics(q, qd, qdd)[:3], model, rng)


def test_dynamics_match_catches_wrong_parameters(urdf_cartpole: PinocchioDynamics, rng: np.random.Generator) -> None:
    good = CartPole.from_urdf_parameters()
    heavier = CartPole(**{**good.__dict__, "pole_mass": 0.21})
    with pytest.raises(AssertionError, match=r"(?s)mass matrix.*worst entry.*q = "):
        assert_dynamics_match(heavier, urdf_cartpole, rng, n_states=5)
    flipped = CartPole(**{**good.__dict__, "pole_com": -good.pole_com})  # pole hanging instead of upright
    with pytest.raises(AssertionError, match=r"gravity g\(q\)"):
        assert_dynamics_match(flipped, urdf_cartpole, rng, n_states=5)
    with pytest.raises(AssertionError, match="dimension mismatch"):
        assert_dynamics_match(MODELS["pendulum"], urdf_cartpole, rng)


class _WrongCoriolis:
    """A double pendulum whose Coriolis vector has the sign of the centrifugal term flipped."""

    def __init__(self, base: DoublePendulum) -> None:
        self.base = base
        self.nq = self.nv = 2

    def __getattr__(self, name: str) -> object:
        return getattr(self.base, name)

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.base.coriolis(q, qd) * np.array([1.0, -1.0])

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.base.coriolis_matrix(q, qd) * np.array([[1.0], [-1.0]])


def test_physics_checks_catch_wrong_coriolis(rng: np.random.Generator) -> None:
    wrong = _WrongCoriolis(MODELS["double_pendulum"])
    with pytest.raises(AssertionError, match="Lagrange"):
        assert_lagrangian_consistency(wrong, rng)
    with pytest.raises(AssertionError, match="Ṁ − 2C"):
        assert_skew_symmetry(wrong, rng)


def test_random_states_are_reproducible_and_need_a_generator() -> None:
    model = MODELS["floating_arm"]
    a = random_states(model, np.random.default_rng(7), 4)
    b = random_states(model, np.random.default_rng(7), 4)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert a.q.shape == (4, 4) and a.qd.shape == (4, 4) and a.qdd.shape == (4, 4)
    with pytest.raises(TypeError, match="Generator"):
        random_states(model, 7, 4)  # type: ignore[arg-type]


def test_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="mass"):
        SimplePendulum(mass=0.0)
    with pytest.raises(ValueError, match="inertia"):
        DoublePendulum(inertia1=-1.0)
    with pytest.raises(ValueError, match="q must have 2"):
        CartPole().mass_matrix(np.zeros(3))
