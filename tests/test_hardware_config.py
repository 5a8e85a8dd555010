"""Motor configuration (presets, overrides, joint <-> motor maps) and hardware.toml plans."""

from __future__ import annotations

import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from giwbc.hal.hardware import HardwareConfigError, load_hardware, parse_hardware, validate_joints
from giwbc.hal.motor import MOTOR_PRESETS, MotorConfig, MotorGroup, Range, motor_preset

ROOT = Path(__file__).resolve().parents[1]
G1_HARDWARE = ROOT / "robots" / "g1" / "hardware.toml"

G1_JOINTS = """
left_hip_pitch_joint left_hip_roll_joint left_hip_yaw_joint left_knee_joint left_ankle_pitch_joint left_ankle_roll_joint
right_hip_pitch_joint right_hip_roll_joint right_hip_yaw_joint right_knee_joint right_ankle_pitch_joint
right_ankle_roll_joint waist_yaw_joint waist_roll_joint waist_pitch_joint
left_shoulder_pitch_joint left_shoulder_roll_joint left_shoulder_yaw_joint left_elbow_joint
left_wrist_roll_joint left_wrist_pitch_joint left_wrist_yaw_joint
right_shoulder_pitch_joint right_shoulder_roll_joint right_shoulder_yaw_joint right_elbow_joint
right_wrist_roll_joint right_wrist_pitch_joint right_wrist_yaw_joint
""".split()


def g1_effort(joint: str) -> float:
    """The brief's G1 joint effort limits (N m)."""
    for key, limit in (
        ("hip_roll", 139), ("knee", 139), ("hip", 88), ("ankle", 35), ("waist_yaw", 88), ("waist", 35),
        ("wrist_pitch", 5), ("wrist_yaw", 5), ("shoulder", 25), ("elbow", 25), ("wrist_roll", 25),
    ):  # fmt: skip
        if key in joint:
            return float(limit)
    raise KeyError(joint)


# ------------------------------------------------------------------------------ motors
def test_presets_are_frozen_and_well_formed():
    with pytest.raises(TypeError):
        MOTOR_PRESETS["X"] = MOTOR_PRESETS["AK80-9"]  # type: ignore[index]
    ak = motor_preset("AK80-9")
    assert (ak.position, ak.velocity, ak.kp, ak.kd, ak.torque) == (
        Range(-12.5, 12.5), Range(-50, 50), Range(0, 500), Range(0, 5), Range(-18, 18)
    )
    assert motor_preset("DM8009").torque == Range(-54, 54) and motor_preset("DM4310").reply == "damiao"
    for m in MOTOR_PRESETS.values():
        assert all(r.min < r.max for r in m.ranges)
    with pytest.raises(ValueError, match="unknown motor model preset 'AK80-99'"):
        motor_preset("AK80-99")


def test_overrides_field_by_field():
    base = motor_preset("AK80-9")
    m = base.with_overrides(torque=30.0, kp=200, velocity={"min": -10, "max": 20}, position=[-3, 3])
    assert m.torque == Range(-30, 30) and m.kp == Range(0, 200)
    assert m.velocity == Range(-10, 20) and m.position == Range(-3, 3) and m.kd == base.kd
    with pytest.raises(ValueError, match="min 5.0 must be < max -5.0"):
        base.with_overrides(torque=[5.0, -5.0])
    with pytest.raises(ValueError, match="below 0"):
        base.with_overrides(kd=[-1, 5])
    with pytest.raises(ValueError, match="unknown motor model field"):
        base.with_overrides(tmax=3)


