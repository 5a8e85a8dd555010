"""The CAN robot's receive path (issue 13, item 6 and the duplicate rule of item 7): every bus is
read up to the deadline whatever another bus does, stray frames never hide a reply that came in
time, and a duplicated reply counts with its newest copy in every mode, on python-can ``virtual``
buses (message ports) and on giwbc-unix channels (socket ports)."""

from __future__ import annotations

import itertools
import time

import can
import numpy as np
import pytest

from giwbc.hal.bus import CanBusLink
from giwbc.hal.can_robot import CanRobot
from giwbc.hal.frames import fast_message
from giwbc.hal.hardware import load_hardware
from giwbc.hal.protocols import CanFrame
from giwbc.hal.unix_bus import UnixCanBus

_channels = itertools.count()
ERROR_FRAME = fast_message(0x4, bytes(8), error=True)
STRAY = fast_message(0x1AB, b"\x7f\x00\x11", False)  # a foreign frame: byte 0 of no motor


@pytest.fixture(scope="module")
def plan(g1):
    return load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")


class ScriptedMotors:
    """The motors' side of every bus, answering each cycle with the frames a test scripts
    (a lockstep peer: it answers after the host sent, before the host reads)."""

    def __init__(self, plan, interface: str) -> None:
        self.plan = plan
        self.protocols = [b.make_protocol() for b in plan.buses]
        self.host_buses, self.buses = [], []
        for _ in plan.buses:
            if interface == "virtual":
                channel = f"receive-test-{next(_channels)}"
                host, motors = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
            else:
                host, motors = UnixCanBus.pair(f"receive-test-{next(_channels)}")
            self.host_buses.append(host)
            self.buses.append(motors)
        self.script: list[list[can.Message]] = [[] for _ in plan.buses]

    def links(self) -> list[CanBusLink]:
        return [CanBusLink(bus, p, name=b.name) for bus, p, b in zip(self.host_buses, self.protocols, self.plan.buses)]

    def reply(self, b: int, motor_id: int, position: float) -> can.Message:
        f: CanFrame = self.protocols[b].encode_reply(motor_id, position, 0.0, 0.0)
        return fast_message(f.arbitration_id, f.data, f.is_extended_id)

    def all_replies(self, position: float = 0.25, silent: tuple[str, ...] = ()) -> list[list[can.Message]]:
        return [[self.reply(b, m.can_id, position) for m in bus.motors if m.joint not in silent] for b, bus in enumerate(self.plan.buses)]

    def advance(self, now: float) -> None:
        pass

    def answer(self, now: float) -> None:
        for bus, frames in zip(self.buses, self.script):
            for msg in frames:
                bus.send(msg)
        for bus in self.buses:  # the host's command frames: read and dropped
            while bus.recv(0.0) is not None:
                pass

    def close(self) -> None:
        for bus in self.buses + self.host_buses:
            bus.shutdown()


@pytest.fixture(params=["virtual", "giwbc-unix"])
def motors(request, plan):
    m = ScriptedMotors(plan, request.param)
    yield m
    m.close()


def robot_for(g1, plan, motors: ScriptedMotors, **kw) -> CanRobot:
    return CanRobot(g1, plan, links=motors.links(), peer=motors if kw.get("wait_for_replies", True) else None, reply_timeout=20e-3, **kw)


def test_a_silent_motor_and_an_error_frame_elsewhere_cost_only_the_silent_motor(g1, plan, motors):
    """The issue's case: left hip yaw silent on can0, one error frame before the replies on can1.
    Buses read one after the other waited for can0 to the deadline, then read can1 only up to one
    frame per motor: the error frame hid left_ankle_roll's reply."""
    robot = robot_for(g1, plan, motors)
    try:
        script = motors.all_replies(silent=("left_hip_yaw_joint",))
        script[1].insert(0, ERROR_FRAME)
        motors.script = script
        report = robot.exchange(0.0)
        missing = [g1.joint_names[j] for j in np.flatnonzero(report.missing)]
        assert missing == ["left_hip_yaw_joint"]
        assert robot.links[1].counters.errors == 1
        assert robot.late_frames == 0
    finally:
        robot.close()


def test_stray_frames_on_every_bus_never_hide_a_reply(g1, plan, motors):
    """Two foreign frames before and one among the replies of every bus: all motors replied; the
    strays are counted as unknown."""
    robot = robot_for(g1, plan, motors)
    try:
        script = motors.all_replies()
        for frames in script:
            frames[:0] = [STRAY, STRAY]
            frames.insert(3, STRAY)
        motors.script = script
        for k in range(3):
            report = robot.exchange(k * 0.002)
            assert report.complete and report.unknown == 3 * len(plan.buses)
            assert report.late == 0
    finally:
        robot.close()


def test_a_duplicated_reply_counts_with_its_newest_copy_in_both_modes(g1, plan, motors):
    """A second copy of one reply, after all replies of its bus: the newest copy's state is the
    motor's state whether the cycle waits for the replies or reads them at the next cycle, and
    through a single bus link as well."""
    joint = "left_ankle_pitch_joint"
    j = g1.joint_names.index(joint)
    bus, mc = plan.motor(joint)
    b, motor_id = plan.buses.index(bus), mc.can_id
    script = motors.all_replies(position=0.25)
    script[b].append(motors.reply(b, motor_id, -0.5))
    motors.script = script

    waiting = robot_for(g1, plan, motors)
    try:
        report = waiting.exchange(0.0)
        assert report.complete and waiting.joint_positions()[j] == pytest.approx(-0.5, abs=1e-3)
        report = waiting.exchange(0.002)  # nothing of the last cycle is left to drain as late
        assert report.late == 0 and waiting.late_frames == 0
    finally:
        waiting.close()

    motors2 = ScriptedMotors(plan, "giwbc-unix" if isinstance(motors.buses[0], UnixCanBus) else "virtual")
    deferred = robot_for(g1, plan, motors2, wait_for_replies=False)
    try:
        motors2.script = script
        deferred.exchange(0.0)  # sends the commands
        motors2.answer(0.0)
        report = deferred.exchange(0.002)  # reads the replies of the first cycle
        assert report.complete and deferred.joint_positions()[j] == pytest.approx(-0.5, abs=1e-3)
    finally:
        deferred.close()
        motors2.close()

    motors3 = ScriptedMotors(plan, "virtual")
    try:
        link = motors3.links()[b]
        for msg in script[b]:
            motors3.buses[b].send(msg)
        result = link.receive(time.perf_counter() + 0.02)
        assert result.complete and result.replies[motor_id].position == pytest.approx(-0.5, abs=1e-3)
    finally:
        motors3.close()
