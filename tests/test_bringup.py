"""Motor bring-up against the actuator emulator: scan (missing, extra, wrong bus), reading without
torque, set zero, calibration of a deliberately wrong sign and offset, limit checks, plan writing."""

from __future__ import annotations

import re
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from giwbc.errors import HardwareConfigError
from giwbc.hal.bringup import (
    PROBE_UNKNOWN,
    BringupLink,
    CalibrationSession,
    FirstRunLimits,
    calibrate_joint,
    description_limits,
    limit_violations,
    read_joints,
    reply_variant,
    scan,
    set_zero,
)
from giwbc.hal.plan_edit import update_plan, update_plan_text
from giwbc.emulation import ActuatorEmulator, EmulatorConfig, FaultInjection
from giwbc.hal.hardware import HardwarePlan, load_hardware, parse_hardware
from giwbc.hal.motor import MotorConfig, motor_preset
from giwbc.hal.protocols import MitProtocol
from giwbc.hal.safety import SafetyConfig

WRONG = {"left_knee_joint": (-1, 0.3), "right_shoulder_pitch_joint": (-1, -0.2), "left_ankle_pitch_joint": (1, 0.15)}


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


@pytest.fixture(scope="module")
def g1_text(g1) -> str:
    return (g1.folder / "hardware.toml").read_text()


def truth_text(g1_text: str) -> str:
    """The G1 plan as the robot really is: some motors mounted reversed or zeroed elsewhere."""
    return update_plan_text(g1_text, {j: {"sign": s, "zero_offset": z} for j, (s, z) in WRONG.items()})


def on_channels(plan: HardwarePlan, like: HardwarePlan) -> HardwarePlan:
    """``plan``'s motors on the buses (interface, channel) of ``like`` (the emulator's)."""
    chan = {b.name: (b.interface, b.channel) for b in like.buses}
    return replace(plan, buses=tuple(replace(b, interface=chan[b.name][0], channel=chan[b.name][1]) for b in plan.buses))


@pytest.fixture
def emulator(g1, model):
    """Builds emulators of the G1 on a plan text; closes them after the test."""
    made: list[ActuatorEmulator] = []

    def make(text: str, **config) -> ActuatorEmulator:
        plan = parse_hardware(text, 500.0, joint_names=g1.joint_names, interface="virtual")
        made.append(ActuatorEmulator(plan, g1, EmulatorConfig(**config), model=model))
        return made[-1]

    yield make
    for e in made:
        e.close()


def test_probe_is_the_zero_gain_zero_torque_command() -> None:
    m = MotorConfig(can_id=5, model=motor_preset("AK70-10"), joint="j")
    frame = MitProtocol([m]).encode_command(5, 0.0, 0.0, 0.0, 0.0, 0.0).frame
    assert bytes(frame.data) == PROBE_UNKNOWN


def test_reply_variant_from_length_and_byte0() -> None:
    assert reply_variant(3, bytes([0x13]) + bytes(7)) == "damiao"  # state 1 (enabled), id 3
    assert reply_variant(3, bytes([0x03]) + bytes(7)) == "cubemars|damiao"  # a disabled Damiao looks the same
    assert reply_variant(0x23, bytes([0x23]) + bytes(7)) == "cubemars"
    assert reply_variant(0x23, bytes([0x13]) + bytes(7)) == "damiao"
    assert reply_variant(3, bytes([0x03]) + bytes(5)) == "original"
    assert reply_variant(3, bytes([0x04]) + bytes(5)) == "unknown"
    assert reply_variant(3, b"") == "unknown"


def test_scan_finds_a_missing_and_an_extra_motor(g1, emulator, g1_text) -> None:
    # the robot: right_wrist_yaw (can9 id 2) is wired but not in the host's plan; left_knee is dead
    emu = emulator(g1_text, faults=(FaultInjection("dead", joints=("left_knee_joint",)),))
    emu.advance(0.002)  # faults take effect as time passes
    host_text = re.sub(r'\[\[motors\]\]\nbus = "can9"\nid = 2\njoint = "right_wrist_yaw_joint"\n(?:\w+ = .*\n)*', "", g1_text)
    assert host_text != g1_text
    host = on_channels(parse_hardware(host_text, 500.0), emu.host_plan())
    with BringupLink(host, peer=emu) as link:
        report = scan(link, ids=range(1, 9))
    assert report.missing == (("can1", 1, "left_knee_joint"),)
    assert report.extra == (("can9", 2),)
    assert not report.ok and "MISSING 'left_knee_joint'" in str(report) and "EXTRA id 2 on can9" in str(report)
    assert len(report.answers) == 28
    assert {a.variant for a in report.answers} == {"cubemars|damiao"}  # all disabled: byte 0 = id
    assert emu.counters.commands.sum() == 0 and (emu.mode == 0).all()  # nothing was enabled