def test_joint_motor_conversions():
    m = MotorConfig(1, motor_preset("AK80-9"), "j", sign=-1, zero_offset=0.3, gear_ratio=2.0)
    # q = sign * p / gear + offset
    assert m.position_to_joint(1.0) == pytest.approx(-0.5 + 0.3)
    assert m.position_to_motor(0.3) == 0.0
    assert m.position_to_motor(m.position_to_joint(2.7)) == pytest.approx(2.7)
    assert m.velocity_to_motor(1.0) == -2.0 and m.velocity_to_joint(-2.0) == 1.0
    # torque scales up by the gear on the way to the joint
    assert m.torque_to_joint(3.0) == -6.0 and m.torque_to_motor(-6.0) == 3.0
    assert m.gains_to_motor(40.0, 2.0) == (10.0, 0.5)
    assert m.joint_effort_limit == 36.0
    g = MotorGroup([m, MotorConfig(2, motor_preset("DM4310"), "k")])
    p, v, kp, kd, t = g.command_to_motor([0.5, 0.5], [1.0, 1.0], [40.0, 40.0], [2.0, 2.0], [6.0, 6.0])
    np.testing.assert_allclose(p, [m.position_to_motor(0.5), 0.5])
    np.testing.assert_allclose(t, [-3.0, 6.0])
    np.testing.assert_allclose(kp, [10.0, 40.0])
    q, dq, tau = g.state_to_joint(p, v, t)
    np.testing.assert_allclose(q, [0.5, 0.5])
    np.testing.assert_allclose(dq, [1.0, 1.0])
    np.testing.assert_allclose(tau, [6.0, 6.0])
    for bad in (dict(sign=0), dict(sign=True), dict(gear_ratio=0.0), dict(zero_offset=float("nan"))):
        with pytest.raises(ValueError):
            MotorConfig(1, motor_preset("AK80-9"), "j", **bad)


# ------------------------------------------------------------------------------ G1 plan
def test_g1_plan_matches_robot_and_effort_limits():
    robot_joints = list(tomllib.loads((ROOT / "robots" / "g1" / "robot.toml").read_text())["joints"])
    assert robot_joints == G1_JOINTS
    limits = {j: g1_effort(j) for j in G1_JOINTS}
    plan = load_hardware(G1_HARDWARE, joint_names=G1_JOINTS, effort_limits=limits)
    assert plan.control_rate == 500.0
    assert sorted(plan.joints) == sorted(G1_JOINTS) and len(plan.motors) == 29
    assert all(b.bitrate == 1_000_000 and b.interface == "socketcan" for b in plan.buses)
    assert [b.channel for b in plan.buses] == [f"can{i}" for i in range(len(plan.buses))]
    routing = plan.routing(G1_JOINTS)
    for joint, (bus, i) in zip(G1_JOINTS, routing):
        assert plan.bus(bus).motors[i].joint == joint
    # large / medium / small models as planned
    assert plan.motor("left_knee_joint")[1].model.name == "DM10010"
    assert plan.motor("right_ankle_roll_joint")[1].model.name == "DM8009"
    assert plan.motor("left_elbow_joint")[1].model.name == "AK70-10"
    assert plan.motor("right_wrist_yaw_joint")[1].model.name == "DM4310"


@pytest.mark.parametrize("rate", [500.0, 1000.0])
def test_g1_plan_fits_at_500hz_and_1khz(rate):
    plan = load_hardware(G1_HARDWARE, rate)
    assert set(plan.loads) == {b.name for b in plan.buses}
    for load in plan.loads.values():
        assert load.nominal <= 0.8 and load.worst_case <= 1.0


def test_g1_plan_refused_at_2khz_with_the_load_named():
    with pytest.raises(HardwareConfigError) as e:
        load_hardware(G1_HARDWARE, 2000.0)
    msg = str(e.value)
    assert str(G1_HARDWARE) in msg and "'can0'" in msg and "133.2%" in msg and "80%" in msg


def test_g1_dry_run_on_virtual_buses():
    plan = load_hardware(G1_HARDWARE, interface="virtual")
    assert {b.interface for b in plan.buses} == {"virtual"}
    assert plan.with_interface("socketcan").buses[0].interface == "socketcan"
    bus_cfg = plan.bus("can6")  # mixed AK70-10 (CubeMars replies) and DM4310 (Damiao replies)
    import can

    with bus_cfg.open_link() as link, can.Bus(interface="virtual", channel=bus_cfg.channel) as motors:
        p = link.protocol
        for m in bus_cfg.motors:
            f = p.encode_reply(m.can_id, 0.25, 0.0, 1.0)
            motors.send(can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False))
        res = link.exchange(p.encode_commands(0, 0, 0, 0, 0), deadline=time.perf_counter() + 0.5)
        assert res.complete and res.counters.sent == 3
        assert {r.motor_id for r in res.replies.values()} == {m.can_id for m in bus_cfg.motors}


