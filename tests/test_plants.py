"""Plant variants: each parameter changes the MuJoCo plant as documented (giwbc.plants)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from giwbc.errors import PlantMismatchError
from giwbc.plants import FootShape, PlantVariant, available_variants, build_plant, plant_robot, resolve_plant, sole_points
from giwbc.robot import load
from giwbc.robot.actuator_dynamics import ActuatorDynamics
from giwbc.robot.mujoco_model import SOLE_THICKNESS
from giwbc.robot.mujoco_robot import MujocoRobot


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _sole_geoms(model: mujoco.MjModel, foot: str) -> list[int]:
    return [g for g in range(model.ngeom) if (model.geom(g).name or "").startswith(f"{foot}_sole")]


def _lowest_points(model: mujoco.MjModel, geoms: list[int]) -> np.ndarray:
    """Lowest z (body frame, geoms unrotated about x/y so z extent = radius or half-height) of each geom."""
    out = []
    for g in geoms:
        kind, size, pos = model.geom_type[g], model.geom_size[g], model.geom_pos[g]
        out.append(pos[2] - (size[2] if kind == mujoco.mjtGeom.mjGEOM_BOX else size[0]))
    return np.array(out)


@pytest.mark.parametrize(
    ("feet", "count", "kind"),
    [
        (FootShape("capsules", 0.012, 2), 2, mujoco.mjtGeom.mjGEOM_CAPSULE),
        (FootShape("capsules", 0.01, 3), 3, mujoco.mjtGeom.mjGEOM_CAPSULE),
        (FootShape("corner_spheres", 0.005), 4, mujoco.mjtGeom.mjGEOM_SPHERE),
        (FootShape("points", 0.005, points=((0.08, 0.025), (0.08, -0.025), (-0.08, 0.0))), 3, mujoco.mjtGeom.mjGEOM_SPHERE),
    ],
)
def test_foot_shapes_touch_the_sole_plane_within_the_rectangle(g1, feet, count, kind):
    model = build_plant(g1, PlantVariant(name="t", feet=feet)).model
    contact = g1.contact("left_foot")
    geoms = _sole_geoms(model, "left_foot")
    assert len(geoms) == count and all(model.geom_type[g] == kind for g in geoms)
    assert np.allclose(model.geom_size[geoms, 0], feet.radius)
    assert np.allclose(_lowest_points(model, geoms), contact.center[2], atol=1e-12)  # lowest points on the sole plane
    reach_x = np.abs(model.geom_pos[geoms, 0] - contact.center[0]) + np.where(kind == mujoco.mjtGeom.mjGEOM_CAPSULE, model.geom_size[geoms, 1], 0) + feet.radius
    assert np.all(reach_x <= contact.half_length + 1e-12)
    points = sole_points(g1, PlantVariant(feet=feet), "left_foot")
    assert np.all(np.abs(points[:, 1] - contact.center[1]) <= contact.half_width - feet.radius + 1e-12)


def test_point_feet_heel_is_one_point_on_the_centreline(g1):
    plant = resolve_plant(g1, "point_feet")
    model = plant.model
    geoms = _sole_geoms(model, "right_foot")
    contact = g1.contact("right_foot")
    heel = [g for g in geoms if model.geom_pos[g, 0] < contact.center[0]]
    assert len(heel) == 1 and model.geom_pos[heel[0], 1] == pytest.approx(contact.center[1])


def test_rounded_box_keeps_a_flat_core_and_rounds_its_edges(g1):
    model = build_plant(g1, PlantVariant(name="r", feet=FootShape("rounded_box", 0.01))).model
    geoms = _sole_geoms(model, "left_foot")
    boxes = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    capsules = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
    contact = g1.contact("left_foot")
    assert len(boxes) == 1 and len(capsules) == 4
    assert model.geom_size[boxes[0], :2] == pytest.approx([contact.half_length - 0.01, contact.half_width - 0.01])
    assert model.geom_size[boxes[0], 2] == pytest.approx(SOLE_THICKNESS)
    assert np.allclose(_lowest_points(model, geoms), contact.center[2])


def test_contact_solver_and_joint_parameters_land_in_the_model(g1):
    variant = PlantVariant(
        name="t", solref=(0.05, 0.8), solimp=(0.8, 0.95, 0.01, 0.5, 2.0), friction=(0.6, 0.01, 0.001),
        joints={"frictionloss": {"*knee*": 1.2, "*": 0.1}, "damping": {"*ankle*": 0.05},
                "armature_scale": {"*hip_pitch*": 2.5}, "effort_scale": {"*ankle*": 0.85}},
        iterations=20, ls_iterations=10,
    )
    nominal, model = g1.build_mujoco(), build_plant(g1, variant).model
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    foot = _sole_geoms(model, "left_foot")[0]
    for g in (floor, foot):
        assert model.geom_solref[g] == pytest.approx([0.05, 0.8])
        assert model.geom_solimp[g] == pytest.approx([0.8, 0.95, 0.01, 0.5, 2.0])
        assert model.geom_friction[g] == pytest.approx([0.6, 0.01, 0.001])
    assert (model.opt.iterations, model.opt.ls_iterations) == (20, 10)

    def dof(name: str) -> int:
        return int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)])

    assert model.dof_frictionloss[dof("left_knee_joint")] == 1.2  # first matching pattern wins
    assert model.dof_frictionloss[dof("left_elbow_joint")] == 0.1
    assert model.dof_damping[dof("right_ankle_roll_joint")] == 0.05 and model.dof_damping[dof("left_knee_joint")] == 0.0
    assert model.dof_armature[dof("left_hip_pitch_joint")] == pytest.approx(2.5 * nominal.dof_armature[dof("left_hip_pitch_joint")])
    assert model.dof_armature[dof("left_knee_joint")] == nominal.dof_armature[dof("left_knee_joint")]
    ankle = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "left_ankle_pitch_joint")
    assert model.actuator_forcerange[ankle] == pytest.approx([-0.85 * 35.0, 0.85 * 35.0])


def test_imu_mounting_error_tilts_the_imu_reading(g1):
    nominal = MujocoRobot(g1)
    mounted = plant_robot(g1, PlantVariant(name="imu", imu_rotation=(1.0, 0.5, 0.0), imu_offset=(0.005, 0.0, 0.0)))
    q0, q1 = nominal.sensor("imu_quat"), mounted.sensor("imu_quat")  # (w, x, y, z), same pose
    relative = np.empty(4)
    conjugate = np.empty(4)
    mujoco.mju_negQuat(conjugate, q0)
    mujoco.mju_mulQuat(relative, conjugate, q1)
    angle = 2 * math.degrees(math.acos(min(1.0, abs(relative[0]))))
    assert angle == pytest.approx(math.hypot(1.0, 0.5), rel=2e-3)  # small angles: the rotation's size


def test_actuator_lag_is_a_first_order_response_to_a_step(g1):
    tau = 0.01
    robot = plant_robot(g1, PlantVariant(name="lag", actuators={"lag": {"*elbow*": tau}}))
    elbow = g1.joint_names.index("left_elbow_joint")
    knee = g1.joint_names.index("left_knee_joint")
    command = np.zeros(g1.dofs)
    command[[elbow, knee]] = 2.0
    robot.set_joint_torques(command)
    dt = g1.timestep
    for k in range(1, 11):
        robot.step()
        efforts = robot.joint_efforts()
        assert efforts[elbow] == pytest.approx(2.0 * (1 - math.exp(-k * dt / tau)), rel=1e-9)
        assert efforts[knee] == pytest.approx(2.0)  # no lag on the knee


def test_torque_speed_envelope_clamps_motoring_torque_only():
    dynamics = ActuatorDynamics(np.zeros(3), np.full(3, 10.0), np.full(3, 5.0), np.full(3, 15.0))
    torque = np.array([10.0, 10.0, -10.0])
    assert dynamics.available(torque, np.array([10.0, -10.0, 10.0])) == pytest.approx([5.0, 10.0, -10.0])  # braking keeps the peak
    assert dynamics.available(torque, np.array([20.0, 3.0, -12.0])) == pytest.approx([0.0, 10.0, -3.0])


def test_torque_speed_envelope_in_the_plant(g1):
    robot = plant_robot(g1, PlantVariant(name="env", actuators={"knee_speed": {"*knee*": 5.0}, "no_load_speed": {"*knee*": 15.0}}))
    knee = g1.joint_names.index("left_knee_joint")
    q, v = robot.generalized_state()
    v[6 + knee] = 10.0
    robot.reset(q, v)
    command = np.zeros(g1.dofs)
    command[knee] = 100.0
    robot.set_joint_torques(command)
    robot.step()
    speed = 10.0
    assert robot.joint_efforts()[knee] == pytest.approx(139.0 * (15.0 - speed) / 10.0)  # at the step's start speed


def test_variant_errors_name_what_is_wrong(g1):
    with pytest.raises(PlantMismatchError, match="'\\*kneee\\*' matches no joint"):
        build_plant(g1, PlantVariant(name="typo", joints={"frictionloss": {"*kneee*": 1.0}}))
    with pytest.raises(PlantMismatchError, match="unknown parameter 'friction'"):
        PlantVariant(name="bad", joints={"friction": {"*": 1.0}})
    with pytest.raises(PlantMismatchError, match="capsules': count must be 2 or 3"):
        FootShape("capsules", 0.01, 5)
    with pytest.raises(PlantMismatchError, match="unknown plant 'nope'"):
        resolve_plant(g1, "nope")


def test_the_g1_ships_its_variants_and_each_builds(g1):
    names = available_variants(g1)
    assert {"capsule_feet", "point_feet", "rounded_feet", "soft_floor", "frictional_joints", "lagged_actuators", "all_at_once"} <= set(names)
    for name in names:
        plant = resolve_plant(g1, name)
        assert plant.variant is not None and plant.variant.description, name  # each documents itself
        robot = MujocoRobot(g1, **plant.robot_options())
        robot.step(5)
        assert np.all(np.isfinite(robot.generalized_state()[0]))


def test_engine_level_plant_parameters_are_randomized_per_episode(g1):
    from giwbc.randomization import DomainRandomizer

    robot = MujocoRobot(g1)
    floor = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")

    def entry(parameter, low, high, **extra):
        return {"parameter": parameter, "distribution": "uniform", "low": low, "high": high, "operation": "absolute", **extra}

    randomizer = DomainRandomizer({"parameters": [entry("contact_timeconst", 0.03, 0.05), entry("solver_iterations", 10, 30),
                                                  entry("actuator_lag", 0.004, 0.004, joints=["left_elbow_joint"])]}, g1)
    rng = np.random.default_rng(7)
    drawn = [randomizer.randomize(robot, rng).physics for _ in range(2)]
    timeconst = drawn[-1].scalar("contact_timeconst")
    assert 0.03 <= timeconst <= 0.05 and drawn[0].scalar("contact_timeconst") != timeconst  # a new draw per episode
    assert robot.model.geom_solref[floor, 0] == timeconst
    assert robot.model.opt.iterations == int(drawn[-1].scalar("solver_iterations"))
    robot.reset()
    elbow = g1.joint_names.index("left_elbow_joint")
    command = np.zeros(g1.dofs)
    command[elbow] = 1.0
    robot.set_joint_torques(command)
    robot.step(2)
    assert robot.joint_efforts()[elbow] == pytest.approx(1 - math.exp(-2 * g1.timestep / 0.004))
    randomizer.restore(robot)
    assert robot.model.geom_solref[floor, 0] == 0.02 and robot.model.opt.iterations == 100 and robot.actuator_dynamics is None
