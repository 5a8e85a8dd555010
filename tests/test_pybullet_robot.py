"""PybulletRobot implements the Robot interface from the same description as MujocoRobot, with
physically consistent readings; where PyBullet differs from MuJoCo, the tests say by how much."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
pin = pytest.importorskip("pinocchio")

from giwbc.robot import ImpedanceCommand, MujocoRobot, RobotDescription  # noqa: E402
from giwbc.robot.interface import base_velocity_local, quat_to_matrix  # noqa: E402
from giwbc.robot.pybullet_robot import PybulletRobot  # noqa: E402
from giwbc.robot.standing import base_tilt_deg, pd_hold_command  # noqa: E402

GRAVITY = 9.81


@pytest.fixture(scope="module")
def g1_robot(g1: RobotDescription) -> PybulletRobot:
    robot = PybulletRobot(g1)
    yield robot
    robot.close()


def random_state(description: RobotDescription, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random Pinocchio-convention state with joints inside their limits."""
    lower, upper = description.position_limits
    lower, upper = np.maximum(lower, -np.pi), np.minimum(upper, np.pi)
    quaternion = rng.normal(size=4)
    quaternion /= np.linalg.norm(quaternion)
    q = np.concatenate([rng.uniform(-1, 1, 3), quaternion, rng.uniform(lower, upper)])
    return q, rng.normal(size=description.dofs + 6)


def stand(robot: PybulletRobot, description: RobotDescription, steps: int) -> None:
    robot.reset()
    robot.set_joint_impedance(pd_hold_command(description))
    robot.step(steps)


