"""Whole-body collision geometry: the description's primitives, their fit, and what they do in MuJoCo and PyBullet.

Physical facts: at the default pose only the feet touch anything; a G1 that falls rests on its body
(before the shapes existed it sank through the floor to a pelvis height of about -0.6 m); adjacent
collision bodies never collide, other pairs do, and switching self-collision off leaves the floor.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import struct
from pathlib import Path

import mujoco
import numpy as np
import pytest

from giwbc.robot import MujocoRobot, RobotDescription, RobotDescriptionError, load
from giwbc.robot.collision import (
    CollisionError,
    UrdfGeometry,
    capsule,
    excluded_pairs,
    fit_shape,
    matrix_to_quat,
    quat_to_matrix,
    read_stl,
    rpy_to_matrix,
)
from giwbc.robot.standing import pd_hold_command

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
THIGHS = ("left_hip_yaw_link", "right_hip_yaw_link")


def edited_robot(tmp_path: Path, name: str, edit) -> RobotDescription:
    """A copy of a shipped robot folder with its robot.toml passed through ``edit``."""
    folder = tmp_path / f"{name}-{len(list(tmp_path.iterdir()))}"
    shutil.copytree(ROBOTS / name, folder)
    config = folder / "robot.toml"
    config.write_text(edit(config.read_text()))
    return load(folder)


def g1_with_collision_table(tmp_path: Path, table: str) -> RobotDescription:
    return edited_robot(tmp_path, "g1", lambda text: text + "\n" + table)


# --- the description -------------------------------------------------------------------------
def test_g1_declares_primitives_for_the_whole_body(g1: RobotDescription) -> None:
    links = {s.link for s in g1.collision}
    assert {"pelvis", "torso_link", "head_link", *THIGHS, "left_knee_link", "right_knee_link"} <= links
    assert {"left_shoulder_yaw_link", "left_elbow_link", "left_wrist_yaw_link", "right_wrist_yaw_link"} <= links
    assert {s.kind for s in g1.collision} <= {"box", "capsule", "sphere"}
    assert set(g1.collision_links) == links | {c.link for c in g1.contacts}


def test_g1_shapes_cover_the_urdf_meshes(g1: RobotDescription) -> None:
    """Each declared primitive holds most of its link's mesh and nothing sticks out by more than 3 cm."""
    urdf = UrdfGeometry.parse(g1.urdf_path, g1.urdf_text())
    for shape in g1.collision:
        points = urdf.points(shape.link)
        distance = shape.signed_distance(points)
        assert np.mean(distance <= 0.0) > 0.5, shape.name
        assert distance.max() < 0.03, shape.name


def test_adjacent_collision_bodies_are_excluded_and_others_are_not(g1: RobotDescription) -> None:
    pairs = g1.self_collision_exclusions
    adjacent = [
        ("left_hip_yaw_link", "pelvis"),  # through the shapeless hip pitch and roll links
        ("pelvis", "torso_link"),  # through the waist links
        ("head_link", "torso_link"),  # one rigid body (fixed joint)
        ("left_shoulder_yaw_link", "torso_link"),
        ("left_elbow_link", "left_wrist_yaw_link"),  # through the shapeless wrist links
        ("left_ankle_roll_link", "left_knee_link"),  # the foot's contact box counts as its shape
    ]
    for pair in adjacent:
        assert tuple(sorted(pair)) in pairs
    for pair in [THIGHS, ("left_hip_yaw_link", "left_wrist_yaw_link"), ("left_ankle_roll_link", "right_ankle_roll_link"),
                 ("left_elbow_link", "torso_link"), ("left_knee_link", "pelvis")]:  # fmt: skip
        assert tuple(sorted(pair)) not in pairs


def test_excluded_pairs_on_a_small_tree() -> None:
    #  a -(fixed)- b ; a - c(shapeless) - d ; d - e ; a - f
    parents = {"b": ("a", "fixed"), "c": ("a", "revolute"), "d": ("c", "revolute"), "e": ("d", "revolute"), "f": ("a", "revolute")}
    pairs = excluded_pairs(parents, ["a", "b", "d", "e", "f"], extra=[("f", "e")])
    assert pairs == {("a", "b"), ("a", "d"), ("b", "d"), ("d", "e"), ("a", "f"), ("b", "f"), ("e", "f")}