# -------------------------------------------------------------------------- config errors
BUSES = """
[[buses]]
name = "a"
interface = "socketcan"
channel = "can0"
bitrate = 1000000

[[buses]]
name = "b"
interface = "socketcan"
channel = "can1"
bitrate = 1000000
"""
IMU = '\n[imu]\nsource = "emulated"\n'


def motor_toml(bus: str = "a", id: int = 1, joint: str = "j1", model: str = "AK80-9", **extra: str) -> str:
    lines = [f'bus = "{bus}"', f"id = {id}", f'joint = "{joint}"', f'model = "{model}"']
    lines += [f"{k} = {v}" for k, v in extra.items()]
    return "\n[[motors]]\n" + "\n".join(lines) + "\n"


def write(tmp_path: Path, *motors: str, buses: str = BUSES, imu: str = IMU) -> Path:
    p = tmp_path / "hardware.toml"
    p.write_text(buses + "".join(motors) + imu)
    return p


def test_small_valid_file(tmp_path):
    path = write(
        tmp_path,
        motor_toml(id=1, joint="j1", torque="30.0", sign="-1", zero_offset="0.5", gear_ratio="2.0"),
        motor_toml(bus="b", id=1, joint="j2", model="DM4310", reply='"damiao"'),
    )
    plan = load_hardware(path, 1000.0, joint_names=["j2", "j1"])
    bus, m = plan.motor("j1")
    assert bus.name == "a" and m.model.torque == Range(-30, 30) and m.model.name == "AK80-9"
    assert (m.sign, m.zero_offset, m.gear_ratio, m.reply) == (-1, 0.5, 2.0, "cubemars")
    assert plan.motor("j2")[1].reply == "damiao"
    assert plan.routing(["j2", "j1"]) == (("b", 0), ("a", 0))
    assert plan.imu.source == "emulated"


@pytest.mark.parametrize(
    "motors, match",
    [
        ((motor_toml(bus="nope"),), "unknown bus 'nope'"),
        ((motor_toml(id=5), motor_toml(id=5, joint="j2")), "duplicate CAN id 5 on bus 'a'"),
        ((motor_toml(joint="x"), motor_toml(id=2, joint="x")), "duplicate joint"),
        ((motor_toml(model="AK80-99"),), "unknown motor model preset 'AK80-99'"),
        ((motor_toml(torque="[5.0, -5.0]"),), "min 5.0 must be < max -5.0"),
        ((motor_toml(kp="[100, 100]"),), "min 100 must be < max 100"),
        ((motor_toml(zero_ofset="0.1"),), r"unknown key\(s\) \['zero_ofset'\]"),
        ((motor_toml(sign="2"),), "sign must be \\+1 or -1"),
        ((motor_toml(reply='"robstride"'),), "unknown MIT reply variant 'robstride'"),
        ((motor_toml(model="DM4310", id=3), motor_toml(id=0x13, joint="j2")), "cannot be told apart"),
        ((motor_toml(id=0x7FF),), "does not fit byte 0"),
        (
            tuple(motor_toml(id=i, joint=f"j{i}") for i in range(1, 10)),
            r"bus 'a' over capacity at 500 Hz: load 99.9% nominal",
        ),
    ],
)
def test_config_errors_name_file_and_problem(tmp_path, motors, match):
    path = write(tmp_path, *motors)
    with pytest.raises(HardwareConfigError, match=match) as e:
        load_hardware(path)
    assert str(path) in str(e.value)


def test_same_id_on_different_buses_is_fine(tmp_path):
    plan = load_hardware(write(tmp_path, motor_toml(id=1), motor_toml(bus="b", id=1, joint="j2")))
    assert [m.can_id for m in plan.motors] == [1, 1]


