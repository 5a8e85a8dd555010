"""Bring your own MJCF: a plant bound to the description by name, checked before the first step."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import gymnasium
import mujoco
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the ids)
from giwbc.errors import PlantMismatchError
from giwbc.randomization import DomainRandomizer
from giwbc.robot import load
from giwbc.robot.mujoco_model import build_mujoco_spec
from giwbc.robot.mujoco_robot import MujocoRobot
from giwbc.robot.standing import pd_hold_command


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _refused(g1, spec: mujoco.MjSpec, match: str) -> str:
    model = spec.compile()
    with pytest.raises(PlantMismatchError, match=match) as error:
        MujocoRobot(g1, model)
    assert "\n" not in str(error.value)  # one line
    return str(error.value)


def test_a_position_actuator_is_refused_naming_it(g1):
    spec = build_mujoco_spec(g1)
    knee = spec.actuator("left_knee_joint")
    knee.gainprm = [75.0] + [0.0] * 9
    knee.biasprm = [0.0, -75.0, 0.0] + [0.0] * 7  # MuJoCo's <position kp="75">: 1 N m of ctrl would be 75 N m
    _refused(g1, spec, "actuator 'left_knee_joint' is a position/velocity actuator \\(gain 75")
    spec = build_mujoco_spec(g1)
    ankle = spec.actuator("right_ankle_roll_joint")
    ankle.gainprm = [20.0] + [0.0] * 9
    ankle.biasprm = [0.0, 0.0, -20.0] + [0.0] * 7  # <velocity kv="20">
    _refused(g1, spec, "actuator 'right_ankle_roll_joint' is a position/velocity actuator")
    spec = build_mujoco_spec(g1)
    spec.actuator("left_elbow_joint").gainprm = [3.0] + [0.0] * 9
    _refused(g1, spec, "actuator 'left_elbow_joint' is not a torque actuator \\(gain 3\\)")
    spec = build_mujoco_spec(g1)
    spec.actuator("waist_yaw_joint").gear = [2.0, 0, 0, 0, 0, 0]
    _refused(g1, spec, "actuator 'waist_yaw_joint' has gear 2")


def test_a_model_reused_after_a_robot_held_impedance_gains_binds_again(g1):
    model = g1.build_mujoco()
    first = MujocoRobot(g1, model)
    first.set_joint_impedance(pd_hold_command(g1))  # the gains now sit in the model's actuator bias
    second = MujocoRobot(g1, model)
    assert np.all(second.model.actuator_biasprm[:, 1:3] == 0.0)  # cleared: a torque command is a torque again


def test_a_missing_sensor_renamed_joint_and_other_timestep_are_refused(g1):
    spec = build_mujoco_spec(g1)
    spec.delete(spec.sensor("left_foot_touch"))
    _refused(g1, spec, "no sensor 'left_foot_touch'")
    spec = build_mujoco_spec(g1)
    spec.joint("left_knee_joint").name = "left_knee"
    spec.actuator("left_knee_joint").target = "left_knee"
    _refused(g1, spec, "no joint 'left_knee_joint'")
    spec = build_mujoco_spec(g1)
    spec.option.timestep = 0.001
    _refused(g1, spec, "timestep 0.001 s, the description's is 0.002 s")
    spec = build_mujoco_spec(g1)
    spec.delete(spec.key("default"))
    _refused(g1, spec, "no keyframe")


def test_an_mjcf_file_gets_the_sensors_and_keyframe_it_lacks(g1, tmp_path):
    spec = build_mujoco_spec(g1)
    for name in ("left_foot_touch", "imu_gyro"):
        spec.delete(spec.sensor(name))
    spec.delete(spec.key("default"))
    path = tmp_path / "vendor.xml"
    path.write_text(spec.to_xml())
    robot = MujocoRobot(g1, path)
    left, right = robot.sensor("left_foot_touch")[0], robot.sensor("right_foot_touch")[0]
    assert left > 20.0 and left == pytest.approx(right, rel=0.05)  # the added sensor reads as the plant's own one
    assert robot.sensor("imu_gyro").shape == (3,)
    assert robot.joint_positions() == pytest.approx(g1.default_positions)


def _reordered_xml(g1) -> str:
    """The G1 with the right leg's subtree before the left's and the actuators in reverse order."""
    root = ET.fromstring(build_mujoco_spec(g1).to_xml())
    pelvis = next(b for b in root.iter("body") if b.get("name") == "pelvis")
    children = list(pelvis)
    left = next(c for c in children if c.get("name") == "left_hip_pitch_link")
    right = next(c for c in children if c.get("name") == "right_hip_pitch_link")
    i, j = children.index(left), children.index(right)
    pelvis[i], pelvis[j] = right, left
    actuators = root.find("actuator")
    motors = list(actuators)
    for motor in motors:
        actuators.remove(motor)
    for motor in reversed(motors):
        actuators.append(motor)
    key = root.find("keyframe")
    if key is not None:
        root.remove(key)  # its qpos follows the old order: giwbc writes keyframe 0 from the description
    return ET.tostring(root, encoding="unicode")


def test_by_name_binding_gives_the_same_physics_in_another_joint_order(g1, tmp_path):
    path = tmp_path / "reordered.xml"
    path.write_text(_reordered_xml(g1))
    nominal, reordered = MujocoRobot(g1), MujocoRobot(g1, path)
    first = lambda m: m.joint(1).name  # noqa: E731
    assert first(nominal.model) == "left_hip_pitch_joint" and first(reordered.model) == "right_hip_pitch_joint"
    hold = pd_hold_command(g1)
    hold.tau_ff[g1.joint_names.index("left_elbow_joint")] = 1.0  # an asymmetric command: a swapped joint shows
    for robot in (nominal, reordered):
        robot.set_joint_impedance(hold)
        robot.step(250)
    (q0, v0), (q1, v1) = nominal.generalized_state(), reordered.generalized_state()
    assert np.abs(q1 - q0).max() < 1e-6 and np.abs(v1 - v0).max() < 1e-5
    assert reordered.joint_efforts() == pytest.approx(nominal.joint_efforts(), abs=1e-4)


def _fused_g1(g1) -> mujoco.MjModel:
    spec = build_mujoco_spec(g1)
    spec.compiler.fusestatic = True  # as MuJoCo's URDF import does by default
    return spec.compile()


def test_randomizing_a_plant_with_merged_links(g1):
    model = _fused_g1(g1)
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "pelvis_contour_link") < 0  # merged into the pelvis
    env = gymnasium.make("giwbc/G1Walk-v0", model=model, randomization={"parameters": []})
    env.reset(seed=3)
    env.close()
    robot = MujocoRobot(g1, _fused_g1(g1))
    pelvis = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, "pelvis")
    mass0, com0 = float(robot.model.body_mass[pelvis]), robot.model.body_ipos[pelvis].copy()
    randomizer = DomainRandomizer({"parameters": [
        {"parameter": "link_mass", "distribution": "uniform", "low": 1.0, "high": 1.0, "operation": "add", "links": ["pelvis_contour_link"]},
    ]}, g1)
    randomizer.randomize(robot, np.random.default_rng(0))
    assert robot.model.body_mass[pelvis] == pytest.approx(mass0 + 1.0)  # the merged link's kilogram lands on its carrier
    assert not np.allclose(robot.model.body_ipos[pelvis], com0)  # and moves its centre of mass towards that link
    randomizer.restore(robot)
    assert robot.model.body_mass[pelvis] == pytest.approx(mass0)


def test_the_deploy_emulator_takes_a_plant(g1):
    from giwbc.emulation.emulator import ActuatorEmulator
    from giwbc.hal.hardware import load_hardware

    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    with ActuatorEmulator(plan, g1, plant="point_feet") as emulator:
        assert len([g for g in range(emulator.robot.model.ngeom) if (emulator.robot.model.geom(g).name or "").startswith("left_foot_sole_")]) == 3
    with pytest.raises(PlantMismatchError, match="unknown plant 'no_such_plant'"):
        ActuatorEmulator(plan, g1, plant="no_such_plant")


def test_the_evaluation_protocols_carry_the_plant_to_the_env():
    from giwbc.apps.evaluation import PushProtocol
    from giwbc.apps.walk_evaluation import WalkProtocol

    assert WalkProtocol(plant="point_feet").env_overrides({}, 50.0)["plant"] == "point_feet"
    assert "plant" not in PushProtocol().env_overrides({}, 50.0)  # the robot's own model by default


def test_envs_take_a_plant(g1):
    env = gymnasium.make("giwbc/G1Balance-v0", plant="lagged_actuators")
    env.reset(seed=2)
    robot = env.unwrapped.engine_robot
    assert robot.actuator_dynamics is not None and robot.actuator_dynamics.lag.max() == pytest.approx(0.004)
    env.close()
    with pytest.raises(PlantMismatchError, match="model= or plant="):
        gymnasium.make("giwbc/G1Walk-v0", plant="point_feet", model=g1.build_mujoco())


def test_walk_and_evaluate_refuse_an_unknown_plant_in_one_line(capsys):
    from giwbc.apps.cli import main

    assert main(["walk", "--plant", "no_such_plant", "--seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown plant 'no_such_plant'" in err and "point_feet" in err
    assert main(["evaluate", "--protocol", "walk", "--plant", "missing.xml", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.xml: no such MJCF file" in err


def test_a_vendor_motor_is_adopted_with_its_control_range_as_force_limit(g1):
    spec = build_mujoco_spec(g1)
    knee = spec.actuator("left_knee_joint")
    knee.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    knee.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    knee.ctrlrange = [-100.0, 100.0]  # as a vendor's <motor ctrlrange="-100 100"/>
    robot = MujocoRobot(g1, spec.compile())
    index = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "left_knee_joint")
    assert robot.model.actuator_forcerange[index] == pytest.approx([-100.0, 100.0]) and robot.model.actuator_ctrllimited[index] == 0
    command = np.zeros(g1.dofs)
    command[g1.joint_names.index("left_knee_joint")] = 500.0
    robot.set_joint_torques(command)
    robot.step()
    assert robot.joint_efforts()[g1.joint_names.index("left_knee_joint")] == pytest.approx(100.0)


def test_a_merged_link_keeps_its_pose(g1):
    nominal, fused = MujocoRobot(g1), MujocoRobot(g1, _fused_g1(g1))
    for link in ("imu_in_pelvis", "pelvis_contour_link"):
        (p0, r0), (p1, r1) = nominal.link_pose(link), fused.link_pose(link)
        assert np.allclose(p1, p0, atol=1e-9) and np.allclose(r1, r0, atol=1e-9)
