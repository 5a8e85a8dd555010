"""The CAN robot against the emulator: joint-side conversion, commands, late and missing replies,
IMU, base state only from an estimator, and the one-call encoder against the per-bus protocols."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from giwbc.errors import HardwareConfigError

from giwbc.hal.can_robot import BaseStateUnavailable, CanRobot, NonFiniteCommand
from giwbc.hal.imu import imu_source_for
from giwbc.hal.frames import FastMessage, fast_message
from giwbc.emulation import ActuatorEmulator, EmulatorConfig, FaultInjection
from giwbc.hal.hardware import ImuConfig, load_hardware
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.estimation.estimator import StateEstimator
from giwbc.robot.interface import ImpedanceCommand
from giwbc.robot.standing import pd_hold_command

DT = 0.002
TWISTED = {  # joint: (sign, gear ratio, zero offset)
    "left_knee_joint": (-1, 2.0, 0.3),
    "right_hip_roll_joint": (-1, 1.0, -0.1),
    "left_elbow_joint": (1, 1.5, 0.2),
    "waist_yaw_joint": (-1, 1.0, 0.0),
}


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


@pytest.fixture(scope="module")
def plan(g1):
    return load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")


@pytest.fixture(scope="module")
def twisted_plan(plan):
    """The G1 plan with some motors mounted reversed, geared and offset."""
    buses = []
    for bus in plan.buses:
        motors = tuple(
            replace(m, sign=TWISTED[m.joint][0], gear_ratio=TWISTED[m.joint][1], zero_offset=TWISTED[m.joint][2]) if m.joint in TWISTED else m
            for m in bus.motors
        )
        buses.append(replace(bus, motors=motors))
    return replace(plan, buses=tuple(buses))


@pytest.fixture
def rig(g1, plan, model):
    made = []

    def make(hardware=None, **config):
        emulator = ActuatorEmulator(hardware or plan, g1, EmulatorConfig(**config), model=copy.copy(model))
        # The emulator answers before collection starts (lockstep): a generous reply timeout only
        # matters when a reply is really missing, and (with the send budget) keeps a descheduled
        # test process from reading in-time replies as missing or dropping sends on a loaded machine.
        robot = CanRobot(g1, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator, reply_timeout=0.02, send_budget=0.5)
        made.append((robot, emulator))
        return robot, emulator

    yield make
    for robot, emulator in made:
        robot.close()
        emulator.close()


def hold(robot: CanRobot, cycles: int, start: int = 1) -> None:
    for k in range(start, start + cycles):
        robot.exchange(k * DT)


def test_joint_state_and_commands_cross_sign_offset_and_gear(rig, g1, twisted_plan):
    robot, emu = rig(twisted_plan)
    report = robot.exchange(0.0, kind="enter")
    assert report.complete and report.kind == "enter"
    truth = emu.robot
    assert np.allclose(robot.joint_positions(), truth.joint_positions(), atol=2e-3)
    robot.set_joint_impedance(pd_hold_command(g1))
    hold(robot, 100)
    names = g1.joint_names
    twisted = [names.index(j) for j in TWISTED]
    assert np.allclose(robot.joint_positions(), truth.joint_positions(), atol=2e-3)
    assert np.allclose(robot.joint_velocities(), truth.joint_velocities(), atol=0.05)
    assert np.allclose(robot.joint_efforts(), truth.joint_efforts(), atol=0.5)
    applied = emu._impedance  # what MuJoCo evaluates, joint side
    assert np.allclose(applied.q_ref[twisted], g1.default_positions[twisted], atol=2e-3)
    kp = np.minimum(g1.kp, [m.model.kp.max * m.gear_ratio**2 for m in (twisted_plan.motor(j)[1] for j in names)])
    assert np.allclose(applied.kp, kp, rtol=0.01, atol=0.6)
    for joint, (sign, gear, offset) in TWISTED.items():
        i = emu.motor_index(joint)
        q = g1.default_positions[names.index(joint)]
        assert emu.command[i, 0] == pytest.approx(sign * gear * (q - offset), abs=1e-3)  # motor side, on the wire


def test_torque_commands_go_out_as_zero_gain_impedance_frames(rig, g1, twisted_plan):
    robot, emu = rig(twisted_plan)
    robot.exchange(0.0, kind="enter")
    tau = np.linspace(-3.0, 3.0, g1.dofs)
    robot.set_joint_torques(tau)
    assert robot.command.kp.max() == 0.0 and robot.command.kd.max() == 0.0
    robot.exchange(DT)
    p, v, kp, kd, torque = emu.command.T
    assert (kp == 0).all() and (kd == 0).all()
    expected = emu.group.sign * tau[emu.joint_index] / emu.group.gear
    assert np.allclose(torque, expected, atol=0.1)
    assert np.allclose(emu._impedance.tau_ff, tau, atol=0.2)
    big = np.full(g1.dofs, 1e4)
    robot.set_joint_torques(big)
    assert np.allclose(robot.command.tau_ff, g1.effort_limits)  # clipped to the effort limits


def test_one_call_encoder_matches_each_buses_protocol(rig, g1, rng):
    robot, _ = rig()
    n = len(robot.motors)
    values = [rng.uniform(-30, 30, n), rng.uniform(-60, 60, n), rng.uniform(-10, 600, n), rng.uniform(-1, 7, n), rng.uniform(-250, 250, n)]
    batch, clamped = robot.codec.encode_commands(*values)
    start = 0
    for link in robot.links:
        k = len(link.protocol.motors)
        expected = link.protocol.encode_commands(*(v[start : start + k] for v in values))
        assert np.array_equal(batch["data"][start : start + k], expected.data)
        assert np.array_equal(batch["can_id"][start : start + k], expected.arbitration_ids)
        assert np.array_equal(clamped[start : start + k], expected.clamped)
        start += k


def test_clamped_fields_are_counted(rig, g1):
    robot, _ = rig()
    knee = g1.joint_names.index("left_knee_joint")
    command = pd_hold_command(g1)
    command.kd[knee] = 6.0  # beyond the DM10010's KD range (5)
    robot.exchange(0.0, kind="enter")
    robot.set_joint_impedance(command)
    report = robot.exchange(DT)
    assert report.clamped == 1
    assert robot.clamp_counts[knee, 3] == 1 and robot.clamp_counts[knee, 2] == 0


def test_missing_replies_hold_the_last_state_and_count(rig, g1):
    robot, emu = rig(faults=(FaultInjection("drop", ("left_knee_joint",), start=0.01),))
    knee = g1.joint_names.index("left_knee_joint")
    robot.exchange(0.0, kind="enter")
    robot.set_joint_impedance(pd_hold_command(g1))
    hold(robot, 4)
    last = robot.joint_positions()[knee]
    stale = []
    for k in range(5, 12):
        report = robot.exchange(k * DT)
        stale.append(int(report.stale[knee]))
        assert report.missing.sum() == (1 if k * DT >= 0.01 else 0)
    assert stale == [1, 2, 3, 4, 5, 6, 7]
    assert robot.joint_positions()[knee] == last


def test_late_replies_are_drained_never_taken_as_this_cycles(rig, g1):
    robot, emu = rig(faults=(FaultInjection("delay", ("right_ankle_roll_joint",), start=0.005, delay=0.001),))
    j = g1.joint_names.index("right_ankle_roll_joint")
    robot.exchange(0.0, kind="enter")
    robot.set_joint_impedance(pd_hold_command(g1))
    reports = [robot.exchange(k * DT) for k in range(1, 10)]
    delayed = [r for r in reports if r.time >= 0.005]
    assert all(r.missing[j] and r.missing.sum() == 1 for r in delayed)
    assert [r.late for r in delayed[1:]] == [1] * (len(delayed) - 1)  # each arrives a cycle late
    assert robot.late_frames == len(delayed) - 1
    assert [int(r.stale[j]) for r in delayed] == list(range(1, len(delayed) + 1))


def test_imu_from_the_channel_and_base_state_only_from_an_estimator(rig, g1):
    robot, emu = rig()
    with pytest.raises(RuntimeError):
        robot.imu()  # nothing read yet
    robot.exchange(0.0, kind="enter")
    assert robot.imu() is emu.imu_channel.read()
    with pytest.raises(BaseStateUnavailable):
        robot.base_state()
    with pytest.raises(BaseStateUnavailable):
        robot.generalized_state()

    with pytest.raises(BaseStateUnavailable):
        robot.link_pose(g1.base_link)
    with pytest.raises(BaseStateUnavailable):
        robot.contact_wrench(g1.contacts[0].link)

    # The base state comes from the estimator wrapped around the CAN robot, updated after every
    # exchange that brought a new IMU sample (as the real-time runtime does).
    can_robot, emu = rig()
    robot = EstimatedRobot(can_robot, StateEstimator(g1))
    assert robot.unwrapped is can_robot and robot.latest_estimate is None
    robot.update(fuse=can_robot.exchange(0.0, kind="enter").imu_fresh)
    robot.set_joint_impedance(pd_hold_command(g1))
    for k in range(1, 101):
        report = can_robot.exchange(k * DT)
        assert report.imu_fresh  # lockstep: the emulator publishes a sample every cycle
        robot.update(fuse=report.imu_fresh)
    assert robot.latest_estimate.time == pytest.approx(emu.imu_channel.read().time)
    stale = robot.latest_estimate
    robot.update(fuse=False)  # no new sample: nothing fused, no stale-timestamp fault
    assert robot.latest_estimate is stale and robot.estimate.time == stale.time
    assert robot.estimator.fault_counts.get("STALE_TIMESTAMP", 0) == 0
    base, truth = robot.base_state(), emu.robot.base_state()
    assert np.allclose(base.position, truth.position, atol=0.02)
    assert abs(float(base.quaternion @ truth.quaternion)) == pytest.approx(1.0, abs=1e-3)
    q, v = robot.generalized_state()
    assert q.shape == (7 + g1.dofs,) and np.allclose(q[7:], robot.joint_positions())
    pos, rot = robot.link_pose(g1.base_link)
    assert np.allclose(pos, base.position, atol=1e-9)
    assert robot.contact_wrench(g1.contacts[0].link).in_contact


def test_non_finite_and_malformed_commands_are_refused(rig, g1):
    robot, _ = rig()
    held = robot.command
    bad = pd_hold_command(g1)
    bad.tau_ff[3] = np.nan
    with pytest.raises(NonFiniteCommand):
        robot.set_joint_impedance(bad)
    with pytest.raises(NonFiniteCommand):
        robot.set_joint_torques(np.full(g1.dofs, np.inf))
    with pytest.raises(ValueError):
        robot.set_joint_impedance(ImpedanceCommand.damping(3, 1.0))
    with pytest.raises(ValueError):
        robot.set_joint_impedance(ImpedanceCommand.damping(g1.dofs, -1.0))
    assert robot.command is held


def test_imu_sources_and_fast_messages():
    with pytest.raises(ValueError, match="emulate"):
        imu_source_for(ImuConfig("emulated"))
    with pytest.raises(HardwareConfigError, match="cannot open the serial IMU at '/dev/nonexistent-giwbc-imu'"):
        imu_source_for(ImuConfig("serial", device="/dev/nonexistent-giwbc-imu"))
    msg = fast_message(0x12, b"\x01\x02\x03")
    clone = copy.deepcopy(msg)
    assert isinstance(clone, FastMessage) and clone is not msg and clone.data is not msg.data
    assert clone.equals(msg) and (clone.dlc, clone.is_extended_id, clone.is_rx) == (3, False, True)


def test_block_conversions_equal_the_per_field_ones(twisted_plan, rng):
    from giwbc.hal.motor import MotorGroup

    group = MotorGroup(twisted_plan.motors)
    n = len(group)
    rows = rng.normal(size=(5, n))
    motor = group.commands_to_motor(rows.copy())
    assert np.allclose(motor, np.array(group.command_to_motor(*rows)), rtol=1e-15, atol=1e-15)
    states = rng.normal(size=(n, 3))
    assert np.allclose(group.states_to_joint(states), np.array(group.state_to_joint(*states.T)).T, rtol=1e-15, atol=1e-15)
    some = np.array([3, 0, 7])
    assert np.allclose(group.states_to_joint(states[some], some), np.array(group.state_to_joint(*states.T)).T[some], rtol=1e-15, atol=1e-15)