# --- geometry and fitting -------------------------------------------------------------------
def test_capsule_from_endpoints_round_trips(rng: np.random.Generator) -> None:
    for _ in range(20):
        a, b = rng.normal(size=3), rng.normal(size=3)
        shape = capsule("c", "link", a, b, 0.1)
        ends = shape.endpoints()
        assert np.allclose(ends, [a, b]) or np.allclose(ends, [b, a])
        assert shape.size[1] == pytest.approx(np.linalg.norm(b - a) / 2)
        assert np.allclose(rpy_to_matrix(shape.rpy()), shape.rotation, atol=1e-9)
        assert np.allclose(quat_to_matrix(np.array(matrix_to_quat(shape.rotation))), shape.rotation, atol=1e-12)
        # the segment is inside, points a radius and a bit away along the normal are outside
        normal = np.cross(b - a, rng.normal(size=3))
        normal /= np.linalg.norm(normal)
        assert shape.signed_distance(np.stack([a, (a + b) / 2, (a + b) / 2 + 0.11 * normal]))[:2].max() == pytest.approx(-0.1)
        assert shape.signed_distance(((a + b) / 2 + 0.11 * normal)[None])[0] == pytest.approx(0.01)


def test_capsule_fit_recovers_a_cylinder() -> None:
    """A grid of points on a tilted cylinder of radius 3 cm and length 30 cm: the fit lies along it and holds it."""
    axis = np.array([0.3, -0.2, 0.9])
    axis /= np.linalg.norm(axis)
    side = np.cross(axis, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    other = np.cross(axis, side)
    angle, along = (g.ravel() for g in np.meshgrid(np.linspace(0, 2 * math.pi, 64, endpoint=False), np.linspace(-0.15, 0.15, 31)))
    points = 0.03 * (np.outer(np.cos(angle), side) + np.outer(np.sin(angle), other)) + np.outer(along, axis) + [0.1, 0, 0]
    shape = fit_shape("capsule", points, "fit", "link")
    a, b = shape.endpoints()
    assert abs((b - a) @ axis) / np.linalg.norm(b - a) == pytest.approx(1.0, abs=1e-3)
    assert shape.size[0] == pytest.approx(0.03, abs=1e-9)
    assert 2 * (shape.size[0] + shape.size[1]) == pytest.approx(0.3, abs=1e-9)
    inner = np.abs(along) < 0.15 - 0.03  # the rim circles stick out of the caps by (sqrt 2 - 1) r
    assert np.all(shape.signed_distance(points[inner]) < 1e-9)
    assert shape.signed_distance(points).max() == pytest.approx((math.sqrt(2) - 1) * 0.03, abs=1e-9)
    box = fit_shape("box", points, "fit", "link")
    assert np.all(box.signed_distance(points) < 1e-9)


def test_stl_reader_reads_binary_and_ascii_alike(tmp_path: Path) -> None:
    triangles = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [0, 1, 0], [0, 0, 1]]], dtype=np.float32)
    binary = tmp_path / "tet.stl"
    binary.write_bytes(b"\0" * 80 + struct.pack("<I", 2) + b"".join(b"\0" * 12 + t.tobytes() + b"\0\0" for t in triangles))
    ascii_file = tmp_path / "tet_ascii.stl"
    lines = ["solid tet"] + [
        line for t in triangles for line in ["facet normal 0 0 0", "outer loop", *(f"vertex {x} {y} {z}" for x, y, z in t), "endloop", "endfacet"]
    ] + ["endsolid tet"]  # fmt: skip
    ascii_file.write_text("\n".join(lines))
    assert np.array_equal(read_stl(binary), triangles.reshape(-1, 3))
    assert np.array_equal(read_stl(ascii_file), triangles.reshape(-1, 3))