def test_scan_flags_a_motor_on_the_wrong_bus(g1, emulator, g1_text) -> None:
    emu = emulator(g1_text)
    # the host believes left_hip_yaw (can0 id 3) is on can4 as id 3... where the waist motors are 1..3:
    # so it believes id 7 on can0 instead, and the real id 3 on can0 is extra
    host_text = g1_text.replace('bus = "can0"\nid = 3\n', 'bus = "can0"\nid = 7\n')
    assert host_text != g1_text
    host = on_channels(parse_hardware(host_text, 500.0), emu.host_plan())
    with BringupLink(host, peer=emu) as link:
        report = scan(link, ids=range(1, 9), buses=["can0", "can1"])
    assert report.missing == (("can0", 7, "left_hip_yaw_joint"),)
    assert report.extra == (("can0", 3),)


def test_read_joints_applies_sign_and_offset_without_torque(g1, emulator, g1_text) -> None:
    emu = emulator(truth_text(g1_text))
    q_true = emu.robot.joint_positions()
    with BringupLink(on_channels(emu.plan, emu.host_plan()), peer=emu) as link:
        r = read_joints(link)
    assert r.replied.all()
    idx = [g1.joint_names.index(j) for j in r.joints]
    step = 25.0 / 65535  # position quantum of the widest range (+-12.5 rad)
    np.testing.assert_allclose(r.position, q_true[idx], atol=step)
    assert emu.counters.commands.sum() == 0 and (emu.mode == 0).all()
    assert "left_knee_joint" in r.table()


def test_calibration_recovers_a_wrong_sign_and_offset_and_writes_the_plan(g1, emulator, g1_text, tmp_path) -> None:
    emu = emulator(truth_text(g1_text))
    path = tmp_path / "hardware.toml"
    path.write_text(g1_text)  # the plan as shipped: all +1 / 0
    host = on_channels(load_hardware(path, 500.0), emu.host_plan())
    names = g1.joint_names
    q0 = emu.robot.joint_positions().copy()  # the known posture: the model's default pose
    lo, hi = g1.position_limits
    limits = description_limits(names, lo, hi)
    with BringupLink(host, peer=emu) as link:
        # before calibration the wrong plan reads these joints wrong
        before = read_joints(link)
        for j in WRONG:
            k = before.joints.index(j)
            assert abs(before.position[k] - q0[names.index(j)]) > 0.1
        session = CalibrationSession(link, {j: float(q0[names.index(j)]) for j in WRONG}, limits)
        assert session.record_known_posture() == []
        for j in WRONG:
            q = emu.robot.data.qpos.copy()
            q_by_hand = q0.copy()
            q_by_hand[names.index(j)] += 0.25  # the operator moves the joint in its positive direction
            full = g1.default_configuration()
            full[7:] = q_by_hand
            emu.robot.reset(full)
            cal = session.record_move(j)
            assert cal.ok, cal.problems
            assert cal.sign == WRONG[j][0]
            assert cal.zero_offset == pytest.approx(WRONG[j][1], abs=1e-3)
            assert cal.moved == pytest.approx(0.25, abs=1e-3)
            full[7:] = q0
            emu.robot.reset(full)
            del q
    backup = update_plan(path, session.results(), "giwbc motors calibrate", now=lambda: datetime(2026, 1, 2, 3, 4, 5, tzinfo=timezone.utc))
    assert backup.name == "hardware.toml.bak-20260102T030405Z" and backup.read_text() == g1_text
    new = load_hardware(path, 500.0, joint_names=names)
    for j, (s, z) in WRONG.items():
        _, m = new.motor(j)
        assert m.sign == s and m.zero_offset == pytest.approx(z, abs=1e-3)
    assert "# giwbc motors calibrate (20260102T030405Z)" in path.read_text()
    # with the calibrated plan every joint reads its true angle
    with BringupLink(on_channels(new, emu.host_plan()), peer=emu) as link:
        after = read_joints(link)
    idx = [names.index(j) for j in after.joints]
    np.testing.assert_allclose(after.position, q0[idx], atol=2e-3)
    assert limit_violations(after.joints, after.position, limits) == []


