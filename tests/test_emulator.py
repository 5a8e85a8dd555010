"""The actuator emulator: one reply per frame in the motor's variant, the motor-mode state machine,
the watchdog, the thermal model, injected faults, and its vectorized codec against the protocol."""

from __future__ import annotations

import copy
import math

import can
import numpy as np
import pytest

from giwbc.emulation import (
    MOTOR,
    OFF,
    OVER_CURRENT,
    OVER_TEMPERATURE,
    ActuatorEmulator,
    EmulatorConfig,
    FaultInjection,
    Gantry,
    ThermalModel,
)
from giwbc.emulation.firmware import MitFirmwareCodec
from giwbc.hal.hardware import load_hardware
from giwbc.hal.motor import MOTOR_PRESETS, MotorConfig
from giwbc.hal.protocols import MitProtocol
from giwbc.hal.protocols.mit import REPLY_VARIANTS
from giwbc.robot.noise import SensorNoiseConfig

DT = 0.002


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


@pytest.fixture(scope="module")
def plan(g1):
    return load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")


class Host:
    """The host side of an emulator's buses, raw: send frames, collect replies."""

    def __init__(self, emulator: ActuatorEmulator) -> None:
        self.emulator = emulator
        self.plan = emulator.host_plan()
        self.buses = [b.open() for b in self.plan.buses]
        self.protocols = [b.make_protocol() for b in self.plan.buses]

    def where(self, joint: str) -> tuple[int, int]:
        for b, bus in enumerate(self.plan.buses):
            for m in bus.motors:
                if m.joint == joint:
                    return b, m.can_id
        raise KeyError(joint)

    def send(self, b: int, frame) -> None:
        self.buses[b].send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False))

    def special(self, kind: str, joints=None) -> None:
        for b, (bus, p) in enumerate(zip(self.plan.buses, self.protocols)):
            for m in bus.motors:
                if joints is None or m.joint in joints:
                    self.send(b, getattr(p, {"enter": "enter_motor_mode", "exit": "exit_motor_mode", "zero": "set_zero"}[kind])(m.can_id))

    def command(self, joint: str, position=0.0, velocity=0.0, kp=0.0, kd=0.0, torque=0.0) -> None:
        b, motor_id = self.where(joint)
        self.send(b, self.protocols[b].encode_command(motor_id, position, velocity, kp, kd, torque).frame)

    def command_all(self, **values) -> None:
        for b, p in enumerate(self.protocols):
            batch = p.encode_commands(values.get("position", 0.0), values.get("velocity", 0.0), values.get("kp", 0.0),
                                      values.get("kd", 0.0), values.get("torque", 0.0))  # fmt: skip
            for f in batch.frames():
                self.send(b, f)

    def replies(self) -> list[list[can.Message]]:
        out = []
        for bus in self.buses:
            got = []
            while (msg := bus.recv(timeout=0.0)) is not None:
                got.append(msg)
            out.append(got)
        return out

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()
        self.emulator.close()


@pytest.fixture
def rig(g1, plan, model):
    made: list[Host] = []

    def make(**config) -> Host:
        host = Host(ActuatorEmulator(plan, g1, EmulatorConfig(**config), model=copy.copy(model)))
        made.append(host)
        return host

    yield make
    for host in made:
        host.close()


def test_one_reply_per_frame_in_each_motors_variant(rig):
    host = rig()
    host.command_all()  # motors are off: answered all the same
    host.emulator.poll(0.0)
    replies = host.replies()
    for bus, protocol, got in zip(host.plan.buses, host.protocols, replies):
        assert len(got) == len(bus.motors)
        decoded = {}
        for msg in got:
            r = protocol.decode(msg.arbitration_id, bytes(msg.data))
            motor = protocol.motor(r.motor_id)
            assert len(msg.data) == REPLY_VARIANTS[motor.reply].length
            decoded[r.motor_id] = r
        assert sorted(decoded) == sorted(m.can_id for m in bus.motors)
        for m in bus.motors:
            if m.reply == "damiao":
                assert decoded[m.can_id].status == 0  # disabled
            if m.reply in ("damiao", "cubemars"):
                assert decoded[m.can_id].temperature == pytest.approx(25.0, abs=1.0)
                assert decoded[m.can_id].error_code == 0
    variants = {m.reply for m in host.plan.motors}
    assert variants == {"damiao", "cubemars"}  # the G1 plan mixes both: both were exercised

    host.command("left_knee_joint")
    host.command("left_knee_joint")
    host.emulator.poll(DT)
    assert sum(len(r) for r in host.replies()) == 2  # two frames, two replies
    assert host.emulator.counters.replies.sum() == 31


