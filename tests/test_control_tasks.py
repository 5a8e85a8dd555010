"""The task classes' contracts: the weight split of the contact-force regularisation (the lever
rule), the messages that refuse bad settings, and what a task reports about itself."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control.contact_set import Lever
from giwbc.control import (
    AngularMomentumTask,
    ComTask,
    ContactForceRegularization,
    FrameOrientationTask,
    FramePoseTask,
    FramePositionTask,
    Kinodynamics,
    PostureTask,
    WbcTask,
)
from giwbc.control.tasks import critical_damping


def test_the_lever_rule_and_the_support_point() -> None:
    """Two feet 0.2 m apart along y: a support point a quarter of the way from the second foot
    gives it 3/4 of the weight (its projection on the line counts, clamped to the segment); two
    coincident points define no split. The regularisation keeps the support point's xy and counts
    its changes (the activation-weighted shares on a robot: tests/test_contact_set.py)."""
    lever = Lever.between((0.0, 0.1), (0.0, -0.1))
    assert lever is not None
    assert lever.share(0.3, -0.05) == pytest.approx(0.25)  # off the line: only its projection matters
    assert lever.share(0.0, 0.0) == pytest.approx(0.5)
    assert lever.share(0.0, 0.5) == 1.0 and lever.share(0.0, -0.5) == 0.0  # beyond a foot: clamped
    turned = Lever.between((0.1, 0.1), (-0.1, -0.1))
    assert turned is not None and turned.share(0.05, 0.05) == pytest.approx(0.75)
    assert Lever.between((0.2, 0.1), (0.2, 0.1)) is None
    reg = ContactForceRegularization()
    reg.set_support_point([0.3, -0.05, 0.8])
    assert reg.support_xy == (0.3, -0.05)
    version = reg.version
    reg.set_support_point(None)
    assert reg.support_point is None and reg.support_xy is None and reg.version == version + 1


def test_force_regularisation_settings_and_report() -> None:
    reg = ContactForceRegularization("feet", weight=2e-4)
    assert repr(reg) == "ContactForceRegularization('feet', weight=0.0002)"
    assert reg.reference == "weight" and ContactForceRegularization(reference="zero").reference == "zero"
    with pytest.raises(ValueError, match=r"^reference must be 'weight' or 'zero', got 'half'$"):
        ContactForceRegularization(reference="half")
    with pytest.raises(ValueError, match=r"^force regularisation weight must be finite and >= 0, got -1.0$"):
        reg.set_weight(-1.0)
    with pytest.raises(ValueError, match=r"must be finite and >= 0, got inf$"):
        reg.set_weight(np.inf)
    version = reg.version
    reg.set_weight(0.0)
    assert reg.weight == 0.0 and reg.version == version + 1
    with pytest.raises(ValueError, match=r"^support point must have 3 entries, got shape \(2,\)$"):
        reg.set_support_point([0.0, 1.0])


def test_bad_task_settings_are_refused_with_the_setting_named() -> None:
    with pytest.raises(ValueError, match=r"^task 'com' weight must be finite and >= 0, got -1.0$"):
        ComTask(weight=-1.0)
    with pytest.raises(ValueError, match=r"^task 'com' kp must be finite and >= 0, got nan$"):
        ComTask(kp=np.nan)
    with pytest.raises(ValueError, match=r"^task 'com' kd must be finite and >= 0, got \[1.0, -2.0, 1.0\]$"):
        ComTask(kd=[1.0, -2.0, 1.0])
    with pytest.raises(ValueError, match=r"^CoM position reference must have 3 entries, got shape \(2,\)$"):
        ComTask().set_reference([0.0, 1.0])
    with pytest.raises(ValueError, match=r"^CoM position reference must be finite, got \[ 0. inf  1.\]$"):
        ComTask().set_reference([0.0, np.inf, 1.0])
    column = ComTask()
    column.set_reference(np.array([[0.1], [0.2], [0.3]]))  # a column of 3 is accepted, flattened
    np.testing.assert_array_equal(column.position_ref, [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match=r"^velocity reference must have 3 entries, got shape \(4,\)$"):
        ComTask().set_reference([0.0, 0.0, 1.0], velocity=np.zeros(4))
    with pytest.raises(ValueError, match=r"^acceleration reference must have 3 entries, got shape \(1,\)$"):
        ComTask().set_reference([0.0, 0.0, 1.0], acceleration=np.zeros(1))
    with pytest.raises(ValueError, match=r"^give the posture task its dimension or a reference$"):
        PostureTask()
    with pytest.raises(ValueError, match=r"^posture reference must have 4 entries, got shape \(3,\)$"):
        PostureTask(dim=4).set_reference(np.zeros(3))
    with pytest.raises(ValueError, match=r"^a frame task needs at least one selected row$"):
        FramePoseTask("pelvis", mask=[0] * 6)
    with pytest.raises(TypeError, match=r"^the reference of a frame task is a pinocchio.SE3$"):
        FrameOrientationTask("pelvis").set_reference(np.eye(4))
    with pytest.raises(ValueError, match=r"^frame velocity reference must have 6 entries"):
        FramePositionTask("pelvis").set_reference(pin.SE3.Identity(), velocity=np.zeros(3))


def test_a_posture_task_of_the_wrong_size_is_refused_when_bound(g1) -> None:
    kin = Kinodynamics(g1.build_pinocchio())
    with pytest.raises(ValueError, match=r"^posture task 'posture' has 28 rows, the model has 29 joints$"):
        PostureTask(dim=28).bind(kin)


def test_tasks_report_their_name_size_and_damping() -> None:
    assert repr(ComTask()) == "ComTask('com', dim=3)"
    assert repr(FramePositionTask("pelvis")) == "FramePositionTask('pelvis_position', dim=3)"
    assert repr(FrameOrientationTask("torso_link", "torso")) == "FrameOrientationTask('torso', dim=3)"
    assert FramePoseTask("pelvis", mask=[1, 0, 1, 0, 0, 1]).dim == 3 and FramePoseTask("pelvis").name == "pelvis_pose"
    assert repr(AngularMomentumTask()) == "AngularMomentumTask('angular_momentum', dim=3)"
    np.testing.assert_allclose(critical_damping(np.array([4.0, 25.0])), [4.0, 10.0])
    task = PostureTask(reference=np.zeros(5), kp=np.array([1.0, 4.0, 9.0, 16.0, 25.0]))
    np.testing.assert_allclose(task.kd, [2.0, 4.0, 6.0, 8.0, 10.0])
    task.set_gains(4.0, 1.5)
    np.testing.assert_allclose(task.kp, 4.0)
    np.testing.assert_allclose(task.kd, 1.5)
    version = task.version
    task.set_gains(9.0)
    np.testing.assert_allclose(task.kd, 6.0)
    assert task.version == version + 1
    momentum = AngularMomentumTask(kd=3.0)
    np.testing.assert_allclose(momentum.kp, 0.0)
    np.testing.assert_allclose(momentum.kd, 3.0)
    momentum.set_reference(np.array([1.0, 2.0, 3.0]), rate=np.array([0.5, 0.0, 0.0]))
    np.testing.assert_allclose(momentum.velocity_ref, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(momentum.acceleration_ref, [0.5, 0.0, 0.0])


def test_a_task_that_defines_nothing_says_so(g1) -> None:
    class Nothing(WbcTask):
        pass

    task = Nothing("nothing", 2)
    kin = Kinodynamics(g1.build_pinocchio())
    task.bind(kin)
    kin.update(g1.default_configuration(), np.zeros(35))
    with pytest.raises(NotImplementedError, match=r"^Nothing implements neither compute_jacobian nor write$"):
        task.compute(kin)
    with pytest.raises(NotImplementedError, match=r"^Nothing implements neither compute_error nor write$"):
        task.compute_error(kin)
    np.testing.assert_array_equal(task.compute_drift(kin), np.zeros(2))
    with pytest.raises(NotImplementedError):
        task.constant_gram_matrix(35)


def test_a_posture_task_measures_joint_angles_and_holds_where_it_starts(g1, rng) -> None:
    """Without a reference the posture task holds the joint angles of its first evaluation; its
    rows select the joint accelerations; ẍ* = Kp (q_ref − q) + Kd (v_ref − v) + a_ref."""
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    task = PostureTask(dim=29, kp=4.0, kd=2.0)
    task.bind(kin)
    q = pin.integrate(model, g1.default_configuration(), rng.uniform(-0.2, 0.2, 35))
    v = rng.uniform(-1.0, 1.0, 35)
    kin.update(q, v)
    task.compute(kin)
    np.testing.assert_allclose(task.position_ref, q[7:])
    np.testing.assert_array_equal(task.jacobian, np.hstack([np.zeros((29, 6)), np.eye(29)]))
    np.testing.assert_array_equal(task.drift, 0.0)
    reference = q[7:] + 0.1
    task.set_reference(reference, velocity=np.full(29, 0.3), acceleration=np.full(29, -1.0))
    task.compute(kin)
    np.testing.assert_allclose(task.error, 0.1)
    np.testing.assert_allclose(task.desired_acceleration(), -1.0 + 4.0 * 0.1 + 2.0 * (0.3 - v[6:]))
    qdd = rng.normal(size=35)
    np.testing.assert_allclose(task.residual(qdd), qdd[6:] - task.desired_acceleration())


@pytest.mark.parametrize("mask", [[1, 1, 1, 1, 1, 1], [1, 0, 1, 1, 0, 0], [0, 1, 0, 0, 1, 1]], ids=["pose", "x-z-roll", "y-pitch-yaw"])
def test_a_frame_pose_task_error_is_the_position_and_rotation_to_its_reference(g1, rng, mask) -> None:
    """``[p_ref − p; log3(R_ref Rᵀ)]`` on the selected rows, from Pinocchio's placement of the
    frame; the velocity and acceleration references keep the selected rows of the 6D ones."""
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    task = FramePoseTask("torso_link", mask=mask)
    task.bind(kin)
    q = pin.integrate(model, g1.default_configuration(), rng.uniform(-0.3, 0.3, 35))
    kin.update(q, np.zeros(35))
    reference = pin.SE3(pin.rpy.rpyToMatrix(0.2, -0.1, 0.3), np.array([0.1, -0.2, 0.9]))
    velocity, acceleration = rng.normal(size=6), rng.normal(size=6)
    task.set_reference(reference, velocity=velocity, acceleration=acceleration)
    rows = np.flatnonzero(mask)
    np.testing.assert_array_equal(task.velocity_ref, velocity[rows])
    np.testing.assert_array_equal(task.acceleration_ref, acceleration[rows])
    task.compute(kin)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    placement = data.oMf[model.getFrameId("torso_link")]
    full = np.concatenate([reference.translation - placement.translation, pin.log3(reference.rotation @ placement.rotation.T)])
    np.testing.assert_allclose(task.error, full[rows], atol=1e-12)


def test_the_com_task_residual_is_the_com_acceleration_less_the_wish(g1, rng) -> None:
    """``residual(q̈)`` of a CoM task is the CoM acceleration that q̈ gives (Pinocchio's
    ``centerOfMass`` at acceleration level) less the PD wish ``kp (c_ref − c) − kd ċ``."""
    model = g1.build_pinocchio()
    data = model.createData()
    kin = Kinodynamics(model)
    task = ComTask(kp=50.0, kd=5.0)
    task.bind(kin)
    q = g1.default_configuration()
    q[7:] += rng.uniform(-0.2, 0.2, model.nv - 6)
    v, qdd = rng.uniform(-1.0, 1.0, model.nv), rng.uniform(-1.0, 1.0, model.nv)
    kin.update(q, v)
    target = np.array([0.1, -0.05, 0.6])
    task.set_reference(target)
    task.compute(kin)
    pin.centerOfMass(model, data, q, v, qdd)
    wish = 50.0 * (target - data.com[0]) - 5.0 * data.vcom[0]
    np.testing.assert_allclose(task.residual(qdd), data.acom[0] - wish, atol=1e-9)


def test_a_frame_task_refuses_rates_of_the_wrong_size_and_names_them() -> None:
    """Frame velocity and acceleration references are 6D whatever rows the task keeps."""
    task = FramePositionTask("pelvis")
    with pytest.raises(ValueError, match=r"^frame velocity reference must have 6 entries, got shape \(3,\)$"):
        task.set_reference(pin.SE3.Identity(), velocity=np.zeros(3))
    with pytest.raises(ValueError, match=r"^frame acceleration reference must have 6 entries, got shape \(2,\)$"):
        task.set_reference(pin.SE3.Identity(), acceleration=np.zeros(2))


def test_task_defaults_and_given_gains() -> None:
    """The documented defaults (weight 1; frame tasks kp 100, posture kp 0; critical damping) and
    gains given to every task class reach it."""
    for task in (FramePoseTask("pelvis"), FramePositionTask("pelvis"), FrameOrientationTask("pelvis"), ComTask()):
        np.testing.assert_array_equal(task.weight, 1.0)
        np.testing.assert_array_equal(task.kp, 100.0)
        np.testing.assert_array_equal(task.kd, 20.0)
    posture = PostureTask(dim=3)
    np.testing.assert_array_equal(posture.weight, 1.0)
    np.testing.assert_array_equal(posture.kp, 0.0)
    for task in (FramePoseTask("pelvis", weight=2.0, kp=9.0, kd=1.5), FramePositionTask("pelvis", weight=2.0, kp=9.0, kd=1.5),
                 FrameOrientationTask("pelvis", weight=2.0, kp=9.0, kd=1.5), ComTask(weight=2.0, kp=9.0, kd=1.5),
                 PostureTask(dim=4, weight=2.0, kp=9.0, kd=1.5)):  # fmt: skip
        np.testing.assert_array_equal(task.weight, 2.0)
        np.testing.assert_array_equal(task.kp, 9.0)
        np.testing.assert_array_equal(task.kd, 1.5)
    regularization = ContactForceRegularization()
    assert (regularization.name, regularization.weight, regularization.reference) == ("contact_forces", 1e-5, "weight")
    assert regularization.support_point is None and regularization.support_xy is None
    momentum = AngularMomentumTask(weight=0.3)
    np.testing.assert_array_equal(momentum.weight, 0.3)
    np.testing.assert_array_equal(momentum.kd, 10.0)
    with pytest.raises(ValueError, match=r"^posture reference must be finite, got \[nan\]$"):
        PostureTask(reference=[np.nan])
    np.testing.assert_array_equal(PostureTask(reference=[0.5, 0.25]).position_ref, [0.5, 0.25])


def test_a_full_pose_task_measures_each_state_tick_after_tick(g1, rng) -> None:
    """The swing foot's full-pose path (from its second tick: no placement call of its own, the
    placement read where the Jacobian's Pinocchio call leaves it) measures every new state: its
    error and Jacobian equal a fresh task's at that state, tick after tick."""
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    task = FramePoseTask("left_ankle_roll_link")
    task.bind(kin)
    reference = pin.SE3(pin.rpy.rpyToMatrix(0.1, 0.2, -0.3), np.array([0.05, 0.1, 0.1]))
    task.set_reference(reference)
    rows, error, drift = np.zeros((6, 35)), np.zeros(6), np.zeros(6)
    for _ in range(4):
        q = pin.integrate(model, g1.default_configuration(), rng.uniform(-0.4, 0.4, 35))
        v = rng.normal(size=35)
        kin.update(q, v)
        task.write(kin, rows, error, drift)
        fresh_kin = Kinodynamics(model)
        fresh_kin.update(q, v)
        fresh = FramePoseTask("left_ankle_roll_link")
        fresh.bind(fresh_kin)
        fresh.set_reference(reference)
        fresh.compute(fresh_kin)
        np.testing.assert_array_equal(error, fresh.error)
        np.testing.assert_array_equal(rows, fresh.jacobian)
        np.testing.assert_array_equal(drift, fresh.drift)