@pytest.mark.parametrize(
    "buses, match",
    [
        (BUSES.replace('name = "b"', 'name = "a"'), "duplicate bus name"),
        (BUSES.replace("bitrate = 1000000", "bitrate = 2000000", 1), "classic CAN"),
        (BUSES.replace('channel = "can0"', 'channel = "can0"\nmax_load = 1.5'), "max_load must be in"),
        (BUSES.replace('channel = "can0"', 'channel = "can0"\nprotocol = "canopen"'), "unknown actuator protocol"),
        (BUSES.replace('interface = "socketcan"\n', "", 1), r"missing key\(s\) \['interface'\]"),
    ],
)
def test_bus_errors(tmp_path, buses, match):
    with pytest.raises(HardwareConfigError, match=match):
        load_hardware(write(tmp_path, motor_toml(bus="b"), buses=buses))


CAN_IMU = """
[imu]
source = "can"
bus = "b"
rate = 500.0
[[imu.frames]]
id = 0x50
fields = [{ name = "qw", byte = 0, type = "i16" }, { name = "qx", byte = 2, type = "i16" },
          { name = "qy", byte = 4, type = "i16" }, { name = "qz", byte = 6, type = "i16" }]
[[imu.frames]]
id = 0x51
fields = [{ name = "gx", byte = 0, type = "i8" }, { name = "gy", byte = 1, type = "i8" }, { name = "gz", byte = 2, type = "i8" },
          { name = "ax", byte = 3, type = "i8" }, { name = "ay", byte = 4, type = "i8" }, { name = "az", byte = 5, type = "i8" }]
"""


@pytest.mark.parametrize(
    "imu, match",
    [
        ("", r"missing key\(s\) \['imu'\]"),
        ('\n[imu]\nsource = "gps"\n', "source must be one of"),
        ('\n[imu]\nsource = "serial"\n', r"missing key\(s\) \['device'\]"),
        ('\n[imu]\nsource = "can"\nbus = "zz"\nid = 80\n', "not one id"),
        (CAN_IMU.replace('bus = "b"', 'bus = "zz"'), "unknown bus 'zz'"),
        (CAN_IMU.replace('bus = "b"', 'bus = "a"').replace("id = 0x50", "id = 1"), "CAN id 1 is motor 'j1''s id on bus 'a'"),
        ('\n[imu]\nsource = "emulated"\ndevice = "/dev/ttyUSB0"\n', "unknown key"),
    ],
)
def test_imu_errors(tmp_path, imu, match):
    with pytest.raises(HardwareConfigError, match=match):
        load_hardware(write(tmp_path, motor_toml(), imu=imu))


def test_imu_sources(tmp_path):
    serial = '\n[imu]\nsource = "serial"\ndevice = "/dev/ttyUSB0"\nbaudrate = 921600\n'
    plan = load_hardware(write(tmp_path, motor_toml(), imu=serial))
    assert (plan.imu.source, plan.imu.device, plan.imu.baudrate) == ("serial", "/dev/ttyUSB0", 921600)
    plan = load_hardware(write(tmp_path, motor_toml(), imu=CAN_IMU))
    assert (plan.imu.source, plan.imu.bus, plan.imu.can_id) == ("can", "b", 0x50)
    assert plan.imu.layout.ids == (0x50, 0x51)


def test_joint_validation(tmp_path):
    path = write(tmp_path, motor_toml(joint="j1"), motor_toml(id=2, joint="extra"))
    expected = r"no motor for robot joint\(s\) \['j9'\].*does not have: \['extra'\]"
    with pytest.raises(HardwareConfigError, match=expected):
        load_hardware(path, joint_names=["j1", "j9"])
    plan = load_hardware(path)
    with pytest.raises(HardwareConfigError, match="repeats"):
        validate_joints(plan, ["j1", "j1", "extra"])
    with pytest.raises(HardwareConfigError, match="covers only 18 N m at the joint, below its effort limit 25 N m"):
        validate_joints(plan, ["j1", "extra"], {"j1": 25.0})
    validate_joints(plan, ["extra", "j1"], {"j1": 18.0})


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(HardwareConfigError, match="cannot read"):
        load_hardware(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[buses]\n")
    with pytest.raises(HardwareConfigError, match="invalid TOML") as e:
        load_hardware(bad)
    assert str(bad) in str(e.value)
    with pytest.raises(HardwareConfigError, match="control rate"):
        parse_hardware(BUSES + motor_toml() + IMU, 0.0)