def test_state_machine_off_enter_motor_exit(rig, g1):
    host = rig()
    emu = host.emulator
    knee = g1.joint_names.index("left_knee_joint")
    k = emu.motor_index("left_knee_joint")
    host.command("left_knee_joint", position=1.0, kp=100.0)
    emu.poll(0.0)
    assert emu.mode[k] == OFF and emu.counters.commands[k] == 0
    assert emu.limp()[k] and emu.robot.model.actuator_biasprm[knee, 1] == 0.0  # no stiffness when off

    host.replies()
    host.special("enter")
    emu.poll(DT)
    assert (emu.mode == MOTOR).all()
    assert sum(len(r) for r in host.replies()) == len(emu.motors)  # enter frames are answered too
    b, _ = host.where("left_knee_joint")
    host.command("left_knee_joint", position=1.0, kp=100.0, kd=2.0)
    emu.poll(2 * DT)
    assert emu.counters.commands[k] == 1
    assert emu.command[k, 0] == pytest.approx(1.0, abs=1e-3) and emu.command[k, 2] == pytest.approx(100.0, abs=0.2)
    assert not emu.limp()[k]
    assert emu.robot.model.actuator_biasprm[knee, 1] == pytest.approx(-100.0, abs=0.2)

    host.special("exit", ["left_knee_joint"])
    emu.poll(3 * DT)
    assert emu.mode[k] == OFF and emu.limp()[k]
    assert (emu.mode[np.arange(len(emu.motors)) != k] == MOTOR).all()
    host.replies()
    host.command("left_knee_joint", position=1.0, kp=100.0)
    emu.poll(4 * DT)
    assert emu.counters.commands[k] == 1  # ignored while off, but answered:
    (reply,) = [m for m in host.replies()[b]]
    assert host.protocols[b].decode(reply.arbitration_id, bytes(reply.data)).status == 0


def test_set_zero_only_when_off(rig, g1):
    host = rig()
    emu = host.emulator
    b, motor_id = host.where("left_knee_joint")
    host.special("zero", ["left_knee_joint"])
    emu.poll(0.0)
    host.replies()
    host.command("left_knee_joint")
    emu.poll(DT)
    (msg,) = host.replies()[b]
    assert host.protocols[b].decode(msg.arbitration_id, bytes(msg.data)).position == pytest.approx(0.0, abs=2e-3)
    q_knee = emu.robot.joint_positions()[g1.joint_names.index("left_knee_joint")]
    assert abs(q_knee) > 0.1  # the joint is bent: position 0 comes from the new zero

    host.special("enter", ["left_hip_pitch_joint"])
    emu.poll(2 * DT)
    before = emu.zero.copy()
    host.special("zero", ["left_hip_pitch_joint"])
    emu.poll(3 * DT)
    assert np.array_equal(emu.zero, before)  # ignored in motor mode


def test_watchdog_goes_limp_then_resumes(rig, g1):
    host = rig(watchdog_timeout=0.05, limp_kd=0.7, record=True)
    emu = host.emulator
    k = emu.motor_index("left_elbow_joint")
    host.special("enter")
    emu.poll(0.0)
    host.command_all(kp=20.0, kd=1.0)
    emu.poll(DT)
    assert not emu.limp().any()
    t = DT
    while t < 0.045:
        t += DT
        emu.poll(t)
    assert not emu.timed_out.any()
    while t < 0.06:
        t += DT
        emu.poll(t)
    assert emu.timed_out.all() and emu.limp().all()
    snap = emu.snapshots[-1]
    assert (snap.kp == 0).all() and np.allclose(snap.kd, 0.7) and (snap.tau_ff == 0).all()
    host.command("left_elbow_joint", kp=20.0, kd=1.0)
    emu.poll(t + DT)
    assert not emu.timed_out[k] and not emu.limp()[k]
    assert emu.limp().sum() == len(emu.motors) - 1


