"""The DDS robot against a hand-driven robot on loopback: joints mapped by name through the plan's
slots, states checked (CRC, tick order), commands on the wire where the plan puts them, the mode
byte, zero gain on exit, the watchdog's stop; the plan's and the link's errors in one line."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import replace
from types import MappingProxyType

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from giwbc.errors import HardwareConfigError
from giwbc.hal.can_robot import ENTER, EXIT
from giwbc.hal.dds.config import cyclone_config
from giwbc.hal.dds.messages import OK, LowCmd, LowState
from giwbc.hal.dds.plan import DdsPlan
from giwbc.hal.dds.robot import DdsRobot, tick_after
from giwbc.hal.dds.transport import LOWCMD_TOPIC, LOWSTATE_TOPIC, DdsTransport
from giwbc.hal.hardware import load_hardware, parse_hardware
from giwbc.robot.interface import ImpedanceCommand


def _domain(k: int = 0) -> int:
    return 201 + (os.getpid() + k) % 30  # away from the emulator's (1..200), one per test process


@pytest.fixture()
def plan(g1) -> DdsPlan:
    """The G1's DDS plan on loopback, slots reversed (joint 0 in slot 28, ...): mapping by name shows."""
    shipped = load_hardware(g1.folder / "hardware_dds.toml", 500.0, joint_names=g1.joint_names, allow_dds=True)
    slots = {j: 28 - k for k, j in enumerate(g1.joint_names)}
    return replace(shipped, slots=MappingProxyType(slots), state_timeout=1.0).with_interface("lo", _domain())


class FakeG1:
    """The robot's side, by hand: publishes LowState_, takes LowCmd_."""

    def __init__(self, plan: DdsPlan) -> None:
        self.transport = DdsTransport(plan.domain, "lo", publish=LOWSTATE_TOPIC, subscribe=LOWCMD_TOPIC)
        self.state, self.cmd = LowState(), LowCmd()
        self.state.field("mode_machine")[0] = 5

    def publish(self, tick: int, corrupt: bool = False) -> None:
        self.state.tick[0] = tick
        data = bytearray(self.state.seal())
        if corrupt:
            data[300] ^= 1
        self.transport.write(bytes(data))

    def last_command(self) -> LowCmd | None:
        got = self.transport.take()
        if not got:
            return None
        assert self.cmd.load(got[-1]) == OK
        return self.cmd

    def close(self) -> None:
        self.transport.close()


