"""The support region from the robot description's sole geometry: the hull of point / polygon /
box soles, the wrench cone of that hull, and a WBC whose solved CoP stays inside it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.control.contacts import PolygonContact, SurfaceContact, foot_contacts, pyramid_generators, wrench_cone_matrix
from giwbc.control.sole import SoleSupport, hull_2d, polygon_wrench_cone, scale_polygon
from giwbc.errors import RobotDescriptionError
from giwbc.robot.description import load

TRIANGLE = ((0.080, 0.025), (0.080, -0.025), (-0.080, 0.0))  # two toe points, one heel point on the centreline


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def with_sole(description, sole):
    contacts = tuple(dataclasses.replace(c, sole=sole) for c in description.contacts)
    return dataclasses.replace(description, contacts=contacts)


def inside(point, polygon, tol=1e-9):
    edges = np.roll(polygon, -1, axis=0) - polygon
    rel = point - polygon
    return bool(np.all(edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0] >= -tol))


def test_box_sole_is_the_rectangle_and_its_cone_the_closed_form(g1):
    contact = g1.contacts[0]
    assert contact.sole == ()
    np.testing.assert_array_equal(np.sort(contact.sole_points, axis=0), np.sort(contact.corners[:, :2] - contact.center[:2], axis=0))
    faces = polygon_wrench_cone(contact.sole_points, 0.8)
    closed = wrench_cone_matrix(contact.half_length, contact.half_width, 0.8)
    closed /= np.linalg.norm(closed, axis=1, keepdims=True)
    assert len(faces) == 16
    for row in closed:  # the same 16 faces
        assert np.abs(faces - row).max(axis=1).min() < 1e-9


def test_point_sole_hull_and_cone(g1):
    points = np.array([*TRIANGLE, (0.0, 0.0), (0.05, 0.01)])  # interior points drop out of the hull
    hull = hull_2d(points)
    assert len(hull) == 3 and {tuple(p) for p in hull} == set(TRIANGLE)
    faces = polygon_wrench_cone(points, 0.7)
    generators = pyramid_generators(np.c_[hull, np.zeros(3)], 0.7)
    assert (faces @ generators).max() < 1e-12  # every pyramid edge at a sole point is inside
    # a CoP at a heel corner of the rectangle is outside this sole's cone
    heel_corner = np.array([0.0, 0.0, 1.0, -0.02, 0.07, 0.0])  # f_z = 1 N at (-0.07, -0.02): tau = p x f
    assert (faces @ heel_corner).max() > 0.0
    centre = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    assert (faces @ centre).max() < 0.0


def test_polygon_sole_in_robot_toml_and_refusals(tmp_path, g1):
    folder = tmp_path / "g1poly"
    folder.mkdir()
    text = (g1.folder / "robot.toml").read_text().replace('erd:', 'erd:', 1)
    text = text.replace('half_width = 0.03     # along the link y axis', 'half_width = 0.03\nsole = [[0.08, 0.025], [0.08, -0.025], [-0.08, 0.0]]', 1)
    (folder / "robot.toml").write_text(text)
    robot = load(folder / "robot.toml")
    assert robot.contacts[0].sole == TRIANGLE and robot.contacts[1].sole == ()
    contacts = foot_contacts(robot, scale=0.85)
    assert isinstance(contacts[0], PolygonContact) and isinstance(contacts[1], SurfaceContact)
    # In the contact frame, which sits at the hull's area centroid (the triangle's: 0.0267 m ahead of the rectangle's centre).
    centroid = np.array(TRIANGLE).mean(axis=0)
    np.testing.assert_allclose(np.sort(contacts[0].support_polygon(), axis=0), np.sort(scale_polygon(hull_2d(np.array(TRIANGLE)), 0.85) - centroid, axis=0))
    np.testing.assert_allclose(contacts[0].offset.translation, np.asarray(robot.contacts[0].center) + [*centroid, 0.0])
    for bad, message in (("[[0.08, 0.025], [0.08, -0.025]]", "at least 3"), ("[[0.2, 0.0], [0.08, -0.025], [-0.08, 0.0]]", "outside"),
                         ("[[0.0, 0.0], [0.01, 0.0], [0.02, 0.0]]", "one line")):
        (folder / "robot.toml").write_text(text.replace("[[0.08, 0.025], [0.08, -0.025], [-0.08, 0.0]]", bad))
        with pytest.raises(RobotDescriptionError, match=message):
            load(folder / "robot.toml")


def test_reduced_supports_lie_inside_the_sole():
    support = SoleSupport(np.array(TRIANGLE), 0.8)
    assert support.modes[0].kind == "full" and len(support.modes) == 1 + 3 + 3
    for mode, count in zip(support.modes, support.counts):
        assert count <= support.n_rows
        assert all(inside(p, support.polygon, 1e-12) for p in mode.polygon), mode


@pytest.mark.parametrize("sole", [(), TRIANGLE], ids=["box", "points"])
def test_the_solved_cop_stays_in_the_hull(g1, sole):
    """A CoM target far to the side and back: the QP's CoP of each foot stays inside its (margined) hull."""
    robot = with_sole(g1, sole)
    controller = BalanceController(robot, BalanceConfig(support_scale=0.85))
    q = robot.default_configuration()
    v = np.zeros(robot.pinocchio_model.nv)
    controller.reset(q)
    controller.set_com_target(controller.nominal_com + np.array([-0.06, -0.12, 0.0]))
    for i in range(3):
        result = controller.update(q, v, 0.002 * i)
    for contact in controller.contacts:
        wrench = result.contact_wrenches[contact.name]
        assert wrench[2] > 1.0
        cop = np.array([-wrench[4], wrench[3]]) / wrench[2]  # contact frame, about the sole centre
        assert inside(cop, contact.support_polygon(), 1e-6), (contact.name, cop)