def test_fit_from_the_description_uses_urdf_geometry(tmp_path: Path) -> None:
    """``fit = "capsule"`` on the cart-pole's pole (a visual cylinder, r = 1 cm, 0..0.5 m along z)."""
    table = '\n[[collision]]\nlink = "pole"\nfit = "capsule"\n\n[[collision]]\nlink = "cart"\nfit = "box"\n'
    cartpole = edited_robot(tmp_path, "cartpole", lambda text: text + table)
    pole, cart = cartpole.collision
    assert pole.kind == "capsule" and pole.size[0] == pytest.approx(0.01, abs=1e-9)
    assert np.allclose(sorted(pole.endpoints()[:, 2]), [0.01, 0.49], atol=1e-6)
    assert np.allclose(pole.endpoints()[:, :2], 0.0, atol=1e-9)
    assert cart.kind == "box" and np.allclose(cart.size, [0.15, 0.1, 0.05])
    # the G1 knee mesh: a capsule along the shin holding 90 % of the mesh
    g1 = g1_with_collision_table(tmp_path, '[[collision]]\nname = "fitted_shin"\nlink = "left_knee_link"\nfit = "capsule"\n')
    shin = next(s for s in g1.collision if s.name == "fitted_shin")
    a, b = shin.endpoints()
    assert abs(b - a)[2] / np.linalg.norm(b - a) > 0.95
    points = UrdfGeometry.parse(g1.urdf_path, g1.urdf_text()).points("left_knee_link")
    assert np.mean(shin.signed_distance(points) <= 0) > 0.9


@pytest.mark.parametrize(
    "table, message",
    [
        ('link = "pelvis"\nbox = { center = [0, 0, 0], half_extents = [0.1, 0.1, 0.1] }\nsphere = { center = [0, 0, 0], radius = 0.1 }', "exactly one"),
        ('link = "no_such_link"\nsphere = { center = [0, 0, 0], radius = 0.1 }', "not a link"),
        ('link = "pelvis"\ncapsule = { from = [0, 0, 0], to = [0, 0, 0], radius = 0.1 }', "coincide"),
        ('link = "pelvis"\nsphere = { center = [0, 0, 0], radius = -0.1 }', "radius must be > 0"),
        ('link = "pelvis"\nsphere = { center = [0, 0], radius = 0.1 }', "'center' needs 3"),
        ('link = "pelvis"\nbox = { center = [0, 0, 0], half_extents = [0.1, 0.1, 0.1], color = 1 }', "unknown keys"),
        ('link = "pelvis"\nfit = "cone"', "'fit' should be one of"),
        ('link = "imu_in_pelvis"\nfit = "capsule"', "no collision or visual geometry"),
        ('name = "left_thigh"\nlink = "pelvis"\nsphere = { center = [0, 0, 0], radius = 0.1 }', "unique"),
    ],
)
def test_bad_collision_tables_are_refused(tmp_path: Path, table: str, message: str) -> None:
    with pytest.raises(RobotDescriptionError, match=message):
        g1_with_collision_table(tmp_path, "[[collision]]\n" + table + "\n")


def test_bad_self_collision_tables_are_refused(tmp_path: Path) -> None:
    with pytest.raises(RobotDescriptionError, match="without collision shapes"):
        g1_with_collision_table(tmp_path, '[self_collision]\nexclude = [["pelvis", "left_hip_roll_link"]]\n')
    with pytest.raises(RobotDescriptionError, match="'enabled' should be"):
        g1_with_collision_table(tmp_path, '[self_collision]\nenabled = "yes"\n')


# --- MuJoCo ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def g1_model(g1: RobotDescription) -> mujoco.MjModel:
    return g1.build_mujoco()


def contact_pairs(model: mujoco.MjModel, data: mujoco.MjData) -> set[tuple[str, str]]:
    """Body-name pairs in contact (the floor is "world")."""
    names = [tuple(sorted((model.body(model.geom_bodyid[c.geom1]).name, model.body(model.geom_bodyid[c.geom2]).name))) for c in data.contact[: data.ncon]]
    return set(names)