def test_calibration_refuses_small_or_wrong_way_moves() -> None:
    m = MotorConfig(can_id=1, model=motor_preset("DM8009"), joint="knee")
    small = calibrate_joint(m, 0.5, 0.52, 0.0, (-0.1, 2.5))
    assert not small.ok and "moved only 0.020 rad" in small.problems[0]
    past = calibrate_joint(m, 0.0, -0.8, 2.3, (-0.1, 2.5))
    assert not past.ok and "past the upper limit" in past.problems[0]
    outside = calibrate_joint(m, 0.0, 0.5, 3.0, (-0.1, 2.5))
    assert "outside the joint's limits" in outside.problems[0]
    gear = MotorConfig(can_id=1, model=motor_preset("DM8009"), joint="knee", gear_ratio=2.0)
    cal = calibrate_joint(gear, 1.0, 0.4, 0.2, (-0.1, 2.5))
    assert (cal.sign, cal.zero_offset, cal.moved) == (-1, pytest.approx(0.7), pytest.approx(0.3))


def test_set_zero_makes_the_motor_read_zero_and_records_the_offset(g1, emulator, g1_text, tmp_path) -> None:
    emu = emulator(g1_text)
    names = g1.joint_names
    q0 = emu.robot.joint_positions()
    j = "left_knee_joint"
    with BringupLink(on_channels(emu.plan, emu.host_plan()), peer=emu) as link:
        rec = set_zero(link, j, joint_angle=float(q0[names.index(j)]))
        assert abs(rec.motor_after) < 1e-3 and rec.motor_before == pytest.approx(q0[names.index(j)], abs=1e-3)
    path = tmp_path / "hardware.toml"
    path.write_text(g1_text)
    update_plan(path, {j: {"zero_offset": rec.joint_angle}}, f"zeroed motor {rec.bus} id {rec.motor_id}")
    new = on_channels(load_hardware(path, 500.0), emu.host_plan())
    with BringupLink(new, peer=emu) as link:
        r = read_joints(link, [j])
    assert r.position[0] == pytest.approx(q0[names.index(j)], abs=1e-3)


def test_set_zero_refuses_a_silent_motor(g1, emulator, g1_text) -> None:
    emu = emulator(g1_text, faults=(FaultInjection("dead", joints=("left_knee_joint",)),))
    emu.advance(0.002)
    with BringupLink(on_channels(emu.plan, emu.host_plan()), peer=emu) as link:
        with pytest.raises(HardwareConfigError, match="does not answer: not zeroed"):
            set_zero(link, "left_knee_joint")


def test_limit_violation_message_names_the_joint_and_the_fix() -> None:
    (msg,) = limit_violations(["a", "b"], np.array([0.0, 3.0]), {"a": (-1.0, 1.0), "b": (-1.0, 2.0)})
    assert msg.startswith("joint 'b' reads 3.000 rad (171.9 deg), outside its limits [-1.000, 2.000] rad")
    assert "giwbc motors calibrate" in msg


def test_update_plan_text_keeps_comments_and_refuses_unknown_joints(g1_text) -> None:
    new = update_plan_text(g1_text, {"left_knee_joint": {"sign": -1}}, "note")
    assert new.count("\n#") == g1_text.count("\n#") + 1
    assert parse_hardware(new).motor("left_knee_joint")[1].sign == -1
    with pytest.raises(HardwareConfigError, match="no \\[\\[motors\\]\\] table for joint"):
        update_plan_text(g1_text, {"nope": {"sign": -1}})
    bare = g1_text.replace("sign = 1\nzero_offset = 0.0\n", "")
    added = update_plan_text(bare, {"left_knee_joint": {"sign": -1, "zero_offset": 0.5}})
    _, m = parse_hardware(added).motor("left_knee_joint")
    assert (m.sign, m.zero_offset) == (-1, 0.5)


def test_update_plan_never_writes_a_broken_plan(tmp_path, g1_text) -> None:
    path = tmp_path / "hardware.toml"
    path.write_text(g1_text)
    with pytest.raises(HardwareConfigError):
        update_plan(path, {"left_knee_joint": {"sign": 2}}, "bad")
    assert path.read_text() == g1_text and list(tmp_path.iterdir()) == [path]


def test_first_run_limits_only_tighten() -> None:
    base = SafetyConfig()
    s = FirstRunLimits().safety(base)
    assert s.max_tilt < base.max_tilt and s.soft_limit_margin > base.soft_limit_margin
    assert s.torque_scale <= 0.3 and s.velocity_scale <= 0.5 and s.max_temperature < base.max_temperature
    strict = replace(base, max_tilt=0.1)
    assert FirstRunLimits().safety(strict).max_tilt == 0.1
