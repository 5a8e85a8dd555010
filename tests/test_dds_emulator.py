"""The DDS emulator (the actuator emulator's firmware and physics behind rt/lowcmd / rt/lowstate, in
its own process, on loopback): the mode byte enters and leaves motor mode, a command held by the
PD gains reaches its target, a command with a bad CRC is refused and counted, a motor that hears
nothing for the firmware's timeout goes limp and says so."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from giwbc.emulation import EmulatorConfig, Gantry
from giwbc.emulation.dds_emulator import DdsEmulatorProcess
from giwbc.hal.dds.messages import OK, LowCmd, LowState
from giwbc.hal.dds.transport import LOWCMD_TOPIC, LOWSTATE_TOPIC, DdsTransport
from giwbc.hal.hardware import load_hardware


def _newest(transport: DdsTransport, state: LowState, timeout: float = 1.0) -> LowState:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = transport.take()
        if got:
            assert state.load(got[-1]) == OK
            return state
        time.sleep(0.002)
    raise AssertionError("no rt/lowstate")


def test_mode_byte_commands_crc_and_timeout(g1) -> None:
    plan = load_hardware(g1.folder / "hardware_dds.toml", 500.0, joint_names=g1.joint_names, allow_dds=True)
    motors = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    config = EmulatorConfig(gantry=Gantry(until=np.inf))  # hung: the joints move, the robot does not fall
    with DdsEmulatorProcess(plan, motors, g1, config) as emulator:
        host = DdsTransport(emulator.plan.domain, "lo", publish=LOWCMD_TOPIC, subscribe=LOWSTATE_TOPIC)
        try:
            assert host.wait_matched(5.0)
            state = _newest(host, LowState(), 5.0)
            assert state.modes[:29].max() == 0 and int(state.field("mode_machine")[0]) == 5  # off until told
            knee = g1.joint_names.index("left_knee_joint")  # slot = joint index in the shipped plan
            cmd = LowCmd()
            modes = np.zeros(35, dtype=np.uint8)
            modes[:29] = 1
            cmd.set_modes(modes)
            cmd.q[:29] = g1.default_positions
            cmd.q[knee] = 0.8
            cmd.kp[:29], cmd.kd[:29] = 150.0, 4.0
            good = cmd.seal()
            bad = bytearray(good)
            bad[40] ^= 0x01
            host.write(bytes(bad))
            for _ in range(300):  # 0.6 s of commands at 500 Hz
                host.write(good)
                time.sleep(0.002)
            state = _newest(host, state)
            assert state.modes[:29].min() == 1 and state.q[knee] == pytest.approx(0.8, abs=0.05)
            time.sleep(0.2)  # silence: past the firmware's 50 ms timeout
            state = _newest(host, state)
            assert state.modes[:29].max() == 0  # limp, and says so
        finally:
            host.close()
    counters = emulator.counters
    assert counters["crc_errors"] == 1 and counters["commands"] >= 100