def _stance_foot_tilt(description, plant: str, command, seconds: float, seed: int):
    """Max tilt (deg) of a loaded foot (touch sensor > 50 N) and whether the robot fell, walker on the true state."""
    import math

    from giwbc.locomotion.simulation import simulate_walk
    from giwbc.robot.mujoco_model import foot_sensor_names

    touch = [foot_sensor_names(c.name)["touch"] for c in description.contacts]
    links = [c.link for c in description.contacts]
    tilt = [0.0]

    def observe(robot, controller):
        for link, name in zip(links, touch):
            if robot.sensor(name)[0] > 50.0:
                rotation = robot.link_pose(link)[1]
                tilt[0] = max(tilt[0], math.degrees(math.acos(min(1.0, float(rotation[2, 2])))))

    run = simulate_walk(description, command, seconds, seed=seed, plant=plant, observe=observe)
    return tilt[0], run.fell


@pytest.mark.slow
def test_point_feet_stand_and_walk_flat_on_their_own_hull(g1):
    """The point-foot plant (two toe points, one heel point on the centreline): with the sole's
    points in the description the walker's CoP stays on the triangle — standing 10 s no loaded foot
    tilts past 2 deg, walking 0.3 m/s no loaded foot past 6 deg and no fall; planned on the
    rectangle, the walking feet roll over (~20 deg)."""
    sole = ((0.080, 0.025), (0.080, -0.025), (-0.080, 0.0))
    robot = with_sole(g1, sole)
    standing, fell = _stance_foot_tilt(robot, "point_feet", (0.0, 0.0, 0.0), 10.0, seed=7)
    assert not fell and standing < 2.0
    walking, fell = _stance_foot_tilt(robot, "point_feet", (0.3, 0.0, 0.0), 6.0, seed=7)
    assert not fell and walking < 6.0
    rectangle, _ = _stance_foot_tilt(g1, "point_feet", (0.3, 0.0, 0.0), 6.0, seed=7)
    assert rectangle > 2.0 * walking


def test_corner_model_puts_one_force_per_sole_point(g1):
    """The corner model on a 3-point sole: 3 forces, each in its pyramid, summing to the weight."""
    robot = with_sole(g1, TRIANGLE)
    controller = BalanceController(robot, BalanceConfig(contact_model="corners", support_scale=1.0))
    q = robot.default_configuration()
    controller.reset(q)
    result = controller.update(q, np.zeros(robot.pinocchio_model.nv), 0.0)
    total = 0.0
    for contact in controller.contacts:
        points = contact.corners[:, :2] + contact.offset.translation[:2] - np.asarray(robot.contacts[0].center)[:2]  # back to the rectangle's centre
        assert contact.n_force == 9 and {tuple(np.round(p, 12)) for p in points} == set(TRIANGLE)
        forces = contact.corner_forces(controller.wbc.contact_forces(contact.name, result))
        assert (forces[:, 2] >= -1e-6).all() and (np.abs(forces[:, :2]) <= contact.mu * forces[:, 2:3] + 1e-6).all()
        total += forces[:, 2].sum()
    assert total == pytest.approx(robot.total_mass * 9.81, rel=0.05)