def test_mujoco_has_one_geom_per_shape_and_the_same_inertia(g1: RobotDescription, g1_model: mujoco.MjModel) -> None:
    for shape in g1.collision:
        geom = g1_model.geom(shape.name)
        assert g1_model.body(int(geom.bodyid[0])).name == shape.link
        assert np.allclose(geom.size[: len(shape.size)], shape.size)
    feet_only = dataclasses.replace(g1, collision=()).build_mujoco()
    assert np.array_equal(feet_only.body_mass, g1_model.body_mass)
    assert np.array_equal(feet_only.body_inertia, g1_model.body_inertia)


def test_mujoco_default_pose_touches_with_the_feet_only(g1: RobotDescription) -> None:
    robot = MujocoRobot(g1)
    robot.reset()
    robot.set_joint_impedance(pd_hold_command(g1))
    feet = {tuple(sorted(("world", c.link))) for c in g1.contacts}
    robot.step(1)
    assert contact_pairs(robot.model, robot.data) == feet
    robot.step(500)  # 1 s standing on the PD hold
    assert contact_pairs(robot.model, robot.data) == feet


def settle_fallen_mujoco(description: RobotDescription, tilt: np.ndarray, gain: float, seconds: float = 3.0) -> MujocoRobot:
    """Tip the standing robot by the rotation vector ``tilt`` and let it fall, joints on ``gain`` times the PD hold."""
    robot = MujocoRobot(description)
    q = description.default_configuration()
    q[2] += 0.02
    angle = np.linalg.norm(tilt)
    if angle > 0:
        q[3:7] = np.concatenate([np.sin(angle / 2) * tilt / angle, [np.cos(angle / 2)]])
    robot.reset(q)
    hold = pd_hold_command(description)
    robot.set_joint_impedance(dataclasses.replace(hold, kp=gain * hold.kp, kd=np.maximum(gain, 0.1) * hold.kd))
    robot.step(round(seconds / description.timestep))
    return robot


@pytest.mark.parametrize(
    "tilt, gain",
    [((0.0, 0.0, 0.0), 0.0), ((0.0, 0.4, 0.0), 1.0), ((0.0, -0.4, 0.0), 1.0), ((0.4, 0.0, 0.0), 1.0)],
    ids=["limp", "forward", "backward", "sideways"],
)
def test_mujoco_fallen_g1_rests_on_its_body(g1: RobotDescription, tilt: tuple[float, float, float], gain: float) -> None:
    robot = settle_fallen_mujoco(g1, np.array(tilt), gain)
    base = robot.base_state()
    assert base.position[2] > 0.05  # feet-only collision: about -0.6 m
    assert np.linalg.norm(base.linear_velocity) < 0.05  # at rest
    touching = {b for pair in contact_pairs(robot.model, robot.data) if "world" in pair for b in pair} - {"world"}
    assert touching - {c.link for c in g1.contacts}  # something besides the feet holds it up


def overlap_pose(description: RobotDescription) -> np.ndarray:
    """In the air, thighs crossed (hip roll inward) and the left arm rolled into the torso."""
    q = description.default_configuration()
    names = description.joint_names
    for joint, angle in [("left_hip_roll_joint", -0.5), ("right_hip_roll_joint", 0.5), ("left_shoulder_roll_joint", -0.5)]:
        q[7 + names.index(joint)] = angle
    q[2] += 1.0  # nothing touches the floor
    return q


EXPECTED_SELF_CONTACTS = {THIGHS, ("left_elbow_link", "torso_link")}  # crossed thighs, forearm on the torso


def test_mujoco_self_collision_between_non_adjacent_bodies_only(g1: RobotDescription, g1_model: mujoco.MjModel, tmp_path: Path) -> None:
    data = mujoco.MjData(g1_model)
    robot_q = overlap_pose(g1)
    data.qpos[:3], data.qpos[3:7], data.qpos[7:] = robot_q[:3], [1, 0, 0, 0], robot_q[7:]
    mujoco.mj_forward(g1_model, data)
    fromto = np.zeros(6)
    geom = g1_model.geom
    assert mujoco.mj_geomDistance(g1_model, data, geom("torso_link_box").id, geom("left_upper_arm").id, 1.0, fromto) < -0.05
    pairs = contact_pairs(g1_model, data)
    assert EXPECTED_SELF_CONTACTS <= pairs
    assert not pairs & g1.self_collision_exclusions  # the upper arm, deep in the torso, does not collide with it
    # self-collision off: the same pose has no contact, the floor still holds the robot
    alone = g1_with_collision_table(tmp_path, "[self_collision]\nenabled = false\n")
    model = alone.build_mujoco()
    data = mujoco.MjData(model)
    data.qpos[:3], data.qpos[3:7], data.qpos[7:] = robot_q[:3], [1, 0, 0, 0], robot_q[7:]
    mujoco.mj_forward(model, data)
    assert data.ncon == 0
    robot = settle_fallen_mujoco(alone, np.array([0.0, 0.4, 0.0]), 1.0)
    assert robot.base_state().position[2] > 0.05