def test_g1_stands_10_s_under_joint_pd(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_impedance(pd_hold_command(g1))
    heights, tilts, speeds = [], [], []
    for _ in range(100):  # 10 s in 0.1 s chunks
        g1_robot.step(50)
        heights.append(g1_robot.base_state().position[2])
        tilts.append(base_tilt_deg(g1_robot))
        speeds.append(np.abs(g1_robot.joint_velocities()).max())
    assert g1_robot.time() == pytest.approx(10.0)
    # Same bounds as the MuJoCo test, same gains, same 2 ms step.
    assert min(heights) > g1.default_base_position[2] - 0.03
    assert max(heights) < g1.default_base_position[2] + 0.01
    assert max(tilts) < 3.0
    assert np.linalg.norm(g1_robot.base_state().position[:2]) < 0.02
    assert max(speeds[50:]) < 0.05  # at rest after 5 s: no joint chatters


def test_without_armature_the_explicit_pd_chatters(g1: RobotDescription) -> None:
    """Why the armature is emulated: without it the wrists' explicit damping is unstable at 2 ms."""
    with PybulletRobot(g1, armature="ignore") as robot:
        stand(robot, g1, 500)
        speeds = np.abs(robot.joint_velocities())
        assert robot.base_state().position[2] > g1.default_base_position[2] - 0.03  # it still stands
        assert speeds.max() > 5.0  # ... with chattering joints
        worst = g1.joint_names[int(np.argmax(speeds))]
        assert "wrist" in worst or "shoulder_yaw" in worst


def test_total_mass_and_joint_inertia_match_pinocchio(g1: RobotDescription) -> None:
    model = g1.build_pinocchio()
    with PybulletRobot(g1, armature="ignore") as robot:
        assert robot.total_mass() == pytest.approx(g1.total_mass, rel=1e-12)
        assert robot.total_mass() == pytest.approx(pin.computeTotalMass(model), rel=1e-12)
        # Joint block of the mass matrix, without armature (Bullet computes it only for rigid inertias).
        q = g1.default_configuration()
        bullet = np.array(robot.client.calculateMassMatrix(robot.body, list(q[7:])))
        model.armature[:] = 0.0
        pinocchio = pin.crba(model, model.createData(), q)
        pinocchio = np.triu(pinocchio) + np.triu(pinocchio, 1).T
        np.testing.assert_allclose(bullet[6:, 6:], pinocchio[6:, 6:], atol=1e-9)


def test_armature_is_added_about_each_joint_axis(g1: RobotDescription, g1_robot: PybulletRobot) -> None:
    with PybulletRobot(g1, armature="ignore") as plain:
        for joint, spec in zip(g1_robot._joints, g1.joints):
            axis = np.array(g1_robot.client.getJointInfo(g1_robot.body, joint)[13])  # inertial frame
            with_armature = axis @ np.diag(g1_robot.client.getDynamicsInfo(g1_robot.body, joint)[2]) @ axis
            without = axis @ np.diag(plain.client.getDynamicsInfo(plain.body, joint)[2]) @ axis
            assert with_armature - without == pytest.approx(spec.armature, rel=1e-9), spec.name
    g1_robot.set_armature(2 * g1.joints[0].armature * np.ones(g1.dofs))
    g1_robot.set_armature(np.array([j.armature for j in g1.joints]))  # from the loaded inertia: no build-up
    np.testing.assert_allclose(g1_robot.armature, [j.armature for j in g1.joints])


def unit_torque_response(robot: PybulletRobot, description: RobotDescription, q: np.ndarray) -> np.ndarray:
    """Diagonal of the joint-space inverse inertia, from one step of a unit torque per joint."""
    response = np.zeros(description.dofs)
    for j in range(description.dofs):
        robot.reset(q)
        robot.set_joint_torques(np.eye(description.dofs)[j])
        robot.step(1)
        response[j] = robot.joint_velocities()[j] / robot.dt
    return response


def test_armature_emulation_measured_against_pinocchio(g1: RobotDescription) -> None:
    """The numbers the module docstring quotes: how close the link-inertia emulation gets."""
    model = g1.build_pinocchio()
    data = model.createData()
    q = g1.default_configuration()
    q[2] += 2.0  # free flight, gravity off: only inertia acts
    expected = np.array([pin.aba(model, data, q, np.zeros(model.nv), np.r_[np.zeros(6), e])[6 + j] for j, e in enumerate(np.eye(g1.dofs))])
    ratios = {}
    for mode in ("link", "ignore"):
        with PybulletRobot(g1, armature=mode) as robot:
            robot.set_gravity(np.zeros(3))
            ratios[mode] = unit_torque_response(robot, g1, q) / expected
            robot.reset(q)
            robot.set_external_wrench("pelvis", np.zeros(3), np.array([0.0, 0.0, 2.0]))
            robot.step(10)
            momentum = pin.computeCentroidalMomentum(model, data, *robot.generalized_state()).angular
            ratios[mode + " spin"] = momentum[2] / (2.0 * 10 * robot.dt)
    assert 0.85 < ratios["link"].min() and ratios["link"].max() < 2.6
    assert ratios["ignore"].max() > 10.0  # wrist and ankle roll: up to 23x too light without armature
    assert ratios["ignore spin"] == pytest.approx(1.0, abs=1e-3)  # no emulation: momentum exact
    assert 0.7 < ratios["link spin"] < 0.8  # emulation: the added inertias hold the rest (0.74 with robot.toml's armature)


def test_standing_contact_forces_balance_weight(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    stand(g1_robot, g1, 1000)
    wrenches = [g1_robot.contact_wrench(c.link) for c in g1.contacts]
    assert all(w.in_contact for w in wrenches)
    total = sum(w.force for w in wrenches)
    assert total[2] == pytest.approx(g1.total_mass * GRAVITY, rel=2e-3)
    assert np.linalg.norm(total[:2]) < 0.01 * total[2]
    assert not g1_robot.contact_wrench("pelvis").in_contact
    # Moment balance about each foot: the centre of pressure lies inside the sole rectangle.
    for contact, wrench in zip(g1.contacts, wrenches):
        position, rotation = g1_robot.link_pose(contact.link)
        force, torque = rotation.T @ wrench.force, rotation.T @ wrench.torque
        cop = np.array([-torque[1] / force[2], torque[0] / force[2]])  # about the link origin, sole plane
        center = np.asarray(contact.center)
        assert abs(cop[0] - center[0]) <= contact.half_length + 1e-6
        assert abs(cop[1] - center[1]) <= contact.half_width + 1e-6


def test_contact_forces_account_for_momentum_change_under_a_push(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    """Newton over one step: m (v_com' - v_com) = dt (contact forces + push + m g), friction included."""
    model = g1.build_pinocchio()
    data = model.createData()
    stand(g1_robot, g1, 250)
    push = np.array([6.0, -4.0, 0.0])
    g1_robot.set_external_wrench("pelvis", push)
    g1_robot.step(250)
    for _ in range(3):
        pin.centerOfMass(model, data, *g1_robot.generalized_state())
        before = data.vcom[0].copy()
        g1_robot.step(1)
        pin.centerOfMass(model, data, *g1_robot.generalized_state())
        after = data.vcom[0].copy()
        contact = sum(g1_robot.contact_wrench(c.link).force for c in g1.contacts)
        assert np.linalg.norm(contact[:2]) > 2.0  # friction is doing work here
        expected = g1.total_mass * (after - before) / g1_robot.dt - push - [0, 0, -g1.total_mass * GRAVITY]
        np.testing.assert_allclose(contact, expected, atol=0.05)
    g1_robot.set_external_wrench("pelvis", np.zeros(3))


def test_a_push_moves_the_robot_as_in_mujoco(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    mujoco = MujocoRobot(g1)
    for robot in (g1_robot, mujoco):
        robot.reset()
        robot.set_joint_impedance(pd_hold_command(g1))
        robot.step(250)
        robot.set_external_wrench("pelvis", np.array([6.0, -4.0, 0.0]))
        robot.step(500)
        robot.set_external_wrench("pelvis", np.zeros(3))
    bullet_xy, mujoco_xy = g1_robot.base_state().position[:2], mujoco.base_state().position[:2]
    assert bullet_xy[0] > 0.03 and mujoco_xy[0] > 0.03  # pushed forward by centimetres...
    np.testing.assert_allclose(bullet_xy, mujoco_xy, atol=0.01)  # ... and the engines agree within 1 cm


def test_foot_sensors_follow_mujoco_conventions(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    stand(g1_robot, g1, 1000)
    mujoco = MujocoRobot(g1)
    mujoco.set_joint_impedance(pd_hold_command(g1))
    mujoco.step(1000)
    for contact in g1.contacts:
        names = {kind: f"{contact.name}_{kind}" for kind in ("force", "torque", "touch")}
        force, touch = g1_robot.sensor(names["force"]), g1_robot.sensor(names["touch"])[0]
        foot_weight = g1_robot.client.getDynamicsInfo(g1_robot.body, g1_robot.link_index(contact.link))[0] * GRAVITY
        # The parent pushes the foot down with the contact force less the foot's own weight.
        assert force[2] == pytest.approx(-(touch - foot_weight), rel=5e-3)
        np.testing.assert_allclose(force, mujoco.sensor(names["force"]), atol=0.02 * touch)
        np.testing.assert_allclose(g1_robot.sensor(names["torque"]), mujoco.sensor(names["torque"]), atol=0.5)
        assert touch == pytest.approx(mujoco.sensor(names["touch"])[0], rel=0.01)
    with pytest.raises(KeyError, match="no sensor 'nose'"):
        g1_robot.sensor("nose")


def test_imu_at_rest_reads_gravity_and_base_orientation(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    stand(g1_robot, g1, 1000)
    imu = g1_robot.imu()
    rotation = quat_to_matrix(imu.quaternion)
    np.testing.assert_allclose(imu.linear_acceleration, rotation.T @ [0, 0, GRAVITY], atol=0.05)
    np.testing.assert_allclose(imu.angular_velocity, 0.0, atol=0.01)
    _, pelvis_rotation = g1_robot.link_pose("pelvis")
    np.testing.assert_allclose(rotation, pelvis_rotation, atol=1e-9)
    assert imu.time == pytest.approx(g1_robot.time())
    np.testing.assert_allclose(g1_robot.sensor("imu_quat"), np.roll(imu.quaternion, 1))


def test_imu_in_free_fall_and_spinning(g1_robot: PybulletRobot, g1: RobotDescription, rng: np.random.Generator) -> None:
    q = g1.default_configuration()
    q[2] += 3.0  # far above the floor
    q[3:7] = rng.normal(size=4)
    q[3:7] /= np.linalg.norm(q[3:7])
    v = np.zeros(g1.dofs + 6)
    v[3:6] = [0.3, -0.2, 0.5]  # base angular velocity, base frame
    g1_robot.reset(q, v)
    g1_robot.set_joint_torques(np.zeros(g1.dofs))
    g1_robot.step(1)
    imu = g1_robot.imu()
    # Uniform gravity and no contact: a free-falling rigid robot feels (almost) no specific force;
    # what remains is the centripetal acceleration of the IMU about the spinning robot's CoM.
    assert np.linalg.norm(imu.linear_acceleration) < 0.05
    np.testing.assert_allclose(imu.angular_velocity, v[3:6], atol=2e-3)  # IMU frame = pelvis orientation


def test_link_poses_match_pinocchio(g1_robot: PybulletRobot, g1: RobotDescription, rng: np.random.Generator) -> None:
    model = g1.build_pinocchio()
    data = model.createData()
    links = [f for f in model.frames if f.type == pin.FrameType.BODY]
    assert sorted(f.name for f in links) == sorted(g1_robot.link_names)  # every URDF link, fixed ones too
    for _ in range(3):
        q, v = random_state(g1, rng)
        g1_robot.reset(q, v)
        pin.framesForwardKinematics(model, data, q)
        for frame in links:
            position, rotation = g1_robot.link_pose(frame.name)
            placement = data.oMf[model.getFrameId(frame.name)]
            # 1e-6: Bullet's URDF parser keeps some frames in single precision (errors ~2e-7 seen).
            np.testing.assert_allclose(position, placement.translation, atol=1e-6, err_msg=frame.name)
            np.testing.assert_allclose(rotation, placement.rotation, atol=1e-6, err_msg=frame.name)


def test_link_velocities_match_pinocchio(g1_robot: PybulletRobot, g1: RobotDescription, rng: np.random.Generator) -> None:
    model = g1.build_pinocchio()
    data = model.createData()
    q, v = random_state(g1, rng)
    g1_robot.reset(q, v)
    pin.forwardKinematics(model, data, q, v)
    pin.updateFramePlacements(model, data)
    for name in ("pelvis", "left_ankle_roll_link", "right_wrist_yaw_link", "imu_in_pelvis"):
        frame = model.getFrameId(name)
        twist = pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED)
        linear, angular = g1_robot.link_velocity(name)
        np.testing.assert_allclose(linear, twist.linear, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(angular, twist.angular, atol=1e-6, err_msg=name)


def test_generalized_state_round_trips_through_reset(g1_robot: PybulletRobot, g1: RobotDescription, rng: np.random.Generator) -> None:
    q, v = random_state(g1, rng)
    g1_robot.reset(q, v)
    q_out, v_out = g1_robot.generalized_state()
    sign = np.sign(q_out[6] * q[6])  # q and -q are the same rotation
    np.testing.assert_allclose(q_out[:3], q[:3], atol=1e-12)
    np.testing.assert_allclose(sign * q_out[3:7], q[3:7], atol=1e-12)
    np.testing.assert_allclose(q_out[7:], q[7:], atol=1e-12)
    np.testing.assert_allclose(v_out, v, atol=1e-12)
    base = g1_robot.base_state()
    np.testing.assert_allclose(v_out[:6], base_velocity_local(base), atol=1e-12)
    assert g1_robot.time() == 0.0


def test_external_wrench_changes_momentum(g1: RobotDescription) -> None:
    """With gravity off and no contact, a held wrench changes linear and angular momentum by F t, T t.

    Over 20 ms: Bullet's multibody integrator does not conserve momentum exactly (a free, limp G1
    drifts ~1% in 0.2 s), so longer pushes need looser tolerances.
    """
    model = g1.build_pinocchio()
    data = model.createData()
    with PybulletRobot(g1, armature="ignore") as robot:  # the emulated armature holds momentum too
        robot.set_gravity(np.zeros(3))
        q = g1.default_configuration()
        q[2] += 2.0
        robot.reset(q)
        force, torque, steps = np.array([20.0, -10.0, 5.0]), np.array([0.0, 0.0, 2.0]), 10
        robot.set_external_wrench("pelvis", force)
        robot.step(steps)
        q1, v1 = robot.generalized_state()
        pin.centerOfMass(model, data, q1, v1)
        np.testing.assert_allclose(data.vcom[0], force * steps * robot.dt / g1.total_mass, rtol=1e-3)
        robot.reset(q)
        robot.set_external_wrench("pelvis", np.zeros(3), torque)
        robot.step(steps)
        q1, v1 = robot.generalized_state()
        momentum = pin.computeCentroidalMomentum(model, data, q1, v1)
        assert momentum.angular[2] == pytest.approx(torque[2] * steps * robot.dt, rel=1e-3)
        np.testing.assert_allclose(momentum.angular[:2], 0.0, atol=1e-3)  # Bullet's integrator drifts ~1 %
        np.testing.assert_allclose(momentum.linear, 0.0, atol=1e-3)
        robot.set_external_wrench("pelvis", np.zeros(3))
        before = robot.generalized_state()[1]
        robot.step(1)
        np.testing.assert_allclose(robot.generalized_state()[1][:3], before[:3], atol=1e-3)  # released


def test_torque_and_impedance_commands_are_identical(g1: RobotDescription, rng: np.random.Generator) -> None:
    with PybulletRobot(g1) as a, PybulletRobot(g1) as b:
        command = pd_hold_command(g1)
        command.tau_ff = rng.normal(scale=2.0, size=g1.dofs)
        a.set_joint_impedance(command)
        b.set_joint_torques(command.torque(b.joint_positions(), b.joint_velocities()))
        a.step(1)
        b.step(1)
        # Both are explicit torques in PyBullet: the same torque gives the same next state.
        np.testing.assert_array_equal(a.joint_efforts(), b.joint_efforts())
        np.testing.assert_array_equal(a.generalized_state()[0], b.generalized_state()[0])


def test_efforts_are_clipped_to_limits(g1_robot: PybulletRobot, g1: RobotDescription) -> None:
    g1_robot.reset()
    g1_robot.set_joint_torques(np.full(g1.dofs, 1e4))
    g1_robot.step(1)
    np.testing.assert_allclose(g1_robot.joint_efforts(), g1.effort_limits)


def test_bad_commands_are_rejected(g1_robot: PybulletRobot) -> None:
    with pytest.raises(ValueError, match="expected 29 joint torques"):
        g1_robot.set_joint_torques(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        g1_robot.set_joint_torques(np.full(29, np.nan))
    bad = ImpedanceCommand.damping(29, 1.0)
    bad.kp = -np.ones(29)
    with pytest.raises(ValueError, match=">= 0"):
        g1_robot.set_joint_impedance(bad)
    bad = ImpedanceCommand.damping(29, 1.0)
    bad.q_ref = np.full(29, np.nan)
    with pytest.raises(ValueError, match="not finite"):
        g1_robot.set_joint_impedance(bad)
    with pytest.raises(KeyError, match="no link 'tail'"):
        g1_robot.link_pose("tail")
    with pytest.raises(KeyError, match="no link 'tail'"):
        g1_robot.set_external_wrench("tail", np.ones(3))
    with pytest.raises(ValueError, match="reset expects q"):
        g1_robot.reset(np.zeros(5))
    with pytest.raises(ValueError, match="armature"):
        PybulletRobot(g1_robot.description, armature="magic")


def test_cartpole_pole_falls_and_cart_is_pushed(cartpole: RobotDescription) -> None:
    with PybulletRobot(cartpole) as robot:
        assert robot.floor is None and not robot.floating_base
        assert robot.total_mass() == pytest.approx(cartpole.total_mass)
        robot.reset(q=np.array([0.0, 0.05]))
        robot.set_joint_torques(np.array([5.0, 0.0]))
        robot.step(500)
        q = robot.joint_positions()
        assert robot.time() == pytest.approx(0.5)
        assert q[0] > 0.5 * 0.5 * (5.0 / 1.2) * 0.5**2 * 0.5
        assert abs(q[1]) > 0.1
        assert robot.joint_efforts()[1] == 0.0
        np.testing.assert_allclose(robot.base_state().position, 0.0)  # the rail stays fixed


def test_cartpole_matches_mujoco_over_half_a_second(cartpole: RobotDescription) -> None:
    """No contact, no armature: the two engines integrate the same ODE."""
    with PybulletRobot(cartpole) as bullet:
        mujoco = MujocoRobot(cartpole)
        for robot in (bullet, mujoco):
            robot.reset(q=np.array([0.0, 0.05]))
            robot.set_joint_torques(np.array([2.0, 0.0]))
            robot.step(500)
        np.testing.assert_allclose(bullet.joint_positions(), mujoco.joint_positions(), atol=5e-3)


def test_two_instances_coexist(g1: RobotDescription) -> None:
    with PybulletRobot(g1) as a, PybulletRobot(g1) as b:
        assert a.client.id != b.client.id
        a.set_joint_impedance(pd_hold_command(g1))
        b.set_joint_torques(np.zeros(g1.dofs))  # b collapses, a stands
        a.step(300)
        b.step(300)
        assert a.base_state().position[2] - b.base_state().position[2] > 0.05
        with PybulletRobot(g1) as c:  # a third, alone, reproduces a exactly
            c.set_joint_impedance(pd_hold_command(g1))
            c.step(300)
            np.testing.assert_array_equal(c.generalized_state()[0], a.generalized_state()[0])
    assert not a.client.connected