def _wait(predicate, timeout: float = 2.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


@pytest.fixture()
def pair(g1, plan):
    fake = FakeG1(plan)
    fake.state.q[:29] = np.arange(29) * 0.01  # slot s reads 0.01 s rad
    robot = DdsRobot(g1, plan, wait_for_state=False)  # (the start-up's wait: tests below)
    assert fake.transport.wait_matched(3.0) and robot.transport.wait_matched(3.0)
    fake.publish(1)
    _wait(lambda: robot.exchange(0.0).complete)
    time.sleep(0.02)
    fake.transport.take()  # (the commands of those cycles)
    yield robot, fake
    robot.close()
    fake.close()


def test_joints_by_name_and_commands_in_their_slots(g1, pair) -> None:
    robot, fake = pair
    q = robot.joint_positions()
    np.testing.assert_allclose(q, (28 - np.arange(29)) * 0.01, atol=1e-6)  # joint k is slot 28 - k
    fake.state.motorstate[28] = 0x40  # joint 0's slot: an error bit
    fake.state.temperature[28] = (61, 48)
    fake.publish(2)
    time.sleep(0.02)
    fake.transport.take()
    report = robot.exchange(0.002, kind=ENTER)
    assert report.complete and report.error_code[0] == 0x40 and report.error_code[1:].max() == 0
    assert report.temperature[0] == 61
    _wait(lambda: fake.last_command() is not None)
    cmd = fake.cmd
    assert cmd.modes[28] == 1 and cmd.modes[29:].max() == 0  # enabled, unused slots off
    assert cmd.kp.max() == 0 and cmd.tau.max() == 0  # entering: no torque yet
    assert int(cmd.field("mode_machine")[0]) == 5  # echoed from the state
    command = ImpedanceCommand(np.full(29, 0.1), np.zeros(29), np.arange(29) + 1.0, np.full(29, 2.0), np.linspace(-1, 1, 29))
    robot.set_joint_impedance(command)
    fake.transport.take()
    robot.exchange(0.004)
    _wait(lambda: fake.last_command() is not None)
    np.testing.assert_allclose(fake.cmd.kp[28 - np.arange(29)], np.arange(29) + 1.0)
    np.testing.assert_allclose(fake.cmd.tau[28 - np.arange(29)], np.linspace(-1, 1, 29), atol=1e-6)
    fake.transport.take()
    robot.exchange(0.006, kind=EXIT)
    _wait(lambda: fake.last_command() is not None)
    assert fake.cmd.modes.max() == 0 and fake.cmd.kp.max() == 0 and fake.cmd.kd.max() == 0  # zero gain, motors off


def test_stale_out_of_order_and_bad_crc_states_are_not_taken(pair) -> None:
    robot, fake = pair
    fake.state.q[28] = 0.5
    fake.publish(10)
    time.sleep(0.02)
    assert robot.exchange(0.002).complete
    fake.state.q[28] = 0.9
    fake.publish(9)  # older tick: out of order
    fake.publish(10)  # the same tick again: stale
    fake.publish(11, corrupt=True)  # bad CRC
    time.sleep(0.02)
    report = robot.exchange(0.004)
    assert not report.complete and report.stale.min() == 1
    assert report.unknown == 2 and int(report.corrupt.sum()) == 1 and robot.crc_errors == 1
    assert robot.joint_positions()[0] == pytest.approx(0.5)  # the last good state holds
    fake.publish(12)
    time.sleep(0.02)
    assert robot.exchange(0.006).complete and robot.joint_positions()[0] == pytest.approx(0.9)


def test_tick_wraps() -> None:
    assert tick_after(0, 0xFFFFFFFF) and tick_after(5, 4) and not tick_after(4, 5) and not tick_after(7, 7) and tick_after(3, None)


def test_the_watchdogs_stop_is_damping_then_zero_gain(g1, pair) -> None:
    robot, fake = pair
    damping = ImpedanceCommand.damping(29, 3.0)
    stop = robot.emergency_stop(damping)
    assert fake.cmd.load(stop.damping) == OK and fake.cmd.modes[:29].min() == 1 and fake.cmd.kd[:29].min() == pytest.approx(3.0)
    assert fake.cmd.kp.max() == 0
    assert fake.cmd.load(stop.off) == OK and fake.cmd.modes.max() == 0 and fake.cmd.kd.max() == 0
    out = stop.run(0.0, 0.002, 0.01, 2, realtime=False)
    assert out["damping_steps"] == 5 and out["frames_sent"] == 7 and not out["unreachable_buses"]


def test_no_robot_is_one_line(g1, plan) -> None:
    with pytest.raises(HardwareConfigError, match="no valid rt/lowstate within") as info:
        DdsRobot(g1, replace(plan, state_timeout=0.3))
    assert "\n" not in str(info.value)


def test_a_second_commander_refuses_the_start(g1, plan) -> None:
    fake = FakeG1(plan)
    service = DdsTransport(plan.domain, "lo", publish=LOWCMD_TOPIC, subscribe=None)  # the locomotion service, still running
    stop = threading.Event()

    def robot_side() -> None:  # the robot publishes its state, the service its commands, at 500 Hz
        tick = 0
        while not stop.is_set():
            tick += 1
            fake.publish(tick)
            service.write(LowCmd().seal())
            time.sleep(0.002)

    thread = threading.Thread(target=robot_side, daemon=True)
    thread.start()
    try:
        with pytest.raises(HardwareConfigError, match="locomotion service is still active") as info:
            DdsRobot(g1, plan).close()
        assert "\n" not in str(info.value)
    finally:
        stop.set()
        thread.join(1.0)
        service.close()
        fake.close()


PLAN = """[transport]
kind = "dds"
interface = "eth0"
domain = 0
[joints]
a = 0
b = 1
"""


@pytest.mark.parametrize("change, message", [
    (("domain = 0", "domain = 300"), "domain id must be an integer from 0 to 232"),
    (("interface = \"eth0\"", "interface = \"eth 0; rm\""), "network interface must be a Linux interface name"),
    (("b = 1", "b = 0"), "motor slot 0 is already 'a'"),
    (("b = 1", "b = 35"), "motor slot must be an integer from 0 to 34"),
    (("kind = \"dds\"", "kind = \"udp\""), "kind must be one of can, dds"),
    (("domain = 0", "domain = 0\nwatchdog = 1"), "unknown key"),
    (("[joints]", "[imu]\nsource = \"serial\"\n[joints]"), "a DDS robot's IMU is the one in its rt/lowstate"),
    (("mode_pr", "mode_pr"), None),
])  # fmt: skip
def test_plan_errors_are_one_line(change, message) -> None:
    text = PLAN.replace(*change)
    if message is None:
        plan = parse_hardware(text, source="g1.toml", joint_names=["b", "a"], allow_dds=True)
        assert plan.slot_array(["b", "a"]) == [1, 0] and plan.interface == "eth0"
        return
    with pytest.raises(HardwareConfigError, match=message) as info:
        parse_hardware(text, source="g1.toml", allow_dds=True)
    assert "\n" not in str(info.value) and "g1.toml" in str(info.value)


def test_plan_must_name_the_robots_joints() -> None:
    with pytest.raises(HardwareConfigError, match=r"no motor slot for robot joint\(s\) \['c'\]; slots for joint\(s\) the robot does not have: \['b'\]"):
        parse_hardware(PLAN, source="g1.toml", joint_names=["a", "c"], allow_dds=True)


def test_a_can_command_refuses_a_dds_plan_in_one_line(g1) -> None:
    with pytest.raises(HardwareConfigError, match="a DDS plan \\(\\[transport\\]\\), not CAN buses") as info:
        load_hardware(g1.folder / "hardware_dds.toml", 500.0)
    assert "\n" not in str(info.value)


def test_cyclone_stays_on_the_interface_asked() -> None:
    lo = cyclone_config(7, "lo")
    assert '<NetworkInterface name="lo"/>' in lo and "<AllowMulticast>false</AllowMulticast>" in lo
    assert '<Peer address="127.0.0.1"/>' in lo and '<Domain id="7">' in lo
    eth = cyclone_config(0, "eth0")
    assert '<NetworkInterface name="eth0"/>' in eth and "Peer" not in eth and "lo" not in eth.replace("CycloneDDS", "")