def test_a_task_written_from_error_and_jacobian_sizes_its_rows_from_the_model_it_is_bound_to(g1, rng) -> None:
    """A user's task (pink-style: error and Jacobian only) gets the base class's defaults (weight 1,
    no gains) and knows the model's velocity size once bound (0 before): a knee-angle task."""

    class Knee(WbcTask):
        def __init__(self, joint: int) -> None:
            super().__init__("knee", 1)
            self.joint = joint

        def compute_error(self, kin):
            return np.array([0.6 - kin.q[7 + self.joint]])

        def compute_jacobian(self, kin):
            rows = np.zeros((1, self.nv))
            rows[0, 6 + self.joint] = 1.0
            return rows

    knee = Knee(g1.joint_names.index("left_knee_joint"))
    np.testing.assert_array_equal(knee.weight, 1.0)
    np.testing.assert_array_equal(knee.kp, 0.0)
    np.testing.assert_array_equal(knee.kd, 0.0)
    assert knee.nv == 0  # not bound: no model yet
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    knee.bind(kin)
    assert knee.nv == 35
    q = pin.integrate(model, g1.default_configuration(), rng.uniform(-0.2, 0.2, 35))
    v = rng.uniform(-1.0, 1.0, 35)
    kin.update(q, v)
    knee.compute(kin)
    assert knee.jacobian.shape == (1, 35) and knee.jacobian[0, 6 + knee.joint] == 1.0
    assert knee.error[0] == pytest.approx(0.6 - q[7 + knee.joint])
    assert knee.error_velocity[0] == pytest.approx(-v[6 + knee.joint])