def test_thermal_model_heats_with_torque_squared_and_cools():
    th = ThermalModel(ambient=25.0, time_constant=10.0, rated_rise=40.0, rated_fraction=0.5)
    k = th.heating(np.array([20.0]))  # rated torque 10 N m
    zero = np.zeros(1)
    hot = th.step(np.array([25.0]), np.array([10.0]), 1e4, k, zero)
    assert hot[0] == pytest.approx(65.0)  # steady state: rated rise at rated torque
    one_tau = th.step(np.array([25.0]), np.array([10.0]), 10.0, k, zero)
    assert one_tau[0] == pytest.approx(25.0 + 40.0 * (1 - math.exp(-1)))
    double = th.step(np.array([25.0]), np.array([20.0]), 1e4, k, zero)
    assert double[0] - 25.0 == pytest.approx(4 * 40.0)  # torque squared
    cooled = th.step(hot, zero, 10.0, k, zero)
    assert cooled[0] == pytest.approx(25.0 + 40.0 * math.exp(-1))


def test_emulated_motor_heats_under_torque_and_trips(rig, g1):
    thermal = ThermalModel(time_constant=2.0, rated_rise=40.0, trip=90.0)
    host = rig(thermal=thermal)
    emu = host.emulator
    hot, cold = emu.motor_index("left_shoulder_roll_joint"), emu.motor_index("right_shoulder_roll_joint")
    host.special("enter")
    emu.poll(0.0)
    t = 0.0
    for _ in range(100):  # 0.2 s with 10 N m on one shoulder, nothing on the other
        host.command("left_shoulder_roll_joint", torque=10.0)
        host.command("right_shoulder_roll_joint")
        t += DT
        emu.poll(t)
    rise = emu.temperature[hot] - 25.0
    expected = emu._heating[hot] * 10.0**2 * thermal.time_constant * (1 - math.exp(-t / thermal.time_constant))
    assert rise == pytest.approx(expected, rel=0.05)
    assert emu.temperature[cold] == pytest.approx(25.0, abs=1e-3)  # a zero command quantizes to ~6 mN m
    peak = emu.temperature[hot]
    for _ in range(100):
        host.command("left_shoulder_roll_joint")
        t += DT
        emu.poll(t)
    assert emu.temperature[hot] < peak  # cools without torque

    emu.add_fault(FaultInjection("overheat", ("left_knee_joint",), start=t, heat_rate=2000.0))
    knee = emu.motor_index("left_knee_joint")
    for _ in range(40):
        t += DT
        emu.poll(t)
    assert emu.temperature[knee] > thermal.trip
    assert emu.error[knee] == OVER_TEMPERATURE["damiao"] and emu.limp()[knee]
    host.replies()
    host.command("left_knee_joint")
    emu.poll(t + DT)
    b, _ = host.where("left_knee_joint")
    (msg,) = host.replies()[b]
    r = host.protocols[b].decode(msg.arbitration_id, bytes(msg.data))
    assert r.error_code == 0xC and r.rotor_temperature > thermal.trip


def test_injected_error_code_latches_until_cleared(rig):
    host = rig()
    emu = host.emulator
    elbow, knee = emu.motor_index("left_elbow_joint"), emu.motor_index("left_knee_joint")
    emu.add_fault(FaultInjection("error", ("left_elbow_joint", "left_knee_joint"), start=0.01, stop=0.02))
    host.special("enter")
    t = 0.0
    emu.poll(t)
    while t < 0.012:
        t += DT
        host.command_all()
        emu.poll(t)
    assert emu.error[elbow] == OVER_CURRENT["cubemars"] and emu.error[knee] == OVER_CURRENT["damiao"]
    replies = {m.joint: None for m in host.plan.motors}
    for b, got in enumerate(host.replies()):
        for msg in got:
            r = host.protocols[b].decode(msg.arbitration_id, bytes(msg.data))
            replies[host.protocols[b].motor(r.motor_id).joint] = r
    assert replies["left_elbow_joint"].error_code == 2 and replies["left_knee_joint"].error_code == 0xA
    assert replies["left_hip_pitch_joint"].error_code == 0
    while t < 0.03:  # the cause is gone, but the error stays latched
        t += DT
        host.command_all()
        emu.poll(t)
    assert emu.error[elbow] and emu.error[knee]
    host.special("exit", ["left_elbow_joint"])
    emu.poll(t + DT)
    assert emu.error[elbow] == 0 and emu.error[knee] != 0


