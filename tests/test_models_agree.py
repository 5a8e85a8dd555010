"""The Pinocchio and MuJoCo models built from one description agree: the WBC's trust rests on this."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from giwbc.robot import RobotDescription, load
from giwbc.robot.conventions import pinocchio_to_mujoco, velocity_map

RTOL, ATOL = 1e-9, 1e-9


class ModelPair:
    """Both models of one description, set to the same state."""

    def __init__(self, description: RobotDescription) -> None:
        self.description = description
        self.pin_model = description.build_pinocchio()
        self.pin_data = self.pin_model.createData()
        self.mj_model = description.build_mujoco()
        self.mj_data = mujoco.MjData(self.mj_model)

    def random_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        lower, upper = self.description.position_limits
        lower, upper = np.maximum(lower, -np.pi), np.minimum(upper, np.pi)
        joints = rng.uniform(lower, upper)
        if self.description.floating_base:
            quat = rng.normal(size=4)
            q = np.concatenate([rng.uniform(-1, 1, 3), quat / np.linalg.norm(quat), joints])
        else:
            q = joints
        return q, rng.normal(size=self.pin_model.nv)

    def set_state(self, q: np.ndarray, v: np.ndarray) -> None:
        if self.description.floating_base:
            qpos, qvel = pinocchio_to_mujoco(q, v)
        else:
            qpos, qvel = q, v
        self.mj_data.qpos[:], self.mj_data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.mj_model, self.mj_data)
        pin.computeAllTerms(self.pin_model, self.pin_data, q, v)
        pin.updateFramePlacements(self.pin_model, self.pin_data)

    def velocity_map(self, q: np.ndarray) -> np.ndarray:
        nv = self.pin_model.nv
        return velocity_map(q, nv) if self.description.floating_base else np.eye(nv)


@pytest.fixture(scope="module", params=["g1", "cartpole"])
def pair(request: pytest.FixtureRequest) -> ModelPair:
    return ModelPair(load(request.param))


def test_joint_order_and_dimensions(pair: ModelPair) -> None:
    d = pair.description
    first_pin = 2 if d.floating_base else 1
    first_mj = 1 if d.floating_base else 0
    assert tuple(pair.pin_model.names[first_pin:]) == d.joint_names
    mj_names = tuple(pair.mj_model.joint(i).name for i in range(first_mj, pair.mj_model.njnt))
    assert mj_names == d.joint_names
    assert pair.pin_model.nv == pair.mj_model.nv
    assert pair.mj_model.nu == int(d.actuated.sum())


def moving_bodies(model: mujoco.MjModel) -> np.ndarray:
    """Bodies not welded to the world: Pinocchio leaves a fixed base's root link out of its totals."""
    return np.flatnonzero(model.body_weldid != 0)


def test_total_mass(pair: ModelPair) -> None:
    pin_mass = pin.computeTotalMass(pair.pin_model)
    mj_mass = float(pair.mj_model.body_mass[moving_bodies(pair.mj_model)].sum())
    assert pin_mass == pytest.approx(mj_mass, rel=1e-12)
    assert float(pair.mj_model.body_mass.sum()) == pytest.approx(pair.description.total_mass, rel=1e-12)


def test_mass_matrix_bias_and_com_at_random_states(pair: ModelPair, rng: np.random.Generator) -> None:
    nv = pair.pin_model.nv
    mj_mass = np.zeros((nv, nv))
    for _ in range(10):
        q, v = pair.random_state(rng)
        pair.set_state(q, v)
        transform = pair.velocity_map(q)
        mujoco.mj_fullM(pair.mj_model, pair.mj_data, mj_mass)
        pin_mass = pair.pin_data.M.copy()
        pin_mass = np.triu(pin_mass) + np.triu(pin_mass, 1).T
        np.testing.assert_allclose(transform.T @ mj_mass @ transform, pin_mass, rtol=RTOL, atol=ATOL)

        # Pinocchio's free-flyer acceleration is spatial: MuJoCo's classical linear acceleration
        # adds R (w x v_local), which moves into the bias.
        extra = np.zeros(nv)
        if pair.description.floating_base:
            extra[:3] = transform[:3, :3] @ np.cross(v[3:6], v[:3])
        mj_bias = transform.T @ (pair.mj_data.qfrc_bias + mj_mass @ extra)
        np.testing.assert_allclose(mj_bias, pair.pin_data.nle, rtol=RTOL, atol=1e-8)

        bodies = moving_bodies(pair.mj_model)
        masses = pair.mj_model.body_mass[bodies]
        mj_com = masses @ pair.mj_data.xipos[bodies] / masses.sum()
        np.testing.assert_allclose(mj_com, pair.pin_data.com[0], rtol=RTOL, atol=ATOL)


def test_link_placements_and_jacobians(pair: ModelPair, rng: np.random.Generator) -> None:
    d = pair.description
    links = [c.link for c in d.contacts] + ([d.imu_frame] if d.imu_frame else []) + ["pole" if d.name == "cartpole" else d.base_link]
    nv = pair.pin_model.nv
    jac_pos, jac_rot = np.zeros((3, nv)), np.zeros((3, nv))
    for _ in range(5):
        q, v = pair.random_state(rng)
        pair.set_state(q, v)
        transform = pair.velocity_map(q)
        pin.computeJointJacobians(pair.pin_model, pair.pin_data, q)
        for link in links:
            body = pair.mj_model.body(link).id
            frame = pair.pin_model.getFrameId(link)
            placement = pair.pin_data.oMf[frame]
            np.testing.assert_allclose(pair.mj_data.xpos[body], placement.translation, rtol=RTOL, atol=ATOL)
            np.testing.assert_allclose(pair.mj_data.xmat[body].reshape(3, 3), placement.rotation, rtol=RTOL, atol=ATOL)
            mujoco.mj_jacBody(pair.mj_model, pair.mj_data, jac_pos, jac_rot, body)
            jacobian = pin.getFrameJacobian(pair.pin_model, pair.pin_data, frame, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(jac_pos @ transform, jacobian[:3], rtol=RTOL, atol=ATOL)
            np.testing.assert_allclose(jac_rot @ transform, jacobian[3:], rtol=RTOL, atol=ATOL)


def test_foot_soles_touch_the_floor_at_the_default_pose(g1: RobotDescription) -> None:
    model = g1.build_pinocchio()
    data = model.createData()
    pin.framesForwardKinematics(model, data, g1.default_configuration())
    for contact in g1.contacts:
        placement = data.oMf[model.getFrameId(contact.link)]
        heights = [placement.act(corner)[2] for corner in contact.corners]
        np.testing.assert_allclose(heights, 0.0, atol=2e-3)  # feet flat within 2 mm
        assert min(heights) == pytest.approx(0.0, abs=1e-12)