# --- PyBullet --------------------------------------------------------------------------------
def pybullet_contact_pairs(robot) -> set[tuple[str, str]]:
    names = {index: name for name, index in robot._link_index.items()}
    pairs = set()
    for point in robot.client.getContactPoints(bodyA=robot.body):
        other = names[point[4]] if point[2] == robot.body else "world"
        pairs.add(tuple(sorted((names[point[3]], other))))
    return pairs


def test_pybullet_default_pose_touches_with_the_feet_only_and_a_fall_rests_on_the_body(g1: RobotDescription) -> None:
    pytest.importorskip("pybullet")
    from giwbc.robot.pybullet_robot import PybulletRobot

    with PybulletRobot(g1) as robot:
        feet = {tuple(sorted(("world", c.link))) for c in g1.contacts}
        robot.reset()
        robot.set_joint_impedance(pd_hold_command(g1))
        robot.step(1)
        assert pybullet_contact_pairs(robot) == feet
        robot.step(250)
        assert pybullet_contact_pairs(robot) == feet

        q = overlap_pose(g1)
        robot.reset(q)
        robot.client.performCollisionDetection()
        pairs = pybullet_contact_pairs(robot)
        assert EXPECTED_SELF_CONTACTS <= pairs and not pairs & g1.self_collision_exclusions

        q = g1.default_configuration()
        q[2] += 0.02
        q[3:7] = [0.0, math.sin(0.2), 0.0, math.cos(0.2)]  # tipped 0.4 rad forward
        robot.reset(q)
        robot.set_joint_impedance(pd_hold_command(g1))
        robot.step(1500)
        assert robot.base_state().position[2] > 0.05  # feet-only collision: below the floor
        assert np.linalg.norm(robot.base_state().linear_velocity) < 0.05


def test_pybullet_and_mujoco_shapes_agree(g1: RobotDescription, g1_model: mujoco.MjModel, rng: np.random.Generator) -> None:
    """Every collision link's distance to the floor, at random poses in the air, is the same in both engines."""
    pytest.importorskip("pybullet")
    from giwbc.robot.pybullet_robot import PybulletRobot

    data = mujoco.MjData(g1_model)
    lower, upper = g1.position_limits
    floor, fromto = g1_model.geom("floor").id, np.zeros(6)
    geoms = {link: [g for g in range(g1_model.ngeom) if g1_model.geom_bodyid[g] == g1_model.body(link).id and g1_model.geom_contype[g]]
             for link in g1.collision_links}  # fmt: skip
    with PybulletRobot(g1) as robot:
        for _ in range(3):
            quaternion = rng.normal(size=4)
            quaternion /= np.linalg.norm(quaternion)  # (x, y, z, w)
            q = np.concatenate([[0.0, 0.0, 1.2], quaternion, rng.uniform(np.maximum(lower, -1.5), np.minimum(upper, 1.5))])
            robot.reset(q)
            data.qpos[:3], data.qpos[3:7], data.qpos[7:] = q[:3], np.roll(quaternion, 1), q[7:]
            mujoco.mj_forward(g1_model, data)
            for link, link_geoms in geoms.items():
                in_mujoco = min(mujoco.mj_geomDistance(g1_model, data, floor, g, 3.0, fromto) for g in link_geoms)
                points = robot.client.getClosestPoints(robot.body, robot.floor, 3.0, linkIndexA=robot.link_index(link))
                assert min(p[8] for p in points) == pytest.approx(in_mujoco, abs=1e-6), link