def test_reply_faults_are_seeded_and_behave(rig):
    def run(seed: int, faults) -> ActuatorEmulator:
        host = rig(seed=seed, faults=faults)
        host.special("enter")
        host.emulator.poll(0.0)
        for k in range(1, 121):
            host.command_all()
            host.emulator.poll(k * DT)
            host.replies()
        return host.emulator

    drop = (FaultInjection("drop", probability=0.3),)
    a, b, c = run(1, drop), run(1, drop), run(2, drop)
    assert np.array_equal(a.counters.dropped, b.counters.dropped)
    assert not np.array_equal(a.counters.dropped, c.counters.dropped)
    assert a.counters.dropped.sum() / a.counters.frames.sum() == pytest.approx(0.3, abs=0.03)

    after = 0.001  # the enter frames at t = 0 are answered normally
    host = rig(faults=(
        FaultInjection("corrupt", ("left_knee_joint",), start=after), FaultInjection("delay", ("right_knee_joint",), start=after, delay=0.001),
        FaultInjection("silent", ("waist_yaw_joint",), start=after), FaultInjection("dead", ("left_elbow_joint",), start=after),
    ))  # fmt: skip
    emu = host.emulator
    host.special("enter")
    emu.poll(0.0)
    host.replies()
    host.command_all(kp=10.0)
    emu.poll(DT)
    ids = {}
    for b, got in enumerate(host.replies()):
        for msg in got:
            try:
                r = host.protocols[b].decode(msg.arbitration_id, bytes(msg.data))
            except Exception:  # noqa: BLE001
                ids.setdefault("corrupt", []).append(b)
                continue
            ids.setdefault(host.protocols[b].motor(r.motor_id).joint, []).append(r)
    assert "left_knee_joint" not in ids and ids["corrupt"] == [host.where("left_knee_joint")[0]]
    for joint in ("right_knee_joint", "waist_yaw_joint", "left_elbow_joint"):
        assert joint not in ids
    assert len(ids) == len(emu.motors) - 4 + 1
    emu.poll(2 * DT)  # the delayed reply is released once due
    (late,) = host.replies()[host.where("right_knee_joint")[0]]
    assert host.protocols[host.where("right_knee_joint")[0]].decode(late.arbitration_id, bytes(late.data)).motor_id
    silent, dead = emu.motor_index("waist_yaw_joint"), emu.motor_index("left_elbow_joint")
    assert emu.counters.commands[silent] == 1 and not emu.limp()[silent]  # silent: still obeys
    assert emu.limp()[dead] and emu.counters.commands[dead] == 0  # dead: limp, deaf


def test_imu_comes_from_mujoco_at_emulator_time_and_the_gantry_holds(rig):
    host = rig(gantry=Gantry(until=0.5))  # motors off: only the harness holds the robot
    emu = host.emulator
    z0 = emu.robot.base_state().position[2]
    for k in range(200):
        emu.poll(k * DT)
    reading = emu.imu_channel.read()
    assert reading.time == pytest.approx(emu.time) == pytest.approx(199 * DT)
    assert np.linalg.norm(reading.quaternion) == pytest.approx(1.0)
    assert np.linalg.norm(reading.linear_acceleration) == pytest.approx(9.81, abs=0.3)  # hanging still: gravity
    assert emu.robot.base_state().position[2] == pytest.approx(z0, abs=0.02)
    assert np.degrees(emu.truth[-1][2]) < 2.0
    for k in range(200, 800):
        emu.poll(k * DT)
    assert not emu.robot.data.xfrc_applied.any()  # released
    assert emu.robot.base_state().position[2] < z0 - 0.05  # limp: it sinks


def test_a_mems_imu_profile_publishes_gyro_and_accelerometer_with_its_drawn_errors(rig):
    """The ``mems`` profile: no orientation output (NaN quaternion), the turn-on gyro bias drawn from
    the seed in every sample (the robot hangs still in the gantry), 2 samples of latency, about 1 %
    of samples dropped (repeated); the same seed draws the same bias."""
    mems = SensorNoiseConfig.profile("mems")
    host = rig(gantry=Gantry(until=5.0), imu=mems, seed=3)
    emu = host.emulator
    assert np.abs(emu.imu_errors.gyro_bias).max() > 0.1 * mems.gyro_bias  # drawn, not zero
    readings, truth = [], []
    for k in range(1, 1501):
        emu.poll(k * DT)
        readings.append(emu.imu_channel.read())
        truth.append(emu.robot.imu().angular_velocity)
    assert all(np.isnan(r.quaternion).all() for r in readings)
    gyro = np.array([r.angular_velocity for r in readings[250:]])
    error = gyro.mean(axis=0) - np.mean(truth[250:], axis=0)  # the limp legs sway the hanging base a little
    np.testing.assert_allclose(error, emu.imu_gyro_bias, atol=0.002)  # noise 0.011/sample, 1250 samples
    times = np.array([r.time for r in readings])
    lag = np.median(np.arange(1, 1501) * DT - times)
    assert lag == pytest.approx(2 * DT, abs=0.2 * DT)  # two samples late (jitter aside)
    repeats = np.mean(np.diff(times) == 0.0)
    assert 0.003 < repeats < 0.025  # ~1 % dropouts
    again = rig(gantry=Gantry(until=5.0), imu=mems, seed=3).emulator
    np.testing.assert_array_equal(again.imu_errors.gyro_bias, emu.imu_errors.gyro_bias)


def test_vectorized_codec_matches_the_protocol(rng):
    presets = MOTOR_PRESETS
    motors = [
        MotorConfig(1, presets["MINI-CHEETAH"], "a", reply="original"),
        MotorConfig(2, presets["AK80-9"], "b", reply="voltage"),
        MotorConfig(3, presets["AK70-10"], "c", reply="cubemars"),
        MotorConfig(4, presets["DM8009"], "d", reply="damiao"),
    ]
    protocol = MitProtocol(motors, host_id=0x7F)
    codec = MitFirmwareCodec([protocol], motors)
    index = rng.integers(0, 4, 200)
    frames, expected = [], []
    for i in index:
        lo = np.array([r.min for r in motors[i].model.ranges])
        hi = np.array([r.max for r in motors[i].model.ranges])
        values = rng.uniform(lo - 1, hi + 1)
        frame = protocol.encode_command(motors[i].can_id, *values).frame
        frames.append(frame.data)
        expected.append(protocol.decode_command(motors[i].can_id, frame.data))
    special, values = codec.decode_commands(index, b"".join(frames))
    assert special == [None] * 200
    assert np.array_equal(values, np.array([[e.position, e.velocity, e.kp, e.kd, e.torque] for e in expected]))
    special, values = codec.decode_commands(np.array([0, 3]), protocol.enter_motor_mode(1).data + protocol.exit_motor_mode(4).data)
    assert special == ["enter", "exit"] and np.isnan(values).all()

    n = 300
    index = rng.integers(0, 4, n)
    p, v, t = rng.uniform(-20, 20, n), rng.uniform(-80, 80, n), rng.uniform(-70, 70, n)
    temp, mos = rng.uniform(-50, 300, n), rng.uniform(-50, 300, n)
    error = rng.integers(0, 20, n)
    status = np.where(error != 0, np.minimum(error, 15), rng.integers(0, 2, n))
    data, lengths, arb = codec.encode_replies(index, p, v, t, temp, mos, error, status)
    for k, i in enumerate(index):
        m = motors[i]
        frame = protocol.encode_reply(
            m.can_id, p[k], v[k], t[k], temperature=mos[k] if m.reply == "damiao" else temp[k], rotor_temperature=temp[k],
            error_code=int(error[k]), status=int(status[k]),
        )  # fmt: skip
        assert bytes(data[k, : lengths[k]]) == frame.data, (m.reply, k)
        assert arb[k] == frame.arbitration_id
